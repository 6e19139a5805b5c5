"""runtime.field.hashgrid (numba, no torch) against the numpy reference (models_spec.hashgrid), bit for bit: paper
and small configs, edge inputs, directions at the poles and the azimuth seam, ``out=`` buffers with a column
offset or a strided view, the invalid-input contract, and import without torch."""

from __future__ import annotations

import subprocess
import sys

import numba
import numpy as np
import pytest
from conftest import edge_points, hashgrid_configs, pole_and_seam_directions, random_table

from photon_fields.models_spec.hashgrid import (
    PAPER_DIRECTION,
    PAPER_POSITION,
    HashGridConfig,
    corner_indices,
    direction_to_unit_square,
    encode_reference,
    level_scale,
    table_offsets,
)
from photon_fields.runtime.field.hashgrid import aligned_table, corners, encode, encode_with_layout

_CFG = hashgrid_configs()
SMALL3, SMALL2, DENSE, HASHED, TINY2, WIDE3 = (_CFG[k] for k in
                                               ("SMALL3", "SMALL2", "DENSE", "HASHED", "TINY2", "WIDE3"))
CONFIGS = [PAPER_POSITION, PAPER_DIRECTION, SMALL3, SMALL2, DENSE, HASHED, TINY2, WIDE3]


def cfg_id(cfg: HashGridConfig) -> str:
    return f"D{cfg.dims}L{cfg.levels}F{cfg.features}T{cfg.log2_table_size}b{cfg.per_level_scale:.3g}"


# ----------------------------------------------------------------------------------------------------
# Bit-exact equality with the reference
# ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cfg", CONFIGS, ids=cfg_id)
def test_encode_equals_reference(cfg: HashGridConfig) -> None:
    rng = np.random.default_rng(1)
    table = random_table(cfg)
    x = edge_points(cfg, rng)
    out = encode(cfg, table, x)
    assert out.dtype == np.float32 and out.shape == (x.shape[0], cfg.output_dims)
    np.testing.assert_array_equal(out, encode_reference(cfg, table, x))


@pytest.mark.parametrize("cfg", [SMALL3, SMALL2, TINY2], ids=cfg_id)
def test_encode_outside_unit_box_equals_reference(cfg: HashGridConfig) -> None:
    # Negative cells wrap as (uint32)(int) in tcnn; far faces overflow the dense grid; both unclamped.
    rng = np.random.default_rng(2)
    x = rng.uniform(-3.0, 4.0, size=(500, cfg.dims)).astype(np.float32)
    x[:4] = [[-0.0] * cfg.dims, [-1e-30] * cfg.dims, [1.0 + 2**-23] * cfg.dims, [-1.0] * cfg.dims]
    table = random_table(cfg, 3)
    np.testing.assert_array_equal(encode(cfg, table, x), encode_reference(cfg, table, x))


def test_directions_poles_and_seam() -> None:
    cfg = PAPER_DIRECTION
    rng = np.random.default_rng(12)
    u = direction_to_unit_square(pole_and_seam_directions(rng))
    # The poles map to azimuth 0.5, the seam (d_y = +-0, d_x < 0) to 1 and 0.
    np.testing.assert_array_equal(u[300:304], np.array([[0, 0.5], [1, 0.5], [0.5, 1], [0.5, 0]], np.float32))
    table = random_table(cfg, 4)
    np.testing.assert_array_equal(encode(cfg, table, u), encode_reference(cfg, table, u))


@pytest.mark.parametrize("cfg", [PAPER_POSITION, SMALL2, HASHED], ids=cfg_id)
def test_corners_equal_reference(cfg: HashGridConfig) -> None:
    x = edge_points(cfg, np.random.default_rng(5), n_random=200)
    rows, weights = corners(cfg, x)
    assert rows.dtype == np.int64 and weights.dtype == np.float32
    assert rows.shape == weights.shape == (x.shape[0], cfg.levels, 1 << cfg.dims)
    offsets = table_offsets(cfg)
    for level in range(cfg.levels):
        idx, w = corner_indices(cfg, level, x)
        np.testing.assert_array_equal(rows[:, level], idx + offsets[level])
        np.testing.assert_array_equal(weights[:, level], w)


