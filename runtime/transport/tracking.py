"""Free-flight sampling and transmittance estimation in heterogeneous media.

- **Delta tracking** (Woodcock et al. 1965; the paper's [51]) samples the distance to the next real
  collision: tentative collisions are drawn with the majorant, and accepted with probability
  ``sigma_t(x) / majorant``. The probability of escaping the medium equals the transmittance.
- **Ratio tracking** (Novak et al. 2014) estimates transmittance on shadow rays: the same tentative
  collisions, but the estimate is multiplied by ``1 - sigma_t / majorant`` instead of stopping.
  Once the estimate falls below ``RR_THRESHOLD`` it is Russian-rouletted (kept with probability 1/2,
  doubled), which keeps it unbiased while ending long shadow rays through dense media early.

- **Resampled collision** (the camera estimator ``forced`` of :mod:`runtime.wavefront.first_interaction`):
  the ratio-tracking walk, which also scores every tentative collision t_j with
  ``w_j = T_j sigma_t(t_j) / majorant`` (T_j: the walk's transmittance estimate before t_j) and keeps one of
  them with probability ``w_j / sum_k w_k`` (a weighted reservoir of size one). Tentative collisions are a
  Poisson process of rate majorant, so ``E[sum_j w_j f(t_j)] = integral T(t) sigma_t(t) f(t) dt`` for any f:
  ``W = sum_j w_j`` estimates the collision probability 1 - T(tmax), and W f(t_J) at the kept t_J estimates
  the integral with one evaluation of f. Derivation and measurements: docs/rendering.md.

All walk the majorant grid of :mod:`runtime.transport.medium` with a 3D DDA (Amanatides & Woo 1987) and use the
macrocell's local majorant, so empty macrocells are skipped in one step. The exponential's
memorylessness makes restarting the sampling at each macrocell boundary exact.

Kernels take one ray and return ``(value, rng_state)`` (``resampled_collision``: ``(t, W, T, rng_state)``);
``delta_track_batch``/``ratio_track_batch`` run them over structure-of-arrays ray batches (``o``/``d`` of
shape (3, n)). The interval [tmin, tmax] is clipped to the volume box first: outside it the medium is empty
(lookups clamp at the border, so an unclipped ray would otherwise see the border voxels extended to
infinity). :mod:`runtime.transport.tracking_numpy_baseline` is the
vectorized numpy baseline they are benchmarked and cross-checked against.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.transport.medium import Medium, extinction_at, intersect_box
from photon_fields.runtime.transport.rng import next_float

RR_THRESHOLD = 0.05
_DELTA, _RATIO, _RESAMPLE = 0, 1, 2


@njit(cache=True, inline="always")
def _axis_setup(o: float, d: float, bmin: float, cells_per_unit: float, n: int,
                t: float) -> tuple[int, int, float, float]:
    """DDA set-up on one axis: (cell, step, t_next_boundary, t_per_cell)."""
    p = (o + t * d - bmin) * cells_per_unit
    cell = min(max(int(math.floor(p)), 0), n - 1)
    if d > 0.0:
        return cell, 1, t + (cell + 1 - p) / (d * cells_per_unit), 1.0 / (d * cells_per_unit)
    if d < 0.0:
        return cell, -1, t + (cell - p) / (d * cells_per_unit), -1.0 / (d * cells_per_unit)
    return cell, 0, math.inf, math.inf


@njit(cache=True)
def _track(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
           tmax: float, state: np.uint64, mode: int) -> tuple[float, float, float, np.uint64]:
    """Shared DDA walk, returning (t, W, T, state).

    mode _DELTA: t = the real-collision distance (inf on escape). mode _RATIO: T = the transmittance estimate
    over [tmin, tmax]. mode _RESAMPLE: the ratio-tracking walk that also keeps one tentative collision t
    (inf if none scored) with W = sum of the scores (module docstring) and T its transmittance estimate."""
    t0, t1 = intersect_box(m, ox, oy, oz, dx, dy, dz)
    tmin = max(tmin, t0)
    tmax = min(tmax, t1)
    kept = math.inf
    w_sum = 0.0
    tr = 1.0
    if tmin >= tmax:
        return kept, w_sum, tr, state
    cx, cy, cz = m.majorant.shape
    ix, sx, nx_t, dx_t = _axis_setup(ox, dx, m.bmin[0], cx / m.bsize[0], cx, tmin)
    iy, sy, ny_t, dy_t = _axis_setup(oy, dy, m.bmin[1], cy / m.bsize[1], cy, tmin)
    iz, sz, nz_t, dz_t = _axis_setup(oz, dz, m.bmin[2], cz / m.bsize[2], cz, tmin)
    t = tmin
    while True:
        t_end = min(nx_t, ny_t, nz_t, tmax)
        maj = m.majorant[ix, iy, iz]
        if maj > 0.0:
            while True:
                state, u = next_float(state)
                t -= math.log(1.0 - u) / maj
                if t >= t_end:
                    break
                sigma = extinction_at(m, ox + t * dx, oy + t * dy, oz + t * dz)
                if mode == _DELTA:
                    state, u = next_float(state)
                    if u * maj < sigma:
                        return t, w_sum, tr, state
                    continue
                if mode == _RESAMPLE and sigma > 0.0:
                    w = tr * sigma / maj
                    w_sum += w
                    state, u = next_float(state)
                    if u * w_sum < w:
                        kept = t
                tr *= 1.0 - sigma / maj
                if tr < RR_THRESHOLD:
                    state, u = next_float(state)
                    if u < 0.5:
                        return kept, w_sum, 0.0, state
                    tr *= 2.0
        if t_end >= tmax:
            return kept, w_sum, tr, state
        t = t_end
        # Step into the neighbouring macrocell across the nearest boundary.
        if nx_t <= ny_t and nx_t <= nz_t:
            ix += sx
            nx_t += dx_t
            if ix < 0 or ix >= cx:
                break
        elif ny_t <= nz_t:
            iy += sy
            ny_t += dy_t
            if iy < 0 or iy >= cy:
                break
        else:
            iz += sz
            nz_t += dz_t
            if iz < 0 or iz >= cz:
                break
    return kept, w_sum, tr, state


@njit(cache=True)
def delta_track(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
                tmax: float, state: np.uint64) -> tuple[float, np.uint64]:
    """Distance to the next real collision in [tmin, tmax), or inf if the ray leaves without one."""
    t, _, _, state = _track(m, ox, oy, oz, dx, dy, dz, tmin, tmax, state, _DELTA)
    return t, state


@njit(cache=True)
def ratio_track(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
                tmax: float, state: np.uint64) -> tuple[float, np.uint64]:
    """Unbiased transmittance estimate over [tmin, tmax]."""
    _, _, tr, state = _track(m, ox, oy, oz, dx, dy, dz, tmin, tmax, state, _RATIO)
    return tr, state


@njit(cache=True)
def resampled_collision(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
                        tmax: float, state: np.uint64) -> tuple[float, float, float, np.uint64]:
    """One collision resampled from the ratio-tracking walk over [tmin, tmax] (module docstring):
    (t, W, T, state) with t the kept distance (inf if no tentative collision scored), W the estimate of
    1 - T(tmax) that weights it, T the estimate of T(tmax)."""
    return _track(m, ox, oy, oz, dx, dy, dz, tmin, tmax, state, _RESAMPLE)


@njit(cache=True, parallel=True)
def _track_batch(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray, states: np.ndarray,
                 mode: int) -> np.ndarray:
    n = o.shape[1]
    out = np.empty(n)
    for i in prange(n):
        t, _, tr, states[i] = _track(m, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i], tmin[i], tmax[i],
                                     states[i], mode)
        out[i] = t if mode == _DELTA else tr
    return out


def delta_track_batch(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray,
                      states: np.ndarray) -> np.ndarray:
    """Batch delta tracking over SoA rays (o, d: (3, n)); advances ``states`` in place."""
    return _track_batch(m, o, d, tmin, tmax, states, _DELTA)


def ratio_track_batch(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray,
                      states: np.ndarray) -> np.ndarray:
    """Batch ratio tracking over SoA rays; advances ``states`` in place."""
    return _track_batch(m, o, d, tmin, tmax, states, _RATIO)
