"""Eq. 6 / Eq. 7 target encoding and the field's input conventions (models_spec.encoding), numpy vs torch."""

from __future__ import annotations

import json

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from photon_fields.models_spec.encoding import (  # noqa: E402
    DEFAULT_PSI,
    FieldConfig,
    cubic_bspline,
    decode_radiance,
    direction_gains,
    direction_input,
    encode_radiance,
    normalize_position,
    phase_features,
    phase_input,
)
from photon_fields.models_spec.hashgrid import HashGridConfig, direction_to_unit_square  # noqa: E402

torch = pytest.importorskip("torch")
from photon_fields.train.field.network import decode_radiance_torch, encode_radiance_torch  # noqa: E402  (after the torch skip)

PSIS = (4.0, DEFAULT_PSI, 6.0)


def test_default_psi_is_in_the_papers_range() -> None:
    assert 4.0 <= DEFAULT_PSI <= 6.0


@pytest.mark.parametrize("psi", PSIS)
def test_round_trip_above_the_threshold(psi: float) -> None:
    rng = np.random.default_rng(0)
    lum = 10.0 ** rng.uniform(-psi, 3.0, 200_000)
    L = np.concatenate([lum[lum > 10.0**-psi], [1e3, 1.0, 10.0 ** (-psi) * 1.0001]])
    enc = encode_radiance(L, psi)
    assert enc.dtype == np.float32
    assert np.all(enc < 1.0) and np.all(enc >= -3.0 / psi - 1e-6)  # (10^-psi, 1e3] -> [-3/psi, 1)
    back = decode_radiance(enc, psi)
    # One float32 rounding of L' (relative 6e-8 of |L'| <= 1) is ln(10) psi 6e-8 relative in L, plus
    # the final float32 rounding: 2e-6 is a few ulps of slack.
    np.testing.assert_allclose(back, L, rtol=2e-6)