def test_layouts_blocks_and_threads_agree() -> None:
    cfg = WIDE3
    table = random_table(cfg, 6)
    x = np.random.default_rng(7).random((3000, 3), dtype=np.float32)
    want = encode_reference(cfg, table, x)
    for layout, block in [("blocks", 1), ("blocks", 100), ("blocks", 4096), ("levels", 256)]:
        out = np.full((x.shape[0], cfg.output_dims), np.nan, np.float32)
        np.testing.assert_array_equal(encode_with_layout(cfg, table, x, out, layout, block), want)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        np.testing.assert_array_equal(encode(cfg, table, x), want)
    finally:
        numba.set_num_threads(threads)
    with pytest.raises(ValueError, match="unknown layout"):
        encode_with_layout(cfg, table, x, out, "points", 1)


def test_input_conversions() -> None:
    cfg = SMALL2
    table = random_table(cfg, 8)
    x64 = np.random.default_rng(9).random((200, 2))
    np.testing.assert_array_equal(encode(cfg, table, x64), encode(cfg, table, x64.astype(np.float32)))
    x = np.random.default_rng(10).random((2, 300), dtype=np.float32).T  # Fortran order
    np.testing.assert_array_equal(encode(cfg, table, x), encode_reference(cfg, table, x))
    np.testing.assert_array_equal(encode(cfg, np.asfortranarray(table), x), encode_reference(cfg, table, x))
    assert encode(cfg, table, np.zeros((0, 2), np.float32)).shape == (0, cfg.output_dims)


def test_aligned_table() -> None:
    cfg = SMALL3
    table = random_table(cfg, 11)
    buf = np.empty(table.nbytes + 64, np.uint8)
    start = (16 - buf.ctypes.data) % 64
    misaligned = buf[start:start + table.nbytes].view(np.float32).reshape(table.shape)  # 16 bytes past a line
    misaligned[...] = table
    a = aligned_table(misaligned)
    assert a.ctypes.data % 64 == 0 and a.flags.c_contiguous and a.dtype == np.float32
    np.testing.assert_array_equal(a, table)
    assert aligned_table(a) is a
    x = np.random.default_rng(12).random((100, 3), dtype=np.float32)
    np.testing.assert_array_equal(encode(cfg, a, x), encode(cfg, misaligned, x))
    with pytest.raises(ValueError, match="float32"):
        aligned_table(table.astype(np.float64))


# ----------------------------------------------------------------------------------------------------
# out= buffers
# ----------------------------------------------------------------------------------------------------


def test_out_with_column_offset_encodes_both_inputs_into_one_buffer() -> None:
    pos, dirc = SMALL3, SMALL2
    tp, td = random_table(pos, 13), random_table(dirc, 14)
    rng = np.random.default_rng(15)
    n = 700
    xp = rng.random((n, 3), dtype=np.float32)
    u = direction_to_unit_square(rng.standard_normal((n, 3)) / np.sqrt(3))
    width = 3 + pos.output_dims + dirc.output_dims + 2  # 3 untouched columns before, 2 after
    buf = np.full((n, width), 7.5, np.float32)
    assert encode(pos, tp, xp, out=buf, col=3) is buf
    assert encode(dirc, td, u, out=buf, col=3 + pos.output_dims) is buf
    np.testing.assert_array_equal(buf[:, 3:3 + pos.output_dims], encode_reference(pos, tp, xp))
    np.testing.assert_array_equal(buf[:, 3 + pos.output_dims:-2], encode_reference(dirc, td, u))
    np.testing.assert_array_equal(buf[:, :3], 7.5)
    np.testing.assert_array_equal(buf[:, -2:], 7.5)


def test_out_as_strided_view() -> None:
    cfg = SMALL2
    table = random_table(cfg, 16)
    x = np.random.default_rng(17).random((300, 2), dtype=np.float32)
    buf = np.full((600, 50), -1.0, np.float32)
    view = buf[::2, 5:5 + cfg.output_dims]  # every other row, a column window
    assert encode(cfg, table, x, out=view) is view
    np.testing.assert_array_equal(buf[::2, 5:25], encode_reference(cfg, table, x))
    untouched = np.ones(buf.shape, bool)
    untouched[::2, 5:25] = False
    assert np.all(buf[untouched] == -1.0)


