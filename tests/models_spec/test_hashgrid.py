"""Hash-grid encoding: the numpy reference (models_spec.hashgrid) against hand-computed values, and the torch
module (photon_fields.train.field.hashgrid) against the reference, bit for bit, forward and backward."""

from __future__ import annotations

import json
import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest
from conftest import edge_points, hashgrid_configs, pole_and_seam_directions, random_table

from photon_fields.models_spec.hashgrid import (
    HASH_PRIMES,
    PAPER_DIRECTION,
    PAPER_POSITION,
    HashGridConfig,
    corner_indices,
    direction_to_unit_square,
    encode_reference,
    fma_f32,
    level_dense_strides,
    level_is_hashed,
    level_resolution,
    level_scale,
    level_table_size,
    table_gradient_reference,
    table_offsets,
    total_table_rows,
)

torch = pytest.importorskip("torch")
numba = pytest.importorskip("numba")
from photon_fields.train.field.hashgrid import HashGridEncoding  # noqa: E402  (after the torch skip)

_CFG = hashgrid_configs()
DENSE, HASHED, SMALL3, SMALL2 = _CFG["DENSE"], _CFG["HASHED"], _CFG["SMALL3"], _CFG["SMALL2"]


def f32_round(q: Fraction) -> np.float32:
    """Correctly rounded (to nearest, ties to even) float32 of an exact rational."""
    r = np.float32(float(q))  # within one float32 ulp of q (float() may double-round)
    cands = [np.nextafter(r, np.float32(-np.inf)), r, np.nextafter(r, np.float32(np.inf))]
    dist = [abs(Fraction(float(c)) - q) for c in cands]
    best = min(dist)
    ties = [c for c, dd in zip(cands, dist, strict=True) if dd == best]
    return ties[0] if len(ties) == 1 else next(c for c in ties if (c.view(np.int32) & 1) == 0)


def integer_table(cfg: HashGridConfig, seed: int = 0) -> np.ndarray:
    # Small integers: sums of corners times 1/8 are exact, so averages can be compared with ==.
    rng = np.random.default_rng(seed)
    return rng.integers(-64, 65, size=(total_table_rows(cfg), cfg.features)).astype(np.float32)


def encoder_with_table(cfg: HashGridConfig, table: np.ndarray) -> HashGridEncoding:
    enc = HashGridEncoding(cfg, seed=0)
    with torch.no_grad():
        enc.table.copy_(torch.from_numpy(table))
    return enc


# ----------------------------------------------------------------------------------------------------
# Config
# ----------------------------------------------------------------------------------------------------


def test_config_roundtrip_and_rounding() -> None:
    cfg = HashGridConfig.from_dict(json.loads(json.dumps(SMALL3.to_dict())))
    assert cfg == SMALL3 and cfg.output_dims == 8
    assert SMALL3.per_level_scale == float(np.float32(1.7))  # stored as tcnn's float32
    assert PAPER_POSITION.to_dict() == {"dims": 3, "levels": 16, "features": 8, "log2_table_size": 19,
                                        "base_resolution": 16, "per_level_scale": 2.0}


@pytest.mark.parametrize("kwargs, match", [
    ({"dims": 4}, "dims must be 2 or 3"),
    ({"dims": True}, "dims must be an int"),
    ({"levels": 0}, "levels must be in"),
    ({"features": 3}, "features must be one of"),
    ({"log2_table_size": 32}, "log2_table_size must be in"),
    ({"base_resolution": 0}, "base_resolution must be >= 1"),
    ({"per_level_scale": 0.5}, "per_level_scale must be finite \\(as float32\\) and >= 1"),
    ({"per_level_scale": 1e39}, "per_level_scale must be finite"),
    ({"per_level_scale": float("nan")}, "per_level_scale must be finite"),
    ({"per_level_scale": "2"}, "per_level_scale must be a number"),
    ({"levels": 32, "per_level_scale": 4.0}, "finest level's scale"),
])
def test_config_validation(kwargs: dict, match: str) -> None:
    args = {**PAPER_POSITION.to_dict(), **kwargs}
    with pytest.raises(ValueError, match=match):
        HashGridConfig(**args)


