"""Residual ratio tracking against a control linear between stratified points (runtime.transport.residual_tracking):
the marched camera's picks' shadow rays. Its mean against a fine quadrature on rays through thin walls and a smooth
medium, with the default strata and with coarse ones, with and without the switch to the delta-tracked rest; its
noise against the ratio tracking it replaced."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import smooth_field

from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import Medium, build_medium, extinction_batch
from photon_fields.runtime.transport.residual_tracking import shadowed_light_batch
from photon_fields.runtime.transport.rng import stream_states
from photon_fields.runtime.transport.tracking import SHADOW_SWITCH, ratio_track_batch


def _medium(kind: str, density: float) -> Medium:
    """"walls": one voxel in six along each axis (a quarter of an optical depth across at ``density`` 4) in empty
    space; "smooth": the conftest's smooth field, no empty space. Opacity linear in the scalar."""
    if kind == "walls":
        on = np.arange(24) % 6 == 2
        field = (on[:, None, None] | on[None, :, None] | on[None, None, :]).astype(float)
    else:
        field = smooth_field(24)
    tf = TransferFunction(np.array([0.0, 1.0]), np.full((2, 3), 0.8), np.array([0.0, 1.0]), density, kind)
    return build_medium(make_volume(field, window=(0.0, 1.0), name=kind), tf)


def _ray(m: Medium, n: int, direction: tuple[float, float, float]) -> tuple[np.ndarray, ...]:
    """n copies of one ray from outside the box along ``direction``, clipped to the box (o at the entry)."""
    d = np.asarray(direction, dtype=np.float64)
    d /= np.linalg.norm(d)
    centre = m.bmin + 0.5 * m.bsize + np.array([0.013, -0.021, 0.007])
    t = np.max(m.bsize) * 2.0
    start = centre - t * d
    inv = np.where(d != 0.0, 1.0 / np.where(d != 0.0, d, 1.0), np.inf)
    lo, hi = (m.bmin - start) * inv, (m.bmin + m.bsize - start) * inv
    t0, t1 = np.max(np.minimum(lo, hi)), np.min(np.maximum(lo, hi))
    o = start + t0 * d
    return (np.tile(o[:, None], (1, n)), np.tile(d[:, None], (1, n)), np.zeros(n), np.full(n, t1 - t0))


def _transmittance(m: Medium, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, states: np.ndarray, per_depth: float,
                   longest: float, boost: float, switch: float) -> np.ndarray:
    """The residual tracker's estimates along the rays (o at the box's entry, d, length tmax), through the marched
    picks' shadow-ray stage: each ray a light direction and distance of weight (1, 0, 0)."""
    weight = np.zeros((3, o.shape[1]))
    weight[0] = 1.0
    return shadowed_light_batch(m, o, np.vstack([d, tmax[None, :]]), weight, states, per_depth, longest, boost,
                                switch)[0]


def _exact(m: Medium, o: np.ndarray, d: np.ndarray, length: float, steps: int = 20_000) -> float:
    t = (np.arange(steps) + 0.5) / steps * length
    return math.exp(-extinction_batch(m, o[:, :1] + t[None, :] * d[:, :1]).sum() * length / steps)


@pytest.mark.parametrize("strata", [(2.0, 2.0), (0.25, 8.0)])
@pytest.mark.parametrize("switch", [0.0, SHADOW_SWITCH])
@pytest.mark.parametrize(("kind", "density"), [("walls", 4.0), ("walls", 8.0), ("smooth", 2.0)])
def test_residual_transmittance_is_unbiased(kind: str, density: float, switch: float,
                                            strata: tuple[float, float]) -> None:
    """Two rays per medium (transmittance 0.006-0.6), 20000 estimates each: the mean is exp(-optical depth) of a
    20000-step midpoint sum
    (z < 4.5), with the camera walk's strata (two per majorant optical depth, two voxels at most) and with coarse
    ones (four majorant optical depths, eight voxels), with the delta-tracked rest below SHADOW_SWITCH and without."""
    m = _medium(kind, density)
    per_depth, voxels = strata
    longest = voxels * float(np.max(m.bsize)) / 24
    n = 20_000
    for i, direction in enumerate(((1.0, 0.13, 0.07), (0.6, -0.7, 0.4))):
        o, d, _, tmax = _ray(m, n, direction)
        exact = _exact(m, o, d, float(tmax[0]))
        tr = _transmittance(m, o, d, tmax, stream_states(11, i, n), per_depth, longest, 1.0, switch)
        assert 0.005 < exact < 0.7, exact
        assert abs(tr.mean() - exact) < 4.5 * tr.std() / math.sqrt(n) + 1e-12, (direction, tr.mean(), exact)


@pytest.mark.parametrize("density", [12.0, 16.0])
def test_residual_transmittance_has_less_noise_than_ratio_tracking(density: float) -> None:
    """Through thin walls of about an optical depth the linear control carries the attenuation: the residual tracker
    with events at the plain majorant has at most a fifth of the variance of ratio tracking at four times it (the
    picks' shadow rays before), both without the switch to the delta-tracked rest (measured 0.14 / 0.08; 0.66 / 0.42
    through walls of a quarter / half an optical depth, where ratio tracking's factors are close to 1 already)."""
    m = _medium("walls", density)
    longest = 2.0 * float(np.max(m.bsize)) / 24
    n = 20_000
    o, d, tmin, tmax = _ray(m, n, (1.0, 0.13, 0.07))
    rt = ratio_track_batch(m, o, d, tmin, tmax, stream_states(5, 0, n), 0.0, 4.0)
    res = _transmittance(m, o, d, tmax, stream_states(5, 1, n), 2.0, longest, 1.0, 0.0)
    assert res.var() < 0.2 * rt.var(), (res.var(), rt.var(), res.mean(), rt.mean())
