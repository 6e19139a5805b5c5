"""One photon path through the medium, from its emission to its last collision: the transport that photon tracing
(``train/photons/tracing.py``, the Photon Field Networks paper's Alg. 1) and the PVRT precomputation
(``runtime/pvrt/precompute.py``) share, so that both draw the same random numbers in the same order.

:func:`trace_path` follows a photon already emitted (its origin, direction and power) into the volume's box, free
flight by delta tracking over the majorant grid (``runtime/transport/tracking.py``), and at each real collision
records where it is, the direction it arrives from and the power it *arrives* with; then Russian roulette with
survival probability = the largest albedo component, the survivor's power multiplied by albedo / survival
(Jensen's photon tracing: powers stay nearly constant), and a new direction from the Henyey-Greenstein phase
function with ``g``; at most ``max_bounces`` collisions (no roulette after the last one). What a collision is
used for is the caller's business: tracing stores the second and later ones in the photon map, PVRT splats each
into its transfer cells.

Random draws of a path, all from its stream ``st``: the delta-tracking walk to each collision, then one number for
the roulette and two for the HG direction. The emission's draws come before, in the caller.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from photon_fields.runtime.transport.medium import Medium, _albedo_of, intersect_box, scalar_at
from photon_fields.runtime.transport.phase import sample_hg
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import delta_track


@njit(cache=True)
def trace_path(m: Medium, g: float, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, br: float,
               bg: float, bb: float, st: np.uint64, max_bounces: int, pos: np.ndarray, dirs: np.ndarray,
               power: np.ndarray, scalar: np.ndarray) -> tuple[int, np.uint64]:
    """Follow the photon emitted at (ox, oy, oz) along (dx, dy, dz) with RGB power (br, bg, bb) (module docstring).
    Collision k (0: the first) goes to row k of ``pos``, ``dirs`` (unit travel direction arriving there) and
    ``power`` (power arriving there), each (>= max_bounces, 3) float64, and the volume's scalar there (whose albedo
    the roulette used) to ``scalar[k]`` (not set at the last collision of ``max_bounces``, which plays no
    roulette); returns the number of collisions and the stream state after the path. A photon that misses the box
    has none."""
    t0, t1 = intersect_box(m, ox, oy, oz, dx, dy, dz)
    if t0 >= t1:
        return 0, st
    ox, oy, oz = ox + t0 * dx, oy + t0 * dy, oz + t0 * dz
    tmax = t1 - t0
    n = 0
    for bounce in range(max_bounces):
        t, st = delta_track(m, ox, oy, oz, dx, dy, dz, 0.0, tmax, st)
        if math.isinf(t):
            break
        ox, oy, oz = ox + t * dx, oy + t * dy, oz + t * dz
        pos[n, 0], pos[n, 1], pos[n, 2] = ox, oy, oz
        dirs[n, 0], dirs[n, 1], dirs[n, 2] = dx, dy, dz
        power[n, 0], power[n, 1], power[n, 2] = br, bg, bb
        n += 1
        if bounce + 1 == max_bounces:
            break
        s = scalar_at(m, ox, oy, oz)
        scalar[n - 1] = s
        a0, a1, a2 = _albedo_of(m.albedo_lut, m.categorical, s)
        q = max(a0, a1, a2)
        st, u = next_float(st)
        if u >= q:
            break
        br, bg, bb = br * a0 / q, bg * a1 / q, bb * a2 / q
        st, u1 = next_float(st)
        st, u2 = next_float(st)
        dx, dy, dz, _ = sample_hg(g, dx, dy, dz, u1, u2)
        _, t1 = intersect_box(m, ox, oy, oz, dx, dy, dz)
        tmax = max(t1, 0.0)
    return n, st