def test_from_dict_rejects_bad_keys() -> None:
    with pytest.raises(ValueError, match="unknown keys \\['n_levels'\\]"):
        HashGridConfig.from_dict({**PAPER_POSITION.to_dict(), "n_levels": 16})
    d = PAPER_POSITION.to_dict()
    del d["dims"]
    with pytest.raises(ValueError, match="missing keys \\['dims'\\]"):
        HashGridConfig.from_dict(d)


def test_models_spec_does_not_import_torch() -> None:
    code = ("import sys, photon_fields.models_spec.hashgrid; "
            "assert 'torch' not in sys.modules and 'numba' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


# ----------------------------------------------------------------------------------------------------
# float32 fma emulation
# ----------------------------------------------------------------------------------------------------


def test_fma_f32_avoids_double_rounding() -> None:
    # a*b + c = 1 + 2^-23 + 2^-24 - 2^-70: just below the float32 tie, so the answer is 1 + 2^-23. Rounding
    # to float64 first lands exactly on the tie, which ties-to-even then sends up to 1 + 2^-22.
    a, b, c = np.float32(1 + 2**-23), np.float32(2**-24 - 2**-47), np.float32(1 + 2**-23)
    assert np.float32(float(a) * float(b) + float(c)) == np.float32(1 + 2**-22)  # the naive emulation is wrong
    assert fma_f32(a, b, c) == np.float32(1 + 2**-23)


def test_fma_f32_matches_exact_rounding() -> None:
    rng = np.random.default_rng(3)
    a = rng.uniform(0, 600000, 300).astype(np.float32)
    b = (rng.random(300) ** 8).astype(np.float32)  # many small x: long exact sums
    c = np.full(300, 0.5, np.float32)
    a[:100] = np.float32(1) + np.float32(2**-23) * rng.integers(0, 8, 100).astype(np.float32)
    c[:100] = rng.choice([np.float32(1), np.float32(1 + 2**-23), np.float32(-1)], 100)
    got = fma_f32(a, b, c)
    want = [f32_round(Fraction(float(ai)) * Fraction(float(bi)) + Fraction(float(ci)))
            for ai, bi, ci in zip(a, b, c, strict=True)]
    np.testing.assert_array_equal(got, np.array(want, np.float32))


# ----------------------------------------------------------------------------------------------------
# (a) dense level, by hand
# ----------------------------------------------------------------------------------------------------


def test_dense_level_geometry() -> None:
    assert float(level_scale(DENSE, 0)) == 4.0 and level_resolution(DENSE, 0) == 5
    assert level_table_size(DENSE, 0) == 128 and not level_is_hashed(DENSE, 0)
    assert level_dense_strides(DENSE, 0) == (1, 5, 25)


def test_dense_level_vertices_and_midpoints() -> None:
    table = integer_table(DENSE)
    k = np.array(np.meshgrid(*[np.arange(5)] * 3, indexing="ij")).reshape(3, -1).T  # vertices 0..4
    # Vertex k sits at pos = 4x + 0.5 = k, i.e. x = (2k - 1) / 8 (x in [0, 1] for k >= 1; k = 0 is x = -1/8).
    x = ((2 * k - 1) / 8).astype(np.float32)
    out = encode_reference(DENSE, table, x)
    dense_index = k[:, 0] + 5 * k[:, 1] + 25 * k[:, 2]
    np.testing.assert_array_equal(out, table[dense_index])
    # Midpoints of cells: pos = k + 1/2 in every dimension (x = k / 4), all 8 weights are 1/8.
    k = np.array(np.meshgrid(*[np.arange(4)] * 3, indexing="ij")).reshape(3, -1).T
    x = (k / 4).astype(np.float32)
    corners = [k + np.array([(j >> d) & 1 for d in range(3)]) for j in range(8)]
    mean = np.mean([table[c[:, 0] + 5 * c[:, 1] + 25 * c[:, 2]] for c in corners], axis=0)
    np.testing.assert_array_equal(encode_reference(DENSE, table, x), mean.astype(np.float32))
    idx, w = corner_indices(DENSE, 0, x)
    np.testing.assert_array_equal(w, np.full((64, 8), 0.125, np.float32))
    np.testing.assert_array_equal(idx[:, 7], corners[7][:, 0] + 5 * corners[7][:, 1] + 25 * corners[7][:, 2])


def test_dense_level_wraps_at_the_far_face() -> None:
    # x = 1: pos = 4.5, corners 4 and 5 along x; corner 5 is outside the 5-vertex grid and tcnn does not
    # clamp: index 5 + 5 c1 + 25 c2, i.e. the next row's first vertex (mod 128).
    idx, w = corner_indices(DENSE, 0, np.array([[1.0, 0.0, 0.0]], np.float32))
    assert idx[0, 1] == 5 and w[0, 1] == np.float32(0.5 * 0.5 * 0.5)
    idx, _ = corner_indices(DENSE, 0, np.array([[1.0, 1.0, 1.0]], np.float32))
    assert idx[0, 7] == (5 + 5 * 5 + 25 * 5) % 128 == 27


# ----------------------------------------------------------------------------------------------------
# (b) hashed level, by hand
# ----------------------------------------------------------------------------------------------------


def test_hash_primes() -> None:
    assert HASH_PRIMES.dtype == np.uint32 and tuple(int(p) for p in HASH_PRIMES) == (1, 2654435761, 805459861)


def test_hashed_level_slots() -> None:
    assert float(level_scale(HASHED, 0)) == 8.0 and level_resolution(HASHED, 0) == 9
    assert level_table_size(HASHED, 0) == 64 and level_is_hashed(HASHED, 0)
    # Written out: (1*1) ^ (2*2654435761 mod 2^32 = 1013904226) ^ (3*805459861 = 2416379583) = 2892625372,
    # mod 64 = 28. (4*1) ^ (0) ^ (7*805459861 mod 2^32 = 1343251731) = 1343251735, mod 64 = 23.
    # (2, 3, 4): 2 ^ 3668339987 ^ 3221839444 = 447689541, mod 64 = 5.
    assert (1 ^ (2 * 2654435761 % 2**32) ^ (3 * 805459861)) == 2892625372 and 2892625372 % 64 == 28
    assert (4 ^ (7 * 805459861 % 2**32)) == 1343251735 and 1343251735 % 64 == 23
    assert (2 ^ (3 * 2654435761 % 2**32) ^ (4 * 805459861 % 2**32)) == 447689541 and 447689541 % 64 == 5
    # Vertex (c0, c1, c2) at pos = 8x + 0.5 = c, i.e. x = (2c - 1) / 16.
    x = ((2 * np.array([[1, 2, 3], [4, 0, 7]]) - 1) / 16).astype(np.float32)
    idx, w = corner_indices(HASHED, 0, x)
    assert idx[0, 0] == 28 and idx[1, 0] == 23
    assert idx[0, 7] == 5  # corner j = 7 of the first point: (1, 2, 3) + (1, 1, 1)
    np.testing.assert_array_equal(w[:, 0], [1.0, 1.0])
    np.testing.assert_array_equal(w[:, 1:], 0.0)
    table = np.arange(64, dtype=np.float32)[:, None] * 3 + 1
    np.testing.assert_array_equal(encode_reference(HASHED, table, x), [[28 * 3 + 1], [23 * 3 + 1]])


def test_fine_levels_are_hashed_not_wrapped() -> None:
    """A level is hashed exactly when res^D exceeds its table (tcnn >= PR #501). The pre-fix uint32 stride
    made levels 12-15 of the paper's configs 'dense' with a wrapped stride, indexing by c0 mod 2^19 alone at
    level 15: the reference must not do that."""
    cfg = PAPER_POSITION
    assert [level for level in range(16) if level_is_hashed(cfg, level)] == list(range(3, 16))
    assert [level for level in range(16) if level_is_hashed(PAPER_DIRECTION, level)] == list(range(6, 16))
    x = np.random.default_rng(5).random((200, 3), dtype=np.float32)
    p1, p2 = int(HASH_PRIMES[1]), int(HASH_PRIMES[2])
    for level in (12, 15):
        c = np.floor(fma_f32(level_scale(cfg, level), x, 0.5)).astype(np.int64)
        idx, _ = corner_indices(cfg, level, x)
        expected = (c[:, 0] ^ ((c[:, 1] * p1) & 0xFFFFFFFF) ^ ((c[:, 2] * p2) & 0xFFFFFFFF)) % 2**19
        np.testing.assert_array_equal(idx[:, 0], expected)


# ----------------------------------------------------------------------------------------------------
# (c) the paper's level geometry, by hand
# ----------------------------------------------------------------------------------------------------


def test_paper_position_levels() -> None:
    cfg = PAPER_POSITION
    # scale = 2^l * 16 - 1, res = 2^l * 16, size = min(res^3 (already a multiple of 8), 2^19)
    expected = {0: (15.0, 16, 4096, False), 1: (31.0, 32, 32768, False), 2: (63.0, 64, 262144, False),
                3: (127.0, 128, 524288, True),  # first hashed level: 128^3 = 2^21 > 2^19
                11: (32767.0, 32768, 524288, True), 15: (524287.0, 524288, 524288, True)}
    for level, (scale, res, size, hashed) in expected.items():
        assert level_scale(cfg, level) == np.float32(scale) and isinstance(level_scale(cfg, level), np.float32)
        assert (level_resolution(cfg, level), level_table_size(cfg, level), level_is_hashed(cfg, level)) == \
            (res, size, hashed)
    offsets = table_offsets(cfg)
    assert offsets.shape == (17,) and list(offsets[:5]) == [0, 4096, 36864, 299008, 823296]
    assert offsets[-1] == total_table_rows(cfg) == 4096 + 32768 + 262144 + 13 * 2**19 == 7114752


def test_paper_direction_levels() -> None:
    cfg = PAPER_DIRECTION
    sizes = [level_table_size(cfg, level) for level in range(16)]
    assert sizes == [256, 1024, 4096, 16384, 65536, 262144] + [2**19] * 10
    assert not level_is_hashed(cfg, 5) and level_is_hashed(cfg, 6)  # 1024^2 = 2^20 > 2^19
    assert total_table_rows(cfg) == 349440 + 10 * 2**19


def test_non_power_of_two_scale() -> None:
    # float32 pipeline vs float64 math: equal to float32 precision; ceil decides the resolution.
    for level in range(SMALL3.levels):
        s = float(level_scale(SMALL3, level))
        assert s == pytest.approx(5 * 1.7**level - 1, rel=1e-6)
        assert level_resolution(SMALL3, level) == int(np.ceil(np.float32(s))) + 1


# ----------------------------------------------------------------------------------------------------
# (d) torch forward == reference, bit for bit
# ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cfg", [PAPER_POSITION, SMALL3, SMALL2, DENSE, HASHED], ids=lambda c: f"D{c.dims}L{c.levels}")
def test_torch_forward_equals_reference(cfg: HashGridConfig) -> None:
    rng = np.random.default_rng(11)
    table = random_table(cfg, 11)
    enc = encoder_with_table(cfg, table)
    x = edge_points(cfg, rng, 400, 40)
    out = enc(torch.from_numpy(x))
    assert out.dtype == torch.float32 and out.shape == (x.shape[0], cfg.output_dims)
    np.testing.assert_array_equal(out.detach().numpy(), encode_reference(cfg, table, x))
    rows, weights = enc.corners(torch.from_numpy(x))
    offsets = table_offsets(cfg)
    for level in range(cfg.levels):
        idx, w = corner_indices(cfg, level, x)
        np.testing.assert_array_equal(rows[:, level].numpy(), idx + offsets[level])
        np.testing.assert_array_equal(weights[:, level].numpy(), w)


def test_torch_forward_directions_poles_and_seam() -> None:
    cfg = PAPER_DIRECTION
    rng = np.random.default_rng(12)
    u = direction_to_unit_square(pole_and_seam_directions(rng))
    np.testing.assert_array_equal(u[300:306], np.array([[0, 0.5], [1, 0.5], [0.5, 1], [0.5, 0], [0.5, 0.5],
                                                        [0.5, 0.75]], np.float32))
    table = random_table(cfg, 12)
    enc = encoder_with_table(cfg, table)
    np.testing.assert_array_equal(enc(torch.from_numpy(u)).detach().numpy(), encode_reference(cfg, table, u))


def test_direction_to_unit_square_range_and_clamp() -> None:
    u = direction_to_unit_square(np.array([[0, 0, 1 + 1e-7], [0, 0, -1 - 1e-7]]))
    np.testing.assert_array_equal(u, [[0, 0.5], [1, 0.5]])
    assert u.dtype == np.float32
    with pytest.raises(ValueError, match="shape"):
        direction_to_unit_square(np.zeros((4, 2)))


def test_input_validation() -> None:
    enc = HashGridEncoding(SMALL2)
    with pytest.raises(ValueError, match="shape"):
        enc(torch.zeros(3, 3))
    with pytest.raises(ValueError, match="finite"):
        enc(torch.tensor([[0.5, float("nan")]]))
    with pytest.raises(ValueError, match="finite"):
        encode_reference(SMALL2, np.zeros((total_table_rows(SMALL2), 4), np.float32), [[0.5, np.inf]])
    with pytest.raises(ValueError, match="table must be float32"):
        encode_reference(SMALL2, np.zeros((3, 4), np.float32), [[0.5, 0.5]])
    assert enc(torch.zeros(0, 2)).shape == (0, SMALL2.output_dims)
    # float64 input is rounded to float32 first, like tcnn's float inputs
    x = torch.rand(50, 2, dtype=torch.float64)
    assert torch.equal(enc(x), enc(x.float()))


def test_init_is_seeded_and_in_range() -> None:
    a, b = HashGridEncoding(SMALL3, seed=7), HashGridEncoding(SMALL3, seed=7)
    assert torch.equal(a.table, b.table) and not torch.equal(a.table, HashGridEncoding(SMALL3, seed=8).table)
    assert a.table.abs().max() <= 1e-4 and a.table.shape == (total_table_rows(SMALL3), 2)
    g = torch.Generator().manual_seed(7)
    assert torch.equal(HashGridEncoding(SMALL3, generator=g).table, a.table)
    assert list(dict(a.named_parameters())) == ["table"] and list(a.state_dict()) == ["table"]


# ----------------------------------------------------------------------------------------------------
# (e) gradient == reference scatter; (f) determinism
# ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cfg", [SMALL3, SMALL2], ids=["D3", "D2"])
def test_table_gradient_equals_reference(cfg: HashGridConfig) -> None:
    rng = np.random.default_rng(21)
    enc = HashGridEncoding(cfg, seed=3)
    x = edge_points(cfg, rng, n_random=1500)
    wout = rng.standard_normal((x.shape[0], cfg.output_dims)).astype(np.float32)
    (enc(torch.from_numpy(x)) * torch.from_numpy(wout)).sum().backward()
    grad = enc.table.grad.numpy()
    # Exact: the reference applies the same fma chain per row in the same (point, corner) order.
    np.testing.assert_array_equal(grad, table_gradient_reference(cfg, x, wout))
    # And the plain scatter of corner weights (np.add.at of float32 products) agrees to rounding.
    scatter = np.zeros_like(grad)
    magnitude = np.zeros_like(grad)
    offsets = table_offsets(cfg)
    for level in range(cfg.levels):
        idx, w = corner_indices(cfg, level, x)
        g = wout[:, level * cfg.features:(level + 1) * cfg.features]
        for j in range(idx.shape[1]):
            np.add.at(scatter, offsets[level] + idx[:, j], w[:, j, None] * g)
            np.add.at(magnitude, offsets[level] + idx[:, j], np.abs(w[:, j, None] * g))
    assert np.all(np.abs(grad - scatter) <= 4 * np.finfo(np.float32).eps * magnitude)
    assert np.count_nonzero(scatter) > 0.5 * scatter.size  # the test touches most rows


def test_backward_is_deterministic() -> None:
    cfg = SMALL3
    enc = HashGridEncoding(cfg, seed=4)
    x = torch.from_numpy(np.random.default_rng(31).random((3000, 3), dtype=np.float32))
    wout = torch.randn(3000, cfg.output_dims, generator=torch.Generator().manual_seed(1))
    grads = []
    threads = numba.get_num_threads()
    try:
        for t in (threads, threads, 1):
            numba.set_num_threads(t)
            enc.table.grad = None
            (enc(x) * wout).sum().backward()
            grads.append(enc.table.grad.clone())
    finally:
        numba.set_num_threads(threads)
    assert all(torch.equal(grads[0], g) for g in grads[1:])
