"""Transmittance by marching: the midpoint rule along a ray, with empty-space skipping.

The ray marcher's shadow rays (``runtime/renderers/ray_marcher.py``) and the light volumes that cache them (the
marcher's, :mod:`photon_fields.runtime.transport.light_volume`, and PVRT's, ``runtime/pvrt/radiance.py``) march
sigma_t at midpoints a fixed step apart. The sum is deterministic (no random numbers), which is what lets a cache
hold it; it is biased where sigma_t varies sharply within a step (the ray marcher's docstring says how), where the
path tracer's delta and ratio tracking are not.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from photon_fields.runtime.transport.medium import Medium, extinction_at, intersect_box
from photon_fields.runtime.transport.tracking import empty_run, empty_run_in, macrocell_of

TAU_MAX = 20.0  # a shadow ray this deep is dark (transmittance 2e-9)


@njit(cache=True, inline="always")
def march_transmittance(m: Medium, px: float, py: float, pz: float, lx: float, ly: float, lz: float, tend: float,
                        h: float, skip: bool, tau_max: float = TAU_MAX) -> float:
    """exp(-integral of sigma_t) from p towards l over [0, min(tend, box exit)], midpoint rule; ``skip``: no
    lookups at the midpoints that lie in empty macrocells (:func:`empty_run`; the same sum): the walk jumps to the
    first midpoint past the empty run instead of stepping over each, so empty space costs one step per run.
    0 once the optical depth passes ``tau_max`` (the rest of the ray is not marched)."""
    t0, t1 = intersect_box(m, px, py, pz, lx, ly, lz)
    if t0 >= t1:
        return 1.0
    t1 = min(t1, tend)
    n = max(1, int(math.ceil((t1 - t0) / h)))
    hh = (t1 - t0) / n
    tau = 0.0
    empty_until = -math.inf
    k = 0
    while k < n:
        t = t0 + (k + 0.5) * hh
        if t < empty_until:
            # floor() never passes the first midpoint >= empty_until, and the test above is repeated there:
            # the same midpoints are summed as stepping one by one would, bit for bit
            k = max(k + 1, int(min(math.floor((empty_until - t0) / hh - 0.5), n)))
            continue
        k += 1
        x, y, z = px + t * lx, py + t * ly, pz + t * lz
        if skip:
            run = empty_run(m, x, y, z, lx, ly, lz)
            if run > 0.0:
                empty_until = t + run
                continue
        tau += extinction_at(m, x, y, z) * hh
        if tau > tau_max:
            return 0.0
    return math.exp(-tau)


@njit(cache=True, inline="always")
def march_transmittance_in_segments(m: Medium, units: np.ndarray, px: float, py: float, pz: float, lx: float,
                                    ly: float, lz: float, tend: float, h: float, tau_max: float = TAU_MAX) -> float:
    """:func:`march_transmittance` in adaptive segments (the light volume's cells): base steps of ``h`` from p, a
    segment as many of them as the macrocell of its first base step's midpoint allows (``units``,
    :func:`photon_fields.runtime.transport.step_grid.step_units`: the midpoint rule's error over it and its optical
    depth bounded, the least over every macrocell a segment can reach), sampled at its own midpoint; empty runs
    skipped (an empty macrocell allows one base step, so the skip lands where stepping would). ``units`` all ones:
    every base step sampled, the last one partial."""
    t0, t1 = intersect_box(m, px, py, pz, lx, ly, lz)
    if t0 >= t1:
        return 1.0
    t1 = min(t1, tend)
    tau = 0.0
    empty_until = -math.inf
    k = 0  # base steps from t0
    while t0 + k * h < t1:
        ta = t0 + k * h
        tm = 0.5 * (ta + min(ta + h, t1))
        if tm < empty_until:  # floor() errs low, and the test is repeated there (as march_transmittance's)
            k = max(k + 1, int(math.floor((empty_until - t0) / h - 0.5)))
            continue
        x, y, z = px + tm * lx, py + tm * ly, pz + tm * lz
        i, j, c = macrocell_of(m, x, y, z)
        run = empty_run_in(m, i, j, c, x, y, z, lx, ly, lz)
        if run > 0.0:
            empty_until = tm + run
            continue
        n = int(units[i, j, c])
        tb = min(ta + n * h, t1)
        tm = 0.5 * (ta + tb)
        tau += extinction_at(m, px + tm * lx, py + tm * ly, pz + tm * lz) * (tb - ta)
        if tau > tau_max:
            return 0.0
        k += n
    return math.exp(-tau)


@njit(cache=True, inline="always")
def segment_past(s: int, empty_until: float, h: float, jitter: float, t_end: float) -> int:
    """A camera march's segment to go on from when segment ``s``'s midpoint lies in an empty run that ends at
    ``empty_until``. Segment s spans [t_{s-1}, t_s] with t_s = (jitter + s) h (t_{-1} = 0) and is sampled at its
    midpoint: the result is at least s + 1 and never past the first segment whose midpoint reaches
    ``empty_until`` (floor() errs low; the caller's test repeats there), so the walk sums the same midpoints as
    one stepping over every segment of the run, bit for bit, in one step per run."""
    return max(s + 1, int(min(math.floor(empty_until / h - jitter + 0.5), t_end / h + 2.0)))