def test_out_validation() -> None:
    cfg = SMALL2
    table = random_table(cfg, 18)
    x = np.random.default_rng(19).random((10, 2), dtype=np.float32)
    with pytest.raises(ValueError, match="contiguous columns"):
        encode(cfg, table, x, out=np.zeros((10, 2 * cfg.output_dims), np.float32)[:, ::2])
    with pytest.raises(ValueError, match="10 rows and >= 23 columns"):
        encode(cfg, table, x, out=np.zeros((10, 22), np.float32), col=3)
    with pytest.raises(ValueError, match="10 rows"):
        encode(cfg, table, x, out=np.zeros((11, 20), np.float32))
    with pytest.raises(ValueError, match="2-D float32"):
        encode(cfg, table, x, out=np.zeros((10, 20), np.float64))
    with pytest.raises(ValueError, match="col needs out"):
        encode(cfg, table, x, col=1)
    with pytest.raises(ValueError, match="col must be an int"):
        encode(cfg, table, x, out=np.zeros((10, 20), np.float32), col=-1)
    ro = np.zeros((10, 20), np.float32)
    ro.flags.writeable = False
    with pytest.raises(ValueError, match="read-only"):
        encode(cfg, table, x, out=ro)


# ----------------------------------------------------------------------------------------------------
# Invalid inputs: the same contract as the reference
# ----------------------------------------------------------------------------------------------------


def test_invalid_inputs() -> None:
    cfg = SMALL2
    table = random_table(cfg, 20)
    with pytest.raises(ValueError, match="shape"):
        encode(cfg, table, np.zeros((3, 3), np.float32))
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match="finite"):
            encode(cfg, table, np.array([[0.5, 0.5], [0.5, bad]], np.float32))
    with pytest.raises(ValueError, match="table must be a float32 ndarray"):
        encode(cfg, table.astype(np.float64), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="table must be a float32 ndarray"):
        encode(cfg, table[:-1], np.zeros((1, 2)))
    with pytest.raises(TypeError, match="HashGridConfig"):
        encode(cfg.to_dict(), table, np.zeros((1, 2)))  # type: ignore[arg-type]


def test_int32_range_limit_matches_reference() -> None:
    # The finest scale of SMALL3 is ~23.6: floor(scale * x + 0.5) leaves the int32 range near x = 9.1e7.
    cfg = SMALL3
    table = random_table(cfg, 21)
    limit = 2.0**31 / float(level_scale(cfg, cfg.levels - 1))
    for v in np.float32(limit) + np.arange(-8, 9, dtype=np.float32) * np.spacing(np.float32(limit)):
        for sign in (1.0, -1.0):
            x = np.array([[0.5, 0.5, 0.5], [0.25, np.float32(sign * v), 0.5]], np.float32)
            try:
                want = encode_reference(cfg, table, x)
            except ValueError as e:
                with pytest.raises(ValueError, match="int32 range"):
                    encode(cfg, table, x)
                assert "int32 range" in str(e)
            else:
                np.testing.assert_array_equal(encode(cfg, table, x), want)


# ----------------------------------------------------------------------------------------------------
# Training shares the forward; the runtime imports without torch
# ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("cfg", [PAPER_POSITION, PAPER_DIRECTION, SMALL3, TINY2], ids=cfg_id)
def test_equals_train_forward(cfg: HashGridConfig) -> None:
    torch = pytest.importorskip("torch")
    from photon_fields.train.field.hashgrid import HashGridEncoding

    enc = HashGridEncoding(cfg, seed=3)
    with torch.no_grad():
        enc.table.copy_(torch.from_numpy(random_table(cfg, 22)))
    x = edge_points(cfg, np.random.default_rng(23))
    want = enc(torch.from_numpy(x)).detach().numpy()
    np.testing.assert_array_equal(encode(cfg, enc.table.detach().numpy(), x), want)


def test_runtime_imports_and_encodes_without_torch() -> None:
    code = (
        "import sys\n"
        "sys.modules['torch'] = None  # any 'import torch' now raises ImportError\n"
        "import numpy as np\n"
        "from photon_fields.models_spec.hashgrid import HashGridConfig, encode_reference, total_table_rows\n"
        "import photon_fields.runtime.field.hashgrid as rh\n"
        "cfg = HashGridConfig(2, 3, 2, 6, 4, 1.5)\n"
        "t = np.random.default_rng(0).random((total_table_rows(cfg), 2), dtype=np.float32)\n"
        "x = np.random.default_rng(1).random((50, 2), dtype=np.float32)\n"
        "assert np.array_equal(rh.encode(cfg, t, x), encode_reference(cfg, t, x))\n"
        "assert sys.modules['torch'] is None\n"
        "print('ok')\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"
