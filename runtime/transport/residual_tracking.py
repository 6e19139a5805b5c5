"""Residual ratio tracking against a control linear between stratified points: the marched camera walk's
transmittance (:mod:`photon_fields.runtime.wavefront.marched_camera`) and its picks' shadow rays.

Parameters (arguments of :func:`residual_transmittance`)
--------------------------------------------------------
per_depth : float
    Strata per unit of majorant optical depth (the camera walk's ``STRATA_PER_DEPTH``).
longest : float
    The longest stratum, in world units (the camera walk's two voxels, or 1/48 of the box).
boost : float
    The residual events at this many times the majorant.
switch : float
    Below this transmittance estimate the rest of the ray is one delta-tracking flight (``SHADOW_SWITCH``).

Novak et al. (2014): with a control extinction sigma_c along the ray that does not depend on the events,

    T^(t) = exp(-integral_0^t sigma_c) * prod_{events e < t} (1 - (sigma_t(e) - sigma_c(e)) / mu(e))

over a Poisson process of events at rate mu >= the local majorant is an unbiased estimate of T(t): each factor's
mean given its position cancels the residual's share of the optical depth. The control here is piecewise linear:
each macrocell the ray crosses with majorant mu > 0 is cut into equal strata no longer than ``longest`` and
1 / (per_depth mu) (a partition fixed by the medium and the ray), each stratum k holds a point t_k = its start + u
times its length (one jitter u per ray), sigma_t is looked up there, and between two consecutive points of a run of
occupied macrocells sigma_c goes linearly from sigma_t(t_k) to sigma_t(t_k+1); before a run's first point and after
its last it is that point's value. The points depend on u and the medium only, so the control is fixed before any
event is drawn; the events of [t_k, t_k+1] are drawn when the walk reaches t_k+1. sigma_t is trilinear in the
volume, so the residual is mostly the kinks at voxel boundaries and the transfer function's curvature: 3-16x
smaller in mean square than a control constant per stratum over the embedded scenes' camera rays
(docs/rendering.md, "A linear control"). A factor is never negative (sigma_t - sigma_c <= mu, sigma_c >= 0 as an
interpolation of values >= 0); it can exceed 1 where a dense macrocell's point precedes a thin one's, which costs
variance, not bias. Against plain ratio tracking (:mod:`photon_fields.runtime.transport.tracking`, whose factors
1 - sigma_t / mu spread over [0, 1]) the exponential carries the attenuation without noise and the events only
correct the control's error: through a thin wall of an optical depth or two the estimate is nearly exact.

Once the estimate at a point falls below ``switch``, the point's stratum is tracked to its end with the control
constant (chosen from what precedes the point, so independent of the events it weighs) and the rest of the ray is
one delta-tracking flight: 0 at a real collision, else the estimate at the switch (unbiased: that estimate is
independent of the flight, which escapes with probability T(switch -> end)).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.transport.macrocell_walk import enter_macrocell, leap_if_empty, next_event, step_macrocell
from photon_fields.runtime.transport.medium import Medium, borrowed_medium, extinction_at, intersect_box
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import TASK_ITEMS, _sign


@njit(cache=True, inline="always")
def residual_events(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, t: float,
                    t_end: float, mu: float, sigma_c: float, slope: float, t0: float, tau: float, ratio: float,
                    state: np.uint64) -> tuple[float, float, np.uint64]:
    """Residual ratio tracking over [t, t_end]: the Poisson events at rate ``mu``, ``ratio`` times each one's factor
    against the control ``sigma_c + slope (t' - t0)`` at its distance t' (module docstring): (tau left, ratio,
    state). ``tau`` is the rate's optical depth left to the next event (< 0: not drawn yet), carried across calls so
    that a walk's stretches of different rates make one process."""
    while True:
        hit, t, tau, state = next_event(t, t_end, mu, tau, state)
        if not hit:
            return tau, ratio, state
        sigma = extinction_at(m, ox + t * dx, oy + t * dy, oz + t * dz)
        ratio *= 1.0 - (sigma - (sigma_c + slope * (t - t0))) / mu


@njit(cache=True, inline="always")
def flight_collision(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, t: float,
                     t_end: float, mu: float, tau: float, state: np.uint64) -> tuple[float, float, np.uint64]:
    """Delta tracking over [t, t_end] at majorant ``mu``: (tau left, the first real collision's distance or inf,
    state); ``tau`` as in :func:`residual_events`."""
    while True:
        hit, t, tau, state = next_event(t, t_end, mu, tau, state)
        if not hit:
            return tau, math.inf, state
        sigma = extinction_at(m, ox + t * dx, oy + t * dy, oz + t * dz)
        state, u = next_float(state)
        if u * mu < sigma:
            return tau, t, state


@njit(cache=True, inline="always")
def constant_control_events(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, t: float,
                            t_end: float, mu: float, sigma_c: float, tau: float, ratio: float,
                            state: np.uint64) -> tuple[float, float, float, np.uint64]:
    """Residual ratio tracking over [t, t_end] against the constant control ``sigma_c`` (:func:`residual_events`):
    (tau left, ratio, the control's optical depth over the stretch, state)."""
    tau, ratio, state = residual_events(m, ox, oy, oz, dx, dy, dz, t, t_end, mu, sigma_c, 0.0, t, tau, ratio, state)
    return tau, ratio, sigma_c * (t_end - t), state


@njit(cache=True, inline="always")
def events_to_point(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, a: float, tk: float,
                    mu: float, sigma_k: float, pend: bool, p_t: float, p_b: float, p_mu: float, p_s: float,
                    tau: float, ratio: float, state: np.uint64) -> tuple[float, float, float, np.uint64]:
    """The events up to the point tk of the stratum [a, ..] (majorant ``mu``, sigma_t ``sigma_k`` there): (tau left,
    ratio, the control's optical depth added, state). ``pend``: the previous point p_t (sigma_t ``p_s``) is in the
    same run, its stratum's tail [p_t, p_b] (majorant ``p_mu``) not tracked yet; the control is linear from it to
    tk over the tail and [a, tk]. Else the control is sigma_k over [a, tk]. ``mu``, ``p_mu``: the events' rates."""
    if not pend:
        return constant_control_events(m, ox, oy, oz, dx, dy, dz, a, tk, mu, sigma_k, tau, ratio, state)
    slope = (sigma_k - p_s) / (tk - p_t) if tk > p_t else 0.0
    tau, ratio, state = residual_events(m, ox, oy, oz, dx, dy, dz, p_t, p_b, p_mu, p_s, slope, p_t, tau, ratio, state)
    tau, ratio, state = residual_events(m, ox, oy, oz, dx, dy, dz, a, tk, mu, p_s, slope, p_t, tau, ratio, state)
    return tau, ratio, 0.5 * (p_s + sigma_k) * (tk - p_t), state


@njit(cache=True, inline="always")
def close_run(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, leapt: bool, ix: int,
              iy: int, iz: int, pend: bool, p_t: float, p_b: float, p_mu: float, p_s: float, tau: float, ratio: float,
              state: np.uint64) -> tuple[bool, float, float, float, np.uint64]:
    """Where a walk meets empty space after a point (a leap, or macrocell (ix, iy, iz) without medium), the point's
    tail [p_t, p_b] is tracked with its value as the control (events at rate ``p_mu``) and the run ends: (pend,
    tau left, ratio, the control's optical depth added, state)."""
    if pend and (leapt or not m.majorant[ix, iy, iz] > 0.0):
        tau, ratio, dc, state = constant_control_events(m, ox, oy, oz, dx, dy, dz, p_t, p_b, p_mu, p_s, tau, ratio,
                                                        state)
        return False, tau, ratio, dc, state
    return pend, tau, ratio, 0.0, state


@njit(cache=True, inline="always")
def strata_in(t: float, t_end: float, mu: float, per_depth: float, longest: float) -> tuple[int, float]:
    """The equal strata of a macrocell's stretch [t, t_end] of majorant ``mu``: (how many, their length), none
    longer than ``longest`` or 1 / (per_depth mu)."""
    n = int(math.ceil((t_end - t) / min(longest, 1.0 / (per_depth * mu))))
    return n, (t_end - t) / n


@njit(cache=True, inline="always")
def residual_transmittance(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, t: float,
                           tmax: float, state: np.uint64, per_depth: float, longest: float, boost: float,
                           switch: float) -> tuple[float, np.uint64]:
    """An unbiased estimate of the transmittance over [t, tmax] along the ray (module docstring) and the state."""
    state, u = next_float(state)  # the points' jitter
    sx, sy, sz = _sign(dx), _sign(dy), _sign(dz)
    ivx = 1.0 / dx if sx != 0 else math.inf
    ivy = 1.0 / dy if sy != 0 else math.inf
    ivz = 1.0 / dz if sz != 0 else math.inf
    octant = (sx >= 0) + 2 * (sy >= 0) + 4 * (sz >= 0)
    ix, iy, iz, nx_t, ny_t, nz_t = enter_macrocell(m, ox, oy, oz, dx, dy, dz, ivx, ivy, ivz, t)
    tau = -1.0
    ratio = 1.0
    tau_c = 0.0
    pend = False  # the last point's tail [p_t, p_b] (majorant p_mu, sigma_t p_s at p_t) is not tracked yet
    p_t = p_b = p_mu = p_s = 0.0
    rest = False
    while True:
        leapt, inside, t, ix, iy, iz, nx_t, ny_t, nz_t = leap_if_empty(m, ox, oy, oz, dx, dy, dz, ivx, ivy, ivz,
                                                                      octant, ix, iy, iz, t, nx_t, ny_t, nz_t)
        pend, tau, ratio, dc, state = close_run(m, ox, oy, oz, dx, dy, dz, leapt, ix, iy, iz, pend, p_t, p_b,
                                                boost * p_mu, p_s, tau, ratio, state)
        tau_c += dc
        if leapt:
            if not inside or t >= tmax:
                break
            continue
        t_end = min(nx_t, ny_t, nz_t, tmax)
        mu = m.majorant[ix, iy, iz]
        if mu > 0.0 and t_end > t and not rest:
            n, length = strata_in(t, t_end, mu, per_depth, longest)
            for j in range(n):
                a = t + j * length
                b = t_end if j == n - 1 else a + length
                tk = a + u * (b - a)
                sc = extinction_at(m, ox + tk * dx, oy + tk * dy, oz + tk * dz)
                tau, ratio, dc, state = events_to_point(m, ox, oy, oz, dx, dy, dz, a, tk, boost * mu, sc, pend, p_t,
                                                        p_b, boost * p_mu, p_s, tau, ratio, state)
                tau_c += dc
                pend, p_t, p_b, p_mu, p_s = True, tk, b, mu, sc
                if math.exp(-tau_c) * ratio < switch:  # the stratum's tail, then the rest by the flight below
                    tau, ratio, dc, state = constant_control_events(m, ox, oy, oz, dx, dy, dz, tk, b, boost * mu, sc,
                                                                    tau, ratio, state)
                    tau_c += dc
                    pend = False
                    rest = True
                    t = b
                    break
        if mu > 0.0 and t_end > t and rest:
            tau, tc, state = flight_collision(m, ox, oy, oz, dx, dy, dz, t, t_end, mu, tau, state)
            if tc < math.inf:
                return 0.0, state
        if t_end >= tmax:
            break
        t = t_end
        ix, iy, iz, nx_t, ny_t, nz_t, inside = step_macrocell(m, ox, oy, oz, ivx, ivy, ivz, sx, sy, sz, ix, iy, iz,
                                                              nx_t, ny_t, nz_t)
        if not inside:
            break
    if pend:  # the last point's tail
        tau, ratio, dc, state = constant_control_events(m, ox, oy, oz, dx, dy, dz, p_t, p_b, boost * p_mu, p_s, tau,
                                                        ratio, state)
        tau_c += dc
    return math.exp(-tau_c) * ratio, state


@njit(cache=True)
def _shadow_items(m: Medium, o: np.ndarray, lights: np.ndarray, weight: np.ndarray, states: np.ndarray,
                  per_depth: float, longest: float, boost: float, switch: float, out: np.ndarray, lo: int,
                  hi: int) -> None:
    """A task of :func:`shadowed_light_batch` over vertices lo..hi-1."""
    m = borrowed_medium(m)  # no reference counting in the loops below (runtime/borrowed.py)
    n = o.shape[1]
    for i in range(lo, hi):
        r = gg = b = 0.0
        s = states[i]
        for j in range(i, lights.shape[1], n):
            if weight[0, j] + weight[1, j] + weight[2, j] <= 0.0:
                continue
            px, py, pz, lx, ly, lz = o[0, i], o[1, i], o[2, i], lights[0, j], lights[1, j], lights[2, j]
            t0, t1 = intersect_box(m, px, py, pz, lx, ly, lz)
            tr = 1.0
            if t0 < t1:
                tr, s = residual_transmittance(m, px, py, pz, lx, ly, lz, t0, min(t1, lights[3, j]), s, per_depth,
                                               longest, boost, switch)
            r += weight[0, j] * tr
            gg += weight[1, j] * tr
            b += weight[2, j] * tr
        out[0, i], out[1, i], out[2, i] = r, gg, b
        states[i] = s


@njit(cache=True, parallel=True)
def shadowed_light_batch(m: Medium, o: np.ndarray, lights: np.ndarray, weight: np.ndarray, states: np.ndarray,
                         per_depth: float, longest: float, boost: float, switch: float) -> np.ndarray:
    """Stage: the shadow rays of NEE's light samples (``direct_light.sample_lights_batch``'s lights and weights at
    the vertices o (3, n)) by :func:`residual_transmittance`: the light arriving at each vertex, (3, n). A stage of
    its own rather than a branch of every renderer's NEE: inlined there, this walk made every renderer's first
    compile minutes longer (bench/README.md)."""
    n = o.shape[1]
    out = np.empty((3, n))
    for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):
        lo, hi = task * TASK_ITEMS, min(n, (task + 1) * TASK_ITEMS)
        _shadow_items(m, o, lights, weight, states, per_depth, longest, boost, switch, out, lo, hi)
    return out