@pytest.mark.parametrize("psi", PSIS)
def test_eq6_values(psi: float) -> None:
    enc = encode_radiance(np.array([1.0, 0.1, 10.0, 10.0 ** (1 - psi)]), psi)
    np.testing.assert_allclose(enc, [0.0, 1.0 / psi, -1.0 / psi, 1.0 - 1.0 / psi], rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("psi", PSIS)
def test_values_at_or_below_the_threshold_encode_to_one(psi: float) -> None:
    low = np.array([10.0**-psi, 0.5 * 10.0**-psi, 1e-30, 0.0, -0.0, -1.0, -np.inf, np.nan])
    enc = encode_radiance(low, psi)
    assert np.array_equal(enc, np.ones_like(enc))
    dec = decode_radiance(enc, psi)
    assert np.array_equal(dec, np.full(low.shape, np.float32(10.0**-psi)))  # "clamped to zero": 10^-psi


def test_decode_is_not_clamped() -> None:
    # L' > 1 (a network overshoot) decodes darker still, L' < 0 brighter than 1.
    dec = decode_radiance(np.array([1.2, -0.4]), 5.0)
    np.testing.assert_allclose(dec, [1e-6, 100.0], rtol=1e-6)


@pytest.mark.parametrize("psi", PSIS)
def test_torch_matches_numpy_bit_for_bit(psi: float) -> None:
    rng = np.random.default_rng(1)
    L = np.concatenate([10.0 ** rng.uniform(-psi - 2, 4.0, 100_000), rng.random(1000),
                        [0.0, -1.0, np.nan, np.inf, 10.0**-psi, 1.0, 1e3]])
    for dtype in (np.float64, np.float32):
        Ld = L.astype(dtype)
        assert np.array_equal(encode_radiance_torch(torch.from_numpy(Ld), psi).numpy(), encode_radiance(Ld, psi))
    Lp = np.concatenate([rng.uniform(-1.0, 1.5, 100_000), [0.0, 1.0, -0.6]]).astype(np.float32)
    assert np.array_equal(decode_radiance_torch(torch.from_numpy(Lp), psi).numpy(), decode_radiance(Lp, psi))


def test_bad_psi_is_refused() -> None:
    for psi in (0.0, -1.0, float("nan"), 40.0):
        with pytest.raises(ValueError, match="psi"):
            encode_radiance(np.ones(2), psi)


def test_position_and_direction_inputs() -> None:
    bmin, bsize = np.array([-0.5, -0.25, -0.4]), np.array([1.0, 0.5, 0.8])
    corners = np.array([bmin, bmin + bsize, bmin + 0.5 * bsize])
    np.testing.assert_array_equal(normalize_position(corners, bmin, bsize),
                                  np.array([[0, 0, 0], [1, 1, 1], [0.5, 0.5, 0.5]], np.float32))
    assert normalize_position(corners, bmin, bsize).dtype == np.float32
    d = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert np.array_equal(direction_input(d), direction_to_unit_square(d))
    np.testing.assert_allclose(direction_input(d)[:, 0], [0.0, 1.0, 0.5, 0.5], atol=1e-7)
    assert phase_input(0.75, 3).shape == (3, 1) and phase_input(np.array([0.1, 0.2])).shape == (2, 1)


def test_field_config_round_trip_and_validation() -> None:
    cfg = FieldConfig(HashGridConfig(3, 8, 2, 15, 16, 1.5), HashGridConfig(2, 4, 2, 12, 4, 2.0), 32, 2, 5.0,
                      (-0.75, 0.0, 0.75))
    assert cfg.input_dims == 16 + 8 + 1
    again = FieldConfig.from_dict(json.loads(json.dumps(cfg.to_dict())))
    assert again == cfg
    with pytest.raises(ValueError, match="3-D"):
        FieldConfig(position=HashGridConfig(2, 4, 2, 12, 4, 2.0))
    with pytest.raises(ValueError, match="hidden_layers"):
        FieldConfig(hidden_layers=0)
    with pytest.raises(ValueError, match="phases"):
        FieldConfig(phases=(1.5,))
    bad = cfg.to_dict() | {"extra": 1}
    with pytest.raises(ValueError, match="unknown keys"):
        FieldConfig.from_dict(bad)
    with pytest.raises(ValueError, match="version"):
        FieldConfig.from_dict(cfg.to_dict() | {"version": 99})


def test_phase_features_tents_interpolate_between_the_phases() -> None:
    phases = (0.75, -0.75, 0.0, -0.375, 0.375)  # any order: column 1 + j is the tent of phases[j]
    g = np.array([-1.0, -0.75, -0.6, -0.375, 0.1, 0.375, 0.74, 0.75, 1.0])
    f = phase_features(g, phases, "tent")
    assert f.shape == (9, 6) and f.dtype == np.float32
    np.testing.assert_array_equal(f[:, 0], g.astype(np.float32))
    np.testing.assert_allclose(f[:, 1:].sum(axis=1), 1.0, atol=1e-6)  # a partition of unity
    for j, gj in enumerate(phases):  # 1 at its own phase, 0 at every other
        at = phase_features(np.array(phases), phases, "tent")[:, 1 + j]
        np.testing.assert_array_equal(at, (np.array(phases) == gj).astype(np.float32))
    # -0.6 is 40 % of the way from -0.75 to -0.375: weights 0.6 and 0.4, nothing else
    np.testing.assert_allclose(f[2, 1:], [0.0, 0.6, 0.0, 0.4, 0.0], atol=1e-6)
    np.testing.assert_allclose(f[0, 1:], [0.0, 1.0, 0.0, 0.0, 0.0])  # beyond the ends: the end phase
    np.testing.assert_allclose(f[8, 1:], [1.0, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(phase_features(g, phases, "scalar"), g.astype(np.float32).reshape(-1, 1))
    np.testing.assert_array_equal(phase_features(g, (0.2,), "tent")[:, 1], 1.0)
    with pytest.raises(ValueError, match="phase encoding"):
        phase_features(g, phases, "onehot")


def test_phase_features_splines_are_smooth_cubic_b_spline_weights() -> None:
    phases = tuple(np.linspace(-0.75, 0.75, 7).round(6))  # h = 0.25
    g = np.linspace(-1.0, 1.0, 2001)
    f = phase_features(g, phases, "spline").astype(np.float64)
    assert f.shape == (2001, 8)
    np.testing.assert_array_equal(f[:, 0], g.astype(np.float32))
    np.testing.assert_allclose(f[:, 1:].sum(axis=1), 1.0, atol=1e-6)  # a partition of unity, ends included
    w = phase_features(np.array([0.0, 0.125, -0.75, -0.9]), phases, "spline")[:, 1:].astype(np.float64)
    np.testing.assert_allclose(w[0], [0, 0, 1 / 6, 2 / 3, 1 / 6, 0, 0], atol=1e-7)  # at a node
    b_half, b_one_half = 2 / 3 - 0.25 + 0.0625, 0.5**3 / 6  # B(1/2), B(3/2): half-way between two nodes
    np.testing.assert_allclose(w[1], [0, 0, b_one_half, b_half, b_half, b_one_half, 0], atol=1e-7)
    np.testing.assert_allclose(w[2], [5 / 6, 1 / 6, 0, 0, 0, 0, 0], atol=1e-7)  # the node outside folded in
    np.testing.assert_allclose(w[3], w[2], atol=1e-7)  # beyond the ends: clamped
    # Cubic B-splines reproduce linear functions away from the ends: sum_j G_j w_j(g) = g.
    inner = (g >= -0.5) & (g <= 0.5)
    np.testing.assert_allclose(f[inner, 1:] @ np.array(phases), g[inner], atol=1e-6)
    # Smooth (C1) over G where tents have kinks: the slope changes by O(dg) between neighbouring g, also at the
    # nodes (a tent's slope jumps by 2 / h = 8 there). Only beyond the ends, where g is clamped, it stops.
    dg = g[1] - g[0]
    slope = np.diff(f[(g >= -0.75) & (g <= 0.75), 1:], axis=0) / dg
    assert np.max(np.abs(np.diff(slope, axis=0))) < 3 * dg / 0.25**2
    with pytest.raises(ValueError, match="evenly spaced"):
        phase_features(g, (-0.75, 0.0, 0.5), "spline")
    with pytest.raises(ValueError, match="increasing"):
        phase_features(g, (0.5, 0.0, -0.5), "spline")
    with pytest.raises(ValueError, match="FieldConfig.phases: .*evenly spaced"):
        FieldConfig(phases=(-0.75, 0.0, 0.5), phase_encoding="spline")
    cfg = FieldConfig(phases=phases, phase_encoding="spline")
    assert cfg.phase_dims == 8 and FieldConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg


def test_spline_weights_equal_b_at_every_node_bit_for_bit() -> None:
    """The spline weights evaluate B only at the four nodes around g; they must equal B(t - j) at every node j (with
    the nodes outside G folded into the end columns) bit for bit, also at nodes, at the ends, beyond them and for
    non-finite g: the definition, evaluated densely here."""
    rng = np.random.default_rng(1)
    for phases in (tuple(np.linspace(-0.8, 0.8, 16)), tuple(np.linspace(-0.75, 0.75, 7).round(6)), (-0.5, 0.5)):
        p = np.asarray(phases)
        g = np.concatenate([rng.uniform(-1.2, 1.2, 20000), p, (p[:-1] + p[1:]) / 2, [np.nan, -np.inf, np.inf]])
        t = (np.clip(g, p[0], p[-1]) - p[0]) / ((p[-1] - p[0]) / (p.size - 1))
        dense = cubic_bspline(t[:, None] - np.arange(p.size)[None, :])
        dense[:, 0] += cubic_bspline(t + 1.0)
        dense[:, -1] += cubic_bspline(t - p.size)
        fast = phase_features(g, phases, "spline")[:, 1:]
        np.testing.assert_array_equal(fast.view(np.int32), dense.astype(np.float32).view(np.int32))


def test_field_config_phase_encoding() -> None:
    scalar = FieldConfig(phases=(-0.75, 0.0, 0.75))
    tent = FieldConfig(phases=(-0.75, 0.0, 0.75), phase_encoding="tent")
    assert tent.input_dims == scalar.input_dims + 3 and tent.phase_dims == 4 and scalar.phase_dims == 1
    assert "phase_encoding" not in scalar.to_dict()  # configs written before the field existed read unchanged
    assert FieldConfig.from_dict(json.loads(json.dumps(tent.to_dict()))) == tent
    assert FieldConfig.from_dict(scalar.to_dict()) == scalar
    with pytest.raises(ValueError, match="phase_encoding"):
        FieldConfig(phase_encoding="onehot")


def test_field_config_direction_gain() -> None:
    """"g" round-trips through the dict, "none" leaves no key (older configs read unchanged), anything else is
    refused; the gains are g itself (float32, one column) or None."""
    plain = FieldConfig(phases=(-0.75, 0.0, 0.75))
    gained = FieldConfig(phases=(-0.75, 0.0, 0.75), direction_gain="g")
    assert plain.direction_gain == "none" and "direction_gain" not in plain.to_dict()
    assert gained.to_dict()["direction_gain"] == "g" and gained.input_dims == plain.input_dims
    assert FieldConfig.from_dict(json.loads(json.dumps(gained.to_dict()))) == gained
    with pytest.raises(ValueError, match="direction_gain"):
        FieldConfig(direction_gain="abs")
    g = np.array([-0.5, 0.0, 0.75])
    np.testing.assert_array_equal(direction_gains(g, "g"), g.astype(np.float32).reshape(-1, 1))
    assert direction_gains(g, "none") is None
    with pytest.raises(ValueError, match="direction gain"):
        direction_gains(g, "abs")
