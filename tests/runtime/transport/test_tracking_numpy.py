"""The numpy wavefront baseline (runtime.transport.tracking_numpy_baseline) against the numba kernels and quadrature.

- ``extinction_numpy`` equals ``runtime.transport.medium.extinction_batch`` (1e-12) inside, outside and on the box.
- ``next_float_numpy`` reproduces ``photon_fields.runtime.transport.rng`` streams bit for bit.
- Delta tracking: with a one-macrocell majorant grid both back ends draw the same numbers, so they must
  agree exactly; with the default grid they agree in distribution (escape probability = exp(-tau) by
  quadrature, mean collision distance), within a few standard errors.
- Ratio tracking: both back ends' means match exp(-tau) by quadrature.

The volume is a small smooth heterogeneous one (32^3 sin/cos pattern in an anisotropic box) with a
transfer function that leaves some empty space, so the majorant grid is genuinely non-uniform.
"""

from __future__ import annotations

import numpy as np
import pytest

from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import Medium, build_medium, extinction_batch
from photon_fields.runtime.transport.rng import stream_states, uniform_batch
from photon_fields.runtime.transport.tracking import (
    SHADOW_BOOST,
    SHADOW_SWITCH,
    delta_track_batch,
    ratio_track_batch,
)
from photon_fields.runtime.transport.tracking_numpy_baseline import (
    delta_track_numpy,
    extinction_numpy,
    next_float_numpy,
    ratio_track_numpy,
)

N_VOX = 32
Z_MAX = 4.5  # deterministic seeds; ~20 comparisons, so 4.5 sigma keeps a false alarm implausible


def _volume_and_tf() -> tuple:
    x = (np.arange(N_VOX) + 0.5) / N_VOX
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    raw = 0.5 + 0.5 * np.sin(2 * np.pi * 1.5 * X) * np.cos(2 * np.pi * Y) * np.sin(2 * np.pi * (Z + 0.3))
    vol = make_volume(raw, spacing=(1.0, 1.0, 1.5), window=(0.0, 1.0), name="sincos")
    # Zero extinction below s = 0.3 (empty voxels), up to 12 per unit length: the macrocell majorants
    # vary several-fold, so the numba DDA really uses local bounds while the numpy baseline uses the max.
    tf = TransferFunction(np.array([0.0, 0.3, 1.0]), np.full((3, 3), 0.9), np.array([0.0, 0.0, 1.0]), 12.0)
    return vol, tf


@pytest.fixture(scope="module")
def medium() -> Medium:
    return build_medium(*_volume_and_tf())


@pytest.fixture(scope="module")
def medium_one_cell() -> Medium:
    return build_medium(*_volume_and_tf(), macrocell=N_VOX)


