"""Empty-space leaping (runtime.transport.medium.leap_distances, the walk in runtime.transport.tracking).

Leaping must change no sample: every tracker gives bit-identical distances, weights, transmittances and random
states whether it leaps over empty macrocells or steps through them one by one (``build_medium(leap=False)``),
on sparse media with structure at the macrocell scale, for rays entering from outside, rays starting inside
(shadow rays), axis-parallel rays and rays that stop early. The leap table itself is checked against brute force.
"""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from photon_fields.runtime.scene.scene import builtin_scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import LEAP_CAP, Medium, build_medium, leap_distances
from photon_fields.runtime.transport.rng import stream_states
from photon_fields.runtime.transport.tracking import _DELTA, _RATIO, _RESAMPLE, _track, _track_batch


def _sparse_media(macrocell: int) -> tuple[Medium, Medium]:
    """A random field thresholded by the transfer function (zero extinction below 0.62): isolated features and
    empty space at every scale; anisotropic spacing so the box is not a cube."""
    rng = np.random.default_rng(5)
    raw = rng.random((13, 11, 15)) ** 3
    raw = np.kron(raw, np.ones((3, 3, 3)))[:37, :30, :41]
    vol = make_volume(raw, spacing=(1.0, 1.3, 0.8), window=(0.0, 1.0), name="sparse")
    tf = TransferFunction(np.array([0.0, 0.62, 1.0]), np.full((3, 3), 0.8), np.array([0.0, 0.0, 1.0]), 30.0)
    return build_medium(vol, tf, macrocell), build_medium(vol, tf, macrocell, leap=False)


def _rays(m: Medium, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A mix: rays from outside aimed into the box, rays starting inside (shadow rays, also with tmin > 0),
    axis-parallel rays and rays cut short by tmax."""
    rng = np.random.default_rng(seed)
    centre, size = m.bmin + 0.5 * m.bsize, m.bsize
    o = np.empty((3, n))
    d = rng.normal(size=(3, n))
    quarter = n // 4
    v = rng.normal(size=(3, quarter))
    o[:, :quarter] = centre[:, None] + 1.2 * size.max() * v / np.linalg.norm(v, axis=0)
    target = m.bmin[:, None] + rng.random((3, quarter)) * size[:, None]
    d[:, :quarter] = target - o[:, :quarter]
    o[:, quarter:] = m.bmin[:, None] + rng.random((3, n - quarter)) * size[:, None]
    axis = rng.integers(0, 3, size=quarter)  # axis-parallel rays from inside
    d[:, quarter : 2 * quarter] = 0.0
    d[axis, quarter + np.arange(quarter)] = rng.choice([-1.0, 1.0], size=quarter)
    d[2, 2 * quarter : 2 * quarter + quarter // 2] = 0.0  # rays in a z plane
    d /= np.linalg.norm(d, axis=0)
    tmin = np.where(rng.random(n) < 0.2, rng.random(n) * 0.3 * size.max(), 0.0)
    tmax = np.where(rng.random(n) < 0.3, tmin + rng.random(n) * size.max(), np.inf)
    return np.ascontiguousarray(o), np.ascontiguousarray(d), tmin, tmax


@njit  # not cached: _track is inlined, and a cached caller would not see it change
def _walk_all(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray, states: np.ndarray,
              mode: int) -> np.ndarray:
    """Every output of the walk (t, W, T, state as float bits) per ray."""
    out = np.empty((4, o.shape[1]))
    for i in range(o.shape[1]):
        t, w, tr, s = _track(m, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i], tmin[i], tmax[i], states[i],
                             mode)
        out[0, i], out[1, i], out[2, i], out[3, i] = t, w, tr, float(s >> np.uint64(11))
    return out


@pytest.mark.parametrize("macrocell", [1, 2, 3])
@pytest.mark.parametrize("mode", [_DELTA, _RATIO, _RESAMPLE])
def test_leaping_changes_no_sample(macrocell: int, mode: int) -> None:
    leaping, stepping = _sparse_media(macrocell)
    assert (leaping.leap.max() > 2) and (stepping.leap.max() == 1)  # the walk really leaps, far
    o, d, tmin, tmax = _rays(leaping, 20_000, seed=macrocell)
    states = stream_states(11, 0, o.shape[1])
    a = _walk_all(leaping, o, d, tmin, tmax, states, mode)
    b = _walk_all(stepping, o, d, tmin, tmax, states, mode)
    np.testing.assert_array_equal(a, b)
    # The media interact: the comparison is not one of empty walks.
    assert (a[2] < 1.0).mean() > 0.05 if mode == _RATIO else np.isfinite(a[0]).mean() > 0.05


@pytest.mark.parametrize("name", ["vortex", "shell"])
def test_leaping_changes_no_sample_on_embedded_scenes(name: str) -> None:
    scene = builtin_scene(name, resolution=48)
    leaping, stepping = (build_medium(scene.volume, scene.tf, leap=flag) for flag in (True, False))
    o, d, tmin, tmax = _rays(leaping, 20_000, seed=3)
    for mode in (_DELTA, _RESAMPLE):
        states = stream_states(4, 0, o.shape[1])
        np.testing.assert_array_equal(_walk_all(leaping, o, d, tmin, tmax, states, mode),
                                      _walk_all(stepping, o, d, tmin, tmax, states, mode))
    t = _track_batch(leaping, o, d, tmin, tmax, stream_states(4, 0, o.shape[1]), _DELTA)
    assert np.isfinite(t).any()


def _largest_empty_cube(occupied: np.ndarray, c: tuple[int, int, int], signs: tuple[int, int, int]) -> int:
    """Brute force: the largest r such that the r^3 cells from c towards ``signs`` hold no occupied cell (cells
    beyond the grid count as empty), capped at LEAP_CAP."""
    n = np.array(occupied.shape)
    r = 0
    while r < LEAP_CAP:
        lo = [c[a] if signs[a] > 0 else c[a] - r for a in range(3)]
        hi = [c[a] + r + 1 if signs[a] > 0 else c[a] + 1 for a in range(3)]
        block = occupied[max(lo[0], 0) : min(hi[0], n[0]), max(lo[1], 0) : min(hi[1], n[1]),
                         max(lo[2], 0) : min(hi[2], n[2])]
        if block.any():
            return r
        r += 1
        if all(lo[a] < 0 or hi[a] > n[a] for a in range(3)):  # the cube covers the grid to its far corner
            return LEAP_CAP
    return r


def test_leap_table_is_the_largest_empty_cube_per_octant() -> None:
    rng = np.random.default_rng(2)
    majorant = np.where(rng.random((9, 7, 8)) < 0.04, rng.random((9, 7, 8)) + 0.1, 0.0)
    table = leap_distances(majorant)
    occupied = majorant > 0
    for o in range(8):
        signs = (1 if o & 1 else -1, 1 if o & 2 else -1, 1 if o & 4 else -1)
        for c in np.ndindex(*majorant.shape):
            assert table[(o, *c)] == _largest_empty_cube(occupied, c, signs), (o, c)
    assert np.array_equal(leap_distances(majorant, leap=False), np.minimum(table, 1))
    assert np.all(leap_distances(np.zeros((3, 4, 5))) == LEAP_CAP)  # nothing to hit: leave in one leap
