"""Transport building blocks: transmittance, free-flight sampling, majorants, energy conservation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import constant_tf, smooth_field

from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import _sparse_max_table, build_medium, extinction_batch, range_max
from photon_fields.runtime.transport.rng import stream_states
from photon_fields.runtime.transport.tracking import delta_track_batch, ratio_track_batch, task_stride


def _rays_through(m, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # noqa: ANN001
    """n rays: random origin inside the box, random direction; tmax = box exit."""
    from photon_fields.runtime.wavefront.rays import RayBatch, clip_rays_to_volume

    rng = np.random.default_rng(seed)
    o = (m.bmin[:, None] + rng.random((3, n)) * m.bsize[:, None])
    d = rng.normal(size=(3, n))
    d /= np.linalg.norm(d, axis=0)
    rays = RayBatch(np.zeros(n, dtype=np.int64), o.copy(), d, np.full(n, np.inf), np.ones((3, n)),
                    np.zeros(n, dtype=np.uint64), np.zeros(n, dtype=np.int64), np.full(n, np.inf))
    assert clip_rays_to_volume(m, rays).all()
    return rays.o, rays.d, np.zeros(n), rays.tmax


@pytest.mark.parametrize("length", [0.2, 0.5, 1.0])
def test_homogeneous_slab_transmittance(homogeneous_medium, length: float) -> None:  # noqa: ANN001
    """Along the x axis through a sigma_t = 3 box: P(escape) = mean ratio estimate = exp(-3 L)."""
    m = homogeneous_medium
    n = 100_000
    o = np.zeros((3, n))
    o[0] = -0.5
    d = np.zeros((3, n))
    d[0] = 1.0
    tmax = np.full(n, length)
    expected = math.exp(-3.0 * length)
    t = delta_track_batch(m, o, d, np.zeros(n), tmax, stream_states(7, 0, n))
    p_escape = np.isinf(t).mean()
    se = math.sqrt(expected * (1 - expected) / n)
    assert abs(p_escape - expected) < 5 * se
    # Collisions are exponentially distributed on [0, L): mean of a truncated exponential.
    hits = t[np.isfinite(t)]
    assert hits.max() < length
    mean_trunc = 1 / 3.0 - length * expected / (1 - expected)
    assert abs(hits.mean() - mean_trunc) < 5 * hits.std() / math.sqrt(hits.size)
    tr = ratio_track_batch(m, o, d, np.zeros(n), tmax, stream_states(8, 0, n))
    assert abs(tr.mean() - expected) < 5 * tr.std() / math.sqrt(n) + 1e-12


@pytest.mark.parametrize("boost", [1.0, 2.0, 4.0])
def test_boosted_ratio_tracking_keeps_the_mean_and_divides_the_variance(homogeneous_medium, boost: float) -> None:  # noqa: ANN001
    """Ratio tracking at ``boost`` times the majorant (the shadow rays', tracking.SHADOW_BOOST) through a
    homogeneous stretch of optical depth tau: mean exp(-tau), relative variance exp(tau^2 / (boost * tau_bar)) - 1
    with tau_bar the majorant's optical depth (tracking module docstring): 3.48 / 1.12 / 0.455 here."""
    m = homogeneous_medium
    n, length = 200_000, 0.5
    o = np.zeros((3, n))
    o[0] = -0.5
    d = np.zeros((3, n))
    d[0] = 1.0
    tau, tau_bar = 3.0 * length, float(m.majorant.max()) * length
    tr = ratio_track_batch(m, o, d, np.zeros(n), np.full(n, length), stream_states(8, 0, n), 0.0, boost)
    assert abs(tr.mean() - math.exp(-tau)) < 5 * tr.std() / math.sqrt(n)
    assert tr.var() / tr.mean() ** 2 == pytest.approx(math.exp(tau * tau / (boost * tau_bar)) - 1.0, rel=0.05)


def test_oblique_ray_transmittance(homogeneous_medium) -> None:  # noqa: ANN001
    """Diagonal rays cross many macrocell boundaries; the DDA must not change the answer."""
    m = homogeneous_medium
    n = 50_000
    d = np.tile(np.array([[1.0], [0.7], [0.4]]) / math.sqrt(1 + 0.49 + 0.16), (1, n))
    o = np.tile(np.array([[-0.5], [-0.35], [-0.2]]), (1, n))
    length = 0.5 / d[0, 0]  # leaves through x = 0 (still inside the box on y and z)
    tr = ratio_track_batch(m, o, d, np.zeros(n), np.full(n, length), stream_states(3, 0, n))
    assert tr.mean() == pytest.approx(math.exp(-3.0 * length), abs=5 * tr.std() / math.sqrt(n))


def _optical_depth(m, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, steps: int = 4000) -> np.ndarray:  # noqa: ANN001
    ts = (np.arange(steps) + 0.5) / steps
    tau = np.zeros(o.shape[1])
    for s in ts:
        t = s * tmax
        tau += extinction_batch(m, o + t * d) * tmax / steps
    return tau


def test_delta_and_ratio_tracking_agree_with_quadrature(smooth_volume) -> None:  # noqa: ANN001
    """Heterogeneous medium: for each of 16 rays, delta-tracking escape frequency, mean ratio-tracking
    estimate and exp(-optical depth) by fine quadrature agree."""
    m = build_medium(smooth_volume, constant_tf(6.0))
    o, d, tmin, tmax = _rays_through(m, 16, seed=2)
    expected = np.exp(-_optical_depth(m, o, d, tmax))
    reps = 20_000
    O, D = np.repeat(o, reps, axis=1), np.repeat(d, reps, axis=1)
    T0, T1 = np.repeat(tmin, reps), np.repeat(tmax, reps)
    escape = np.isinf(delta_track_batch(m, O, D, T0, T1, stream_states(1, 0, O.shape[1]))).reshape(16, reps)
    ratio = ratio_track_batch(m, O, D, T0, T1, stream_states(2, 0, O.shape[1])).reshape(16, reps)
    se_delta = np.sqrt(expected * (1 - expected) / reps) + 1e-9
    assert np.all(np.abs(escape.mean(1) - expected) < 5 * se_delta)
    se_ratio = ratio.std(1) / math.sqrt(reps) + 1e-9
    assert np.all(np.abs(ratio.mean(1) - expected) < 5 * se_ratio)


def test_majorant_bounds_extinction() -> None:
    """Every point's extinction is <= its macrocell majorant, on a rough random field with a TF peak."""
    rng = np.random.default_rng(0)
    vol = make_volume(rng.random((20, 13, 9)), spacing=(1.0, 1.5, 2.0), window=(0.0, 1.0))
    from photon_fields.runtime.scene.transfer import TransferFunction

    tf = TransferFunction(np.array([0.0, 0.43, 0.47, 1.0]), np.full((4, 3), 0.9), np.array([0.0, 1.0, 0.0, 0.2]), 40.0)
    m = build_medium(vol, tf, macrocell=4)
    p = m.bmin[:, None] + rng.random((3, 200_000)) * m.bsize[:, None]
    sigma = extinction_batch(m, p)
    cells = np.array(m.majorant.shape)
    idx = np.minimum((((p - m.bmin[:, None]) / m.bsize[:, None]) * cells[:, None]).astype(int), cells[:, None] - 1)
    bound = m.majorant[idx[0], idx[1], idx[2]]
    assert np.all(sigma <= bound)
    # ... and the bound is useful: no cell is more than a TF-peak away from its true max.
    assert m.majorant.max() <= 40.0 * (1 + 1e-5)


@pytest.mark.parametrize("n", [1, 2, 5, 1024, 1000])
def test_range_max_is_the_max_over_every_index_range(n: int) -> None:
    """The majorant's range-maximum query (a sparse table) equals a plain max over lut[lo : hi + 1] for random
    ranges, single entries and the whole table included, on table sizes that are and are not powers of two."""
    rng = np.random.default_rng(n)
    lut = rng.random(n) * 10.0
    lo = np.concatenate([rng.integers(0, n, 3000), [0, n - 1, 0]])
    hi = np.concatenate([np.minimum(n - 1, lo[:3000] + rng.integers(0, n, 3000)), [n - 1, n - 1, 0]])
    expected = np.array([lut[a : b + 1].max() for a, b in zip(lo, hi, strict=True)])
    np.testing.assert_array_equal(range_max(_sparse_max_table(lut), lo, hi), expected)


@pytest.mark.parametrize("macrocell", [1, 2, 4])
def test_majorant_grid_is_the_table_max_over_each_macrocells_scalar_range(macrocell: int) -> None:
    """The fused majorant pass equals its definition computed step by step: each macrocell's scalar range
    (``_cell_scalar_range``), its table indices (floor / ceil) and the table's max over them (``range_max``), times
    the safety factor, bit for bit (a noisy ramp through a narrow TF peak, grid sizes that macrocells do not
    divide)."""
    from photon_fields.runtime.scene.transfer import LUT_SIZE, TransferFunction
    from photon_fields.runtime.transport.medium import _MAJORANT_SAFETY, _cell_scalar_range, majorant_grid

    rng = np.random.default_rng(macrocell)
    ramp = np.linspace(0.0, 1.0, 21)[:, None, None] * np.ones((21, 14, 9))
    density = np.clip(ramp + 0.05 * rng.standard_normal(ramp.shape), 0.0, 1.0).astype(np.float32)
    tf = TransferFunction(np.array([0.0, 0.43, 0.47, 1.0]), np.full((4, 3), 0.9), np.array([0.0, 1.0, 0.0, 0.2]), 40.0)
    _, lut = tf.lut(LUT_SIZE)
    cells = -(-np.array(density.shape) // macrocell)
    smin, smax = _cell_scalar_range(density, *(int(c) for c in cells))
    lo = np.floor(smin * (len(lut) - 1)).astype(np.int64).ravel()
    hi = np.ceil(smax * (len(lut) - 1)).astype(np.int64).ravel()
    expected = (range_max(_sparse_max_table(lut), lo, hi) * _MAJORANT_SAFETY).reshape(smin.shape)
    assert expected.max() > expected.min() > 0.0
    np.testing.assert_array_equal(majorant_grid(density, lut, macrocell), expected)


def test_escape_probability_independent_of_macrocell_size(smooth_volume) -> None:  # noqa: ANN001
    tf = constant_tf(8.0)
    n = 200_000
    res = []
    for mc in (1, 4, 64):
        m = build_medium(smooth_volume, tf, macrocell=mc)
        o, d, tmin, tmax = _rays_through(m, n, seed=9)
        res.append(np.isinf(delta_track_batch(m, o, d, tmin, tmax, stream_states(mc, 0, n))).mean())
    se = math.sqrt(0.25 / n)
    assert max(res) - min(res) < 8 * se


def test_smooth_field_is_heterogeneous() -> None:
    f = smooth_field()
    assert f.min() > 0.09 and f.max() <= 1.0 and f.std() > 0.1


@pytest.mark.parametrize("tasks", [1, 2, 3, 4, 10, 97, 256, 1024, 1025])
def test_task_stride_permutes_the_blocks_and_spreads_each_half(tasks: int) -> None:
    """(t * stride) % tasks visits every block once, and either half of the tasks (what each of two threads gets)
    takes blocks from both halves of the items."""
    s = task_stride(tasks)
    blocks = [(t * s) % tasks for t in range(tasks)]
    assert sorted(blocks) == list(range(tasks))
    if tasks >= 10:
        first = np.array(blocks[: tasks // 2])
        assert 0.3 < np.mean(first < tasks // 2) < 0.7


def test_a_transfer_function_edit_reuses_the_volumes_scalar_ranges_and_gets_its_own_majorant() -> None:
    """build_medium keeps each macrocell's scalar range on the volume (they do not depend on the transfer function):
    a second function's medium on the same volume has the majorant of a cold build, bit for bit, not the first's."""
    from photon_fields.runtime.scene.transfer import TransferFunction
    from photon_fields.runtime.scene.volume import make_volume
    from photon_fields.runtime.transport.medium import build_medium

    rng = np.random.default_rng(7)
    raw = rng.random((19, 12, 10))
    vol = make_volume(raw)
    tfs = [TransferFunction(np.array([0.0, 0.5, 1.0]), np.full((3, 3), 0.9), np.array([0.0, 1.0, 0.0]), 30.0),
           TransferFunction(np.array([0.0, 0.8, 1.0]), np.full((3, 3), 0.9), np.array([0.5, 0.0, 1.0]), 60.0)]
    first = build_medium(vol, tfs[0])
    assert vol._majorant_ranges  # kept for the next edit
    second = build_medium(vol, tfs[1])
    cold = build_medium(make_volume(raw), tfs[1])
    np.testing.assert_array_equal(second.majorant, cold.majorant)
    np.testing.assert_array_equal(second.leap, cold.leap)
    assert not np.array_equal(second.majorant, first.majorant)


def test_the_macrocell_grows_with_large_volumes_only() -> None:
    """2-voxel macrocells up to 256 voxels a side (the embedded scenes' grids unchanged); beyond, the grid keeps to
    MAX_MACROCELLS_SIDE cells a side, and a medium built without a macrocell takes that one."""
    from photon_fields.runtime.scene.transfer import TransferFunction
    from photon_fields.runtime.scene.volume import make_volume
    from photon_fields.runtime.transport.medium import (
        DEFAULT_MACROCELL,
        MAX_MACROCELLS_SIDE,
        auto_macrocell,
        build_medium,
    )

    assert auto_macrocell((96, 96, 96)) == auto_macrocell((256, 31, 200)) == DEFAULT_MACROCELL == 2
    assert auto_macrocell((257, 4, 4)) == 3 and auto_macrocell((512, 512, 460)) == 4
    tf = TransferFunction(np.array([0.0, 1.0]), np.full((2, 3), 0.9), np.array([0.0, 1.0]), 10.0)
    vol = make_volume(np.random.default_rng(1).random((300, 8, 7)))
    m = build_medium(vol, tf)
    assert m.majorant.shape == (100, 3, 3) and max(m.majorant.shape) <= MAX_MACROCELLS_SIDE
    np.testing.assert_array_equal(m.majorant, build_medium(vol, tf, macrocell=3).majorant)