def _box_rays(m: Medium, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays from a sphere around the box towards random interior points, clipped to the box:
    (o on the entry face, unit d, tmax = box exit distance)."""
    rng = np.random.default_rng(seed)
    centre = m.bmin + 0.5 * m.bsize
    v = rng.normal(size=(3, n))
    o = centre[:, None] + 1.5 * v / np.linalg.norm(v, axis=0)
    target = m.bmin[:, None] + rng.uniform(0.05, 0.95, size=(3, n)) * m.bsize[:, None]
    d = target - o
    d /= np.linalg.norm(d, axis=0)
    with np.errstate(divide="ignore"):
        inv = 1.0 / d
    ta = (m.bmin[:, None] - o) * inv
    tb = (m.bmin[:, None] + m.bsize[:, None] - o) * inv
    t0 = np.minimum(ta, tb).max(axis=0)
    t1 = np.maximum(ta, tb).min(axis=0)
    assert np.all(t0 < t1)  # every ray aims at an interior point
    return o + t0 * d, d, t1 - t0


def _optical_depth(m: Medium, o: np.ndarray, d: np.ndarray, tmax: np.ndarray,
                   steps: int = 20000) -> np.ndarray:
    """Midpoint-rule integral of sigma_t along each ray (the reference for transmittance)."""
    out = np.empty(o.shape[1])
    for r in range(o.shape[1]):
        t = (np.arange(steps) + 0.5) * (tmax[r] / steps)
        out[r] = extinction_numpy(m, o[:, r : r + 1] + t * d[:, r : r + 1]).sum() * (tmax[r] / steps)
    return out


def _repeat(a: np.ndarray, k: int) -> np.ndarray:
    """Each ray (column) repeated k times, contiguous per ray."""
    return np.ascontiguousarray(np.repeat(a, k, axis=-1))


# --- lookups and random numbers --------------------------------------------------------------------


def test_test_medium_has_nonuniform_majorants(medium: Medium) -> None:
    assert medium.majorant.size > 1
    assert medium.majorant.max() > 2.0 * medium.majorant.min()


def test_extinction_matches_numba(medium: Medium) -> None:
    m = medium
    rng = np.random.default_rng(1)
    lo, hi = m.bmin, m.bmin + m.bsize
    pad = 0.2 * m.bsize
    inside = lo[:, None] + rng.uniform(0, 1, (3, 5000)) * m.bsize[:, None]
    around = (lo - pad)[:, None] + rng.uniform(0, 1, (3, 5000)) * (m.bsize + 2 * pad)[:, None]
    # Points on the faces, edges and corners, and exactly on voxel centres / faces (index boundaries).
    faces = inside[:, :600].copy()
    for a in range(3):
        faces[a, a * 200 : a * 200 + 100] = lo[a]
        faces[a, a * 200 + 100 : a * 200 + 200] = hi[a]
    corners = np.array(np.meshgrid(*[[lo[a], hi[a]] for a in range(3)], indexing="ij")).reshape(3, -1)
    k = rng.integers(0, 2 * N_VOX + 1, size=(3, 2000))
    grid = lo[:, None] + k / (2 * N_VOX) * m.bsize[:, None]
    p = np.ascontiguousarray(np.concatenate([inside, around, faces, corners, grid], axis=1))
    ref = extinction_batch(m, p)
    np.testing.assert_allclose(extinction_numpy(m, p), ref, rtol=0, atol=1e-12)
    assert ref.max() > 1.0 and (ref == 0).any()  # the test volume is really heterogeneous


def test_next_float_reproduces_numba_streams() -> None:
    s_np = stream_states(12345, 7, 4096)
    s_nb = s_np.copy()
    u_np = np.stack([next_float_numpy(s_np) for _ in range(6)], axis=1)
    u_nb = uniform_batch(s_nb, 6)
    np.testing.assert_array_equal(u_np, u_nb)
    np.testing.assert_array_equal(s_np, s_nb)
    assert u_np.min() >= 0.0 and u_np.max() < 1.0
    with pytest.raises(TypeError):
        next_float_numpy(np.zeros(3, dtype=np.int64))


# --- delta tracking -------------------------------------------------------------------------------


def test_delta_tracking_identical_with_one_macrocell(medium_one_cell: Medium) -> None:
    """One macrocell: the DDA has nothing to step through, so both draw the same numbers in order."""
    m = medium_one_cell
    assert m.majorant.shape == (1, 1, 1)
    o, d, tmax = _box_rays(m, 3000, seed=2)
    s_nb = stream_states(3, 0, o.shape[1])
    s_np = s_nb.copy()
    t_nb = delta_track_batch(m, o, d, np.zeros(o.shape[1]), tmax, s_nb)
    t_np = delta_track_numpy(m, o, d, 0.0, tmax, s_np)
    # numpy's vectorized log and math.log may differ by an ulp, hence the relative tolerance. A ray whose
    # tentative collision lands within rounding of the box exit could be decided differently (the DDA's
    # exit distance and tmax are computed differently), so allow a couple of such rays.
    close = np.isclose(t_nb, t_np, rtol=1e-12, atol=0.0)  # inf == inf counts as close
    same = close & (s_nb == s_np)
    assert same.sum() >= o.shape[1] - 2
    assert np.isfinite(t_np).any() and np.isinf(t_np).any()


def test_delta_tracking_respects_interval(medium: Medium) -> None:
    o, d, tmax = _box_rays(medium, 2000, seed=4)
    tmin = 0.3 * tmax
    tend = 0.8 * tmax
    t = delta_track_numpy(medium, o, d, tmin, tend, stream_states(5, 0, o.shape[1]))
    hit = np.isfinite(t)
    assert hit.any()
    assert np.all(t[hit] >= tmin[hit]) and np.all(t[hit] < tend[hit])


def test_delta_tracking_agrees_statistically(medium: Medium) -> None:
    m = medium
    n_rays, k = 8, 20000
    o, d, tmax = _box_rays(m, n_rays, seed=6)
    tau = _optical_depth(m, o, d, tmax)
    assert tau.min() < 1.0 and tau.max() > 3.0  # a spread of thin and thick rays
    O, D, T = _repeat(o, k), _repeat(d, k), _repeat(tmax, k)
    n = n_rays * k
    t_nb = delta_track_batch(m, O, D, np.zeros(n), T, stream_states(7, 0, n)).reshape(n_rays, k)
    t_np = delta_track_numpy(m, O, D, 0.0, T, stream_states(8, 0, n)).reshape(n_rays, k)
    esc_nb = np.isinf(t_nb).mean(axis=1)
    esc_np = np.isinf(t_np).mean(axis=1)
    p_ref = np.exp(-tau)
    # Escape probability = transmittance, for each back end against the quadrature and each other.
    se = np.sqrt(p_ref * (1 - p_ref) / k) + 1e-4
    assert np.all(np.abs(esc_np - p_ref) < Z_MAX * se), (esc_np, p_ref)
    assert np.all(np.abs(esc_nb - p_ref) < Z_MAX * se), (esc_nb, p_ref)
    assert np.all(np.abs(esc_np - esc_nb) < Z_MAX * np.sqrt(2) * se)
    # Mean collision distance of the rays that collided (Welch z-score per ray).
    for r in range(n_rays):
        a = t_np[r][np.isfinite(t_np[r])]
        b = t_nb[r][np.isfinite(t_nb[r])]
        if min(a.size, b.size) < 50:
            continue
        se_ab = np.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
        assert abs(a.mean() - b.mean()) < Z_MAX * se_ab + 1e-12, (r, a.mean(), b.mean())


# --- ratio tracking -------------------------------------------------------------------------------


@pytest.mark.parametrize(("switch", "boost"), [(0.0, 1.0), (SHADOW_SWITCH, 1.0), (0.9, 1.0), (0.0, 3.5),
                                               (SHADOW_SWITCH, SHADOW_BOOST)])
def test_ratio_tracking_matches_quadrature(medium: Medium, switch: float, boost: float) -> None:
    """Also with the rest of the ray by delta tracking below ``switch`` (the shadow rays' estimator; 0.9: almost
    all of every ray) and with tentative collisions at ``boost`` times the majorant before it, the rest at the
    plain one: both must keep the mean."""
    m = medium
    n_rays, k = 6, 5000
    o, d, tmax = _box_rays(m, n_rays, seed=9)
    ref = np.exp(-_optical_depth(m, o, d, tmax))
    O, D, T = _repeat(o, k), _repeat(d, k), _repeat(tmax, k)
    n = n_rays * k
    tr_nb = ratio_track_batch(m, O, D, np.zeros(n), T, stream_states(10, 0, n), switch, boost)
    tr_nb = tr_nb.reshape(n_rays, k)
    tr_np = ratio_track_numpy(m, O, D, 0.0, T, stream_states(11, 0, n)).reshape(n_rays, k)
    assert np.all((tr_np >= 0) & (tr_np <= 1))
    for est in (tr_np, tr_nb):
        se = est.std(axis=1, ddof=1) / np.sqrt(k) + 1e-6
        assert np.all(np.abs(est.mean(axis=1) - ref) < Z_MAX * se), (est.mean(axis=1), ref)
    se_ab = np.sqrt(tr_np.var(axis=1, ddof=1) / k + tr_nb.var(axis=1, ddof=1) / k) + 1e-6
    assert np.all(np.abs(tr_np.mean(axis=1) - tr_nb.mean(axis=1)) < Z_MAX * se_ab)


def test_empty_medium_is_transparent() -> None:
    vol, tf = _volume_and_tf()
    empty = TransferFunction(tf.points, tf.albedo, np.zeros(3), tf.density_scale)
    m = build_medium(vol, empty)
    o, d, tmax = _box_rays(m, 50, seed=12)
    s = stream_states(13, 0, 50)
    before = s.copy()
    assert np.all(np.isinf(delta_track_numpy(m, o, d, 0.0, tmax, s)))
    assert np.all(ratio_track_numpy(m, o, d, 0.0, tmax, s) == 1.0)
    np.testing.assert_array_equal(s, before)  # no random number drawn, as in the numba kernels


def test_interval_is_clipped_to_the_box() -> None:
    """Unclipped rays (origin outside, tmax = inf) only see the medium inside the box, and rays that
    miss it draw no random numbers."""
    vol = make_volume(np.ones((8, 8, 8)), window=(0.0, 1.0))
    sigma = 1.5
    m = build_medium(vol, TransferFunction(np.array([0.0, 1.0]), np.full((2, 3), 0.9), np.ones(2), sigma))
    n = 20000
    o = np.zeros((3, n))
    o[0] = -2.0  # 1.5 in front of the box, then 1.0 of medium
    d = np.zeros((3, n))
    d[0] = 1.0
    k = np.exp(-sigma)
    se = np.sqrt(k * (1 - k) / n)
    t = delta_track_numpy(m, o, d, 0.0, np.inf, stream_states(14, 0, n))
    assert abs(np.isinf(t).mean() - k) < Z_MAX * se
    assert np.all(t[np.isfinite(t)] >= 1.5)
    assert abs(ratio_track_numpy(m, o, d, 0.0, np.inf, stream_states(15, 0, n)).mean() - k) < Z_MAX * se
    miss = np.array([[-2.0], [2.0], [0.0]])
    s = stream_states(16, 0, 1)
    before = s.copy()
    assert np.isinf(delta_track_numpy(m, miss, np.array([[1.0], [0.0], [0.0]]), 0.0, np.inf, s)[0])
    np.testing.assert_array_equal(s, before)
