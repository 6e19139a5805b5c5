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

Records with a floor (``floor`` q > 0, photon tracing's default ``models_spec.RECORD_FLOOR``). Recorded at real
collisions only, records have density sigma_t(x) times the fluence, and the radiance estimate weights each by Phi /
sigma_t(x): where sigma_t is a sliver of its neighbourhood's (a voxel at the edge of a dense feature) a rare record
carries a huge weight, a firefly in the targets (docs/training.md, "Records with a floor"). Delta tracking's tentative
collisions have density m(x) (the majorant) times the fluence; recording each with probability r(x) = max(sigma_t(x) /
m(x), q) where sigma_t > 0 gives records of density max(sigma_t, q m) times the fluence, so the weight Phi /
max(sigma_t(x), q m(x)) (:func:`record_densities`) keeps the estimate unbiased and bounds every weight by Phi / (q m).
The one draw delta tracking makes at a tentative collision decides both (``tracking.record_track``): real if u m <
sigma_t, else a null record if u < q; the flight, and so every real collision, is distributed as without the floor. A
null record on the flight towards the k-th real collision carries what the k-th would: the same power, direction and
earlier collisions.

Random draws of a path, all from its stream ``st``: the delta-tracking walk to each collision, then one number for
the roulette and two for the HG direction. The emission's draws come before, in the caller.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.transport.medium import Medium, _albedo_of, extinction_at, intersect_box, scalar_at
from photon_fields.runtime.transport.phase import sample_hg
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import majorant_at, record_track


@njit(cache=True)
def trace_path(m: Medium, g: float, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, br: float,
               bg: float, bb: float, st: np.uint64, max_bounces: int, floor: float, pos: np.ndarray, dirs: np.ndarray,
               power: np.ndarray, coll: np.ndarray, scalar: np.ndarray) -> tuple[int, np.uint64, int]:
    """Follow the photon emitted at (ox, oy, oz) along (dx, dy, dz) with RGB power (br, bg, bb) (module docstring).
    Record r goes to row r of ``pos``, ``dirs`` (unit travel direction arriving there) and ``power`` (power arriving
    there), each (capacity, 3) float64 with capacity >= max_bounces, and ``coll[r]`` is its collision number: k for the
    path's k-th real collision (1: the first), k for a null record on the flight towards the k-th (``floor`` > 0, module
    docstring; from the first real collision on: before it the light is direct). ``scalar[k - 1]`` is the volume's
    scalar at the k-th real collision (whose albedo its roulette used; not set at collision ``max_bounces``, which plays
    no roulette). Returns the number of records, the stream state after the path and the number of null records dropped
    because the rows ran out (rows are kept for every real collision the path can still make). A photon that misses the
    box has none."""
    t0, t1 = intersect_box(m, ox, oy, oz, dx, dy, dz)
    if t0 >= t1:
        return 0, st, 0
    ox, oy, oz = ox + t0 * dx, oy + t0 * dy, oz + t0 * dz
    tmax = t1 - t0
    rows = pos.shape[0]
    n = 0
    k = 0  # real collisions so far
    dropped = 0
    while True:
        t, real, st = record_track(m, ox, oy, oz, dx, dy, dz, 0.0, tmax, st, floor if k > 0 else 0.0)
        if math.isinf(t):
            break
        ox, oy, oz = ox + t * dx, oy + t * dy, oz + t * dz
        tmax -= t
        if not real and n + max_bounces - k >= rows:
            dropped += 1
            continue
        pos[n, 0], pos[n, 1], pos[n, 2] = ox, oy, oz
        dirs[n, 0], dirs[n, 1], dirs[n, 2] = dx, dy, dz
        power[n, 0], power[n, 1], power[n, 2] = br, bg, bb
        coll[n] = k + 1
        n += 1
        if not real:
            continue
        k += 1
        if k == max_bounces:
            break
        s = scalar_at(m, ox, oy, oz)
        scalar[k - 1] = s
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
    return n, st, dropped


@njit(cache=True, parallel=True)
def record_densities(m: Medium, pos: np.ndarray, floor: float) -> np.ndarray:
    """The density of records per unit fluence at world points ``pos`` (3, n) where sigma_t > 0: max(sigma_t(x),
    ``floor`` times the majorant at x) (module docstring); Phi / it is a record's weight in the radiance estimate
    (:mod:`photon_fields.runtime.photons.estimate`). With floor 0: sigma_t(x). (Records lie where sigma_t > 0; a
    float32 position rounded off the support still gets the floor's bound.)"""
    n = pos.shape[1]
    out = np.empty(n)
    for i in prange(n):
        x, y, z = pos[0, i], pos[1, i], pos[2, i]
        out[i] = max(extinction_at(m, x, y, z), floor * majorant_at(m, x, y, z))
    return out
