"""The macrocell DDA's steps as inline helpers, for walks that interleave their own work with the majorant grid
(the marched camera walk, :mod:`photon_fields.runtime.wavefront.marched_camera`). They compute what
:func:`photon_fields.runtime.transport.tracking._track` writes out inline (the same boundaries, leaps and Poisson
steps, bit for bit); ``_track`` keeps its own copy because routing it through these made every kernel that inlines
it compile 35-65 % slower (measured 2026-11-29: a cold 16^2 path-traced frame 71.5 -> 96.3 s).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from photon_fields.runtime.transport.medium import Medium
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import (
    _cell_index,
    _cube_exit,
    _next_boundary,
    _sign,
    _within,
    macrocell_of,
)


@njit(cache=True, inline="always")
def macrocell_boundaries(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, ivx: float,
                         ivy: float, ivz: float, ix: int, iy: int, iz: int) -> tuple[float, float, float]:
    """Distances along the ray to where it leaves macrocell (ix, iy, iz) on each axis (inf where it does not move)."""
    cx, cy, cz = m.majorant.shape
    return (_next_boundary(ox, ivx, m.bmin[0], m.bsize[0] / cx, ix, _sign(dx)),
            _next_boundary(oy, ivy, m.bmin[1], m.bsize[1] / cy, iy, _sign(dy)),
            _next_boundary(oz, ivz, m.bmin[2], m.bsize[2] / cz, iz, _sign(dz)))


@njit(cache=True, inline="always")
def enter_macrocell(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, ivx: float,
                    ivy: float, ivz: float, t: float) -> tuple[int, int, int, float, float, float]:
    """The DDA's start at distance t: the macrocell holding the point and the distances to its boundaries."""
    ix, iy, iz = macrocell_of(m, ox + t * dx, oy + t * dy, oz + t * dz)
    return (ix, iy, iz, *macrocell_boundaries(m, ox, oy, oz, dx, dy, dz, ivx, ivy, ivz, ix, iy, iz))


@njit(cache=True, inline="always")
def leap_cube(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, ivx: float, ivy: float,
              ivz: float, ix: int, iy: int, iz: int, r: int) -> tuple[float, int, int, int, bool]:
    """From macrocell (ix, iy, iz), whose ``Medium.leap`` entry r says that the r^3 macrocells from it on towards
    the ray's octant are empty, to where the ray leaves them: (t, the macrocell entered there, whether it is inside
    the grid). The index on the exit axis is known; on the others the cube bounds the one found from the position.
    ``iv*``: 1 / d per axis (inf where d is 0)."""
    cx, cy, cz = m.majorant.shape
    bx, by, bz = m.bmin[0], m.bmin[1], m.bmin[2]
    hx, hy, hz = m.bsize[0] / cx, m.bsize[1] / cy, m.bsize[2] / cz
    gx, gy, gz = cx / m.bsize[0], cy / m.bsize[1], cz / m.bsize[2]
    sx, sy, sz = _sign(dx), _sign(dy), _sign(dz)
    ex = _cube_exit(ox, ivx, bx, hx, ix, sx, r)
    ey = _cube_exit(oy, ivy, by, hy, iy, sy, r)
    ez = _cube_exit(oz, ivz, bz, hz, iz, sz, r)
    t = min(ex, ey, ez)
    if ex <= ey and ex <= ez:
        iy = _within(_cell_index(oy + t * dy, by, gy, cy), iy, sy, r)
        iz = _within(_cell_index(oz + t * dz, bz, gz, cz), iz, sz, r)
        ix += sx * r
        return t, ix, iy, iz, 0 <= ix < cx
    if ey <= ez:
        ix = _within(_cell_index(ox + t * dx, bx, gx, cx), ix, sx, r)
        iz = _within(_cell_index(oz + t * dz, bz, gz, cz), iz, sz, r)
        iy += sy * r
        return t, ix, iy, iz, 0 <= iy < cy
    ix = _within(_cell_index(ox + t * dx, bx, gx, cx), ix, sx, r)
    iy = _within(_cell_index(oy + t * dy, by, gy, cy), iy, sy, r)
    iz += sz * r
    return t, ix, iy, iz, 0 <= iz < cz


@njit(cache=True, inline="always")
def leap_if_empty(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, ivx: float, ivy: float,
                  ivz: float, octant: int, ix: int, iy: int, iz: int, t: float, nx_t: float, ny_t: float,
                  nz_t: float) -> tuple[bool, bool, float, int, int, int, float, float, float]:
    """The DDA's leap over empty space: when ``Medium.leap`` says that at least 2^3 macrocells from (ix, iy, iz) on
    towards the ray's ``octant`` are empty, go to where the ray leaves them (:func:`leap_cube`). Returns (leapt,
    inside the grid, t, the macrocell, its boundaries); unchanged values and leapt False otherwise."""
    r = int(m.leap[octant, ix, iy, iz])
    if r < 2:
        return False, True, t, ix, iy, iz, nx_t, ny_t, nz_t
    t, ix, iy, iz, inside = leap_cube(m, ox, oy, oz, dx, dy, dz, ivx, ivy, ivz, ix, iy, iz, r)
    if inside:
        nx_t, ny_t, nz_t = macrocell_boundaries(m, ox, oy, oz, dx, dy, dz, ivx, ivy, ivz, ix, iy, iz)
    return True, inside, t, ix, iy, iz, nx_t, ny_t, nz_t


@njit(cache=True, inline="always")
def step_macrocell(m: Medium, ox: float, oy: float, oz: float, ivx: float, ivy: float, ivz: float, sx: int, sy: int,
                   sz: int, ix: int, iy: int, iz: int, nx_t: float, ny_t: float,
                   nz_t: float) -> tuple[int, int, int, float, float, float, bool]:
    """The DDA's step into the neighbouring macrocell across the nearest boundary (``n*_t``: the distances to the
    current macrocell's boundaries): the new macrocell, its boundaries, whether it is inside the grid."""
    cx, cy, cz = m.majorant.shape
    if nx_t <= ny_t and nx_t <= nz_t:
        ix += sx
        return ix, iy, iz, _next_boundary(ox, ivx, m.bmin[0], m.bsize[0] / cx, ix, sx), ny_t, nz_t, 0 <= ix < cx
    if ny_t <= nz_t:
        iy += sy
        return ix, iy, iz, nx_t, _next_boundary(oy, ivy, m.bmin[1], m.bsize[1] / cy, iy, sy), nz_t, 0 <= iy < cy
    iz += sz
    return ix, iy, iz, nx_t, ny_t, _next_boundary(oz, ivz, m.bmin[2], m.bsize[2] / cz, iz, sz), 0 <= iz < cz


@njit(cache=True, inline="always")
def next_event(t: float, t_end: float, mu: float, tau: float,
               state: np.uint64) -> tuple[bool, float, float, np.uint64]:
    """The next tentative collision of a Poisson process of rate ``mu`` after t, if it falls before ``t_end``:
    (whether it does, its distance, tau, state). ``tau`` is the optical depth of rate ``mu`` left to it (< 0: draw
    it now), spent across calls so that a walk's stretches of different rates make one process; after an event it
    is -1, otherwise what is left past ``t_end``."""
    if tau < 0.0:
        state, u = next_float(state)
        tau = -math.log(1.0 - u)
    depth = mu * (t_end - t)
    if tau >= depth:
        return False, t_end, tau - depth, state
    return True, t + tau * (1.0 / mu), -1.0, state
