"""How long a march's steps may be, per macrocell: the ray marcher's adaptive segments, for its camera rays and
for its light volume's shadow rays (:func:`photon_fields.runtime.transport.marching.march_transmittance_in_segments`).

Parameters
----------
step : float
    The march's base step, in voxels (the ray marcher's ``step``): the lattice every segment boundary lies on.
max_step : float
    The longest segment, in voxels (a whole number of base steps; ``max_step <= step`` gives fixed steps).
tolerance : float (default :data:`STEP_TOLERANCE`)
    The quadrature error allowed per segment, in optical depth (below).
depth : float (default :data:`STEP_DEPTH`)
    The optical depth one segment may hold (below).

The ray marcher samples sigma_t, the albedo and the light once per segment. A fixed step of one voxel makes its
cost grow with the volume's resolution (a 256^3 volume takes 2.7x the samples per ray of a 96^3 one showing the
same shapes) and spends as many samples on a smooth cloud as on a skull's wall. The error of one sample per
segment has two sources, and each gives a bound on the segment's length L (in voxels; a shadow ray needs only the
first, the second keeps its segments short in dense media, where it ends soon anyway):

- **sigma_t's variation.** The midpoint rule integrates a linear sigma_t exactly; its error over a segment is
  L^3 |sigma''| / 24 (in optical depth, sigma in optical depth per voxel and '' per voxel). With c the largest
  second difference of sigma_t between neighbouring voxels of the macrocell's neighbourhood, L <= (24 tolerance /
  c)^(1/3). sigma_t is taken at the voxels, through the transfer function (post-classification); where the
  macrocell's majorant exceeds the largest voxel value by more than ``tolerance`` per voxel, the transfer function
  peaks between voxel values (a narrow spike) and the segment stays one base step.
- **The light's variation across the segment.** The camera's attenuation within a segment is exact (the
  scattering centroid, :func:`photon_fields.runtime.renderers.ray_marcher.scattering_centroid`), but the light is
  read at one point; in a dense medium it falls off within a voxel (a lit wall). So a segment holds at most
  ``depth`` optical depths of the macrocell's majorant: L <= depth / majorant.

A macrocell's number of base steps is the least of those bounds over the cube of macrocells that a segment starting
in it can reach (``max_step`` in macrocells, rounded up, on every side: a wall two macrocells ahead of a segment's
start must not fall in its unsampled half), at least 1; an empty macrocell holds 1, so that a march that steps
through empty space segment by segment and one that jumps over it
(:func:`photon_fields.runtime.transport.marching.segment_past`) meet the medium at the same segment and sum the same
samples. Both bounds are in voxels of the volume, so at a finer resolution of the same shapes (sigma_t per voxel and
its second differences shrink) the segments grow where the medium is smooth; near sharp walls they stay one step.

That cube holds for a segment in any direction, and it costs most of the length: at 256^3 vortex's occupied
macrocells allow 2.95 base steps on their own and 1.17 after the cube's minimum (head 2.39 / 1.17). A camera ray
knows its direction, so its march (:func:`units_along`) starts from the cube's number and, where the macrocell's own
number (:func:`own_units`) is larger, walks the macrocells its segment passes and takes the least own number among
them: the same two bounds over exactly the voxels whose sigma_t the segment reads (a macrocell's bounds cover the
second differences of its own voxels, which is all that the trilinear sigma_t inside it depends on), and an empty
macrocell bounds nothing (sigma_t is 0 throughout). The light volume's shadow rays, marched once per cell, keep the
cube.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.transport.medium import Medium, _extinction_of, _voxel_span
from photon_fields.runtime.transport.tracking import _next_boundary, _sign, macrocell_of

#: Quadrature error allowed per segment, in optical depth (module docstring; bench/README.md, ray marcher).
STEP_TOLERANCE = 0.05
#: Optical depth of the majorant one segment may hold (module docstring).
STEP_DEPTH = 1.0
#: Base steps per segment are stored as uint8.
MAX_UNITS = 255
#: :func:`step_lengths` counts in these parts of a voxel (a power of two: the 1- and 1/2-voxel bases are exact) ...
LENGTH_PARTS = 8
#: ... up to this many (uint8): segments of at most ~32 voxels.
MAX_LENGTH = 255
#: Macrocell rows whose sigma_t one block of :func:`step_lengths` holds.
_ROWS = 8


@njit(cache=True, parallel=True)
def _sigma_slices(density: np.ndarray, lut: np.ndarray, categorical: bool, lo: int, hi: int) -> np.ndarray:
    """sigma_t at the voxels of x-slices lo .. hi - 1, float64 (each voxel's value looked up once)."""
    _, ny, nz = density.shape
    out = np.empty((hi - lo, ny, nz))
    for i in prange(lo, hi):
        for j in range(ny):
            for k in range(nz):
                out[i - lo, j, k] = _extinction_of(lut, categorical, density[i, j, k])
    return out


@njit(cache=True, parallel=True)
def _bounds_block(sig: np.ndarray, lo: int, nx: int, majorant: np.ndarray, a0: int, a1: int, voxel: float,
                  tolerance: float, depth: float, out: np.ndarray) -> None:
    """Macrocell rows a0 .. a1 - 1 of :func:`step_lengths`, from ``sig``: sigma_t of x-slices lo .. (every voxel of
    their spans and the x-neighbours the second differences read; indices clamped to the grid)."""
    cx, cy, cz = majorant.shape
    _, ny, nz = sig.shape
    for a in prange(a0, a1):
        x0, x1 = _voxel_span(a, cx, nx)
        for b in range(cy):
            y0, y1 = _voxel_span(b, cy, ny)
            for c in range(cz):
                mu = majorant[a, b, c] * voxel
                if mu <= 0.0:
                    continue
                z0, z1 = _voxel_span(c, cz, nz)
                top = 0.0
                curv = 0.0
                for i in range(x0, x1):
                    xi, xm, xp = i - lo, max(i - 1, 0) - lo, min(i + 1, nx - 1) - lo
                    for j in range(y0, y1):
                        jm, jp = max(j - 1, 0), min(j + 1, ny - 1)
                        for k in range(z0, z1):
                            km, kp = max(k - 1, 0), min(k + 1, nz - 1)
                            s = sig[xi, j, k]
                            top = max(top, s)
                            curv = max(curv, abs(sig[xm, j, k] - 2.0 * s + sig[xp, j, k]),
                                       abs(sig[xi, jm, k] - 2.0 * s + sig[xi, jp, k]),
                                       abs(sig[xi, j, km] - 2.0 * s + sig[xi, j, kp]))
                if mu - top * voxel > tolerance:
                    continue  # the transfer function peaks between the voxels' values
                length = depth / mu
                if curv > 0.0:
                    length = min(length, (24.0 * tolerance / (curv * voxel)) ** (1.0 / 3.0))
                out[a, b, c] = min(MAX_LENGTH, int(math.floor(length * LENGTH_PARTS)))


def step_lengths(m: Medium, voxel: float, tolerance: float = STEP_TOLERANCE, depth: float = STEP_DEPTH) -> np.ndarray:
    """(cx, cy, cz) uint8: the longest segment each macrocell's own bounds allow (module docstring; before the
    neighbourhood's minimum), in :data:`LENGTH_PARTS`-ths of a voxel, rounded down, at most :data:`MAX_LENGTH`; 0 in
    an empty macrocell or where the transfer function peaks between voxel values. The one pass over sigma_t that
    every base step's grid (:func:`units_from_lengths`) derives from: sigma_t looked up once per voxel,
    :data:`_ROWS` macrocell rows at a time (bounded memory: a 512^3 volume's block of sigma_t takes ~40 MB; a lookup
    per voxel and neighbour took seconds there; the pass itself takes ~1 s at 512^3)."""
    cx = m.majorant.shape[0]
    nx = m.density.shape[0]
    out = np.zeros(m.majorant.shape, dtype=np.uint8)
    for a0 in range(0, cx, _ROWS):
        a1 = min(cx, a0 + _ROWS)
        lo = max(_voxel_span(a0, cx, nx)[0] - 1, 0)
        hi = min(_voxel_span(a1 - 1, cx, nx)[1] + 1, nx)
        sig = _sigma_slices(m.density, m.ext_lut, m.categorical, lo, hi)
        _bounds_block(sig, lo, nx, m.majorant, a0, a1, float(voxel), float(tolerance), float(depth), out)
    return out


@njit(cache=True, parallel=True)
def _min_along(units: np.ndarray, axis: int, radius: int) -> np.ndarray:
    """The least value within ``radius`` cells along one axis (one pass of the separable cube minimum)."""
    out = np.empty_like(units)
    n = units.shape[axis]
    for a in prange(units.shape[0]):
        for b in range(units.shape[1]):
            for c in range(units.shape[2]):
                i = a if axis == 0 else (b if axis == 1 else c)
                v = units[a, b, c]
                for j in range(max(i - radius, 0), min(i + radius + 1, n)):
                    v = min(v, units[j, b, c] if axis == 0 else (units[a, j, c] if axis == 1 else units[a, b, j]))
                out[a, b, c] = v
    return out


def _neighbourhood_min(units: np.ndarray, radius: int) -> np.ndarray:
    """The least value over the cube of macrocells within ``radius`` of each (three passes, one per axis)."""
    for axis in range(3):
        units = _min_along(units, axis, radius)
    return units


def step_units(m: Medium, voxel: float, step: float, max_step: float, tolerance: float = STEP_TOLERANCE,
               depth: float = STEP_DEPTH) -> np.ndarray:
    """(cx, cy, cz) uint8 over ``m``'s macrocells: how many base steps of ``step`` voxels one segment of a march
    starting there may span (module docstring), at most ``max_step`` voxels' worth and at least 1.
    ``voxel``: the voxel's edge in world units (``m``'s extinction is per world unit)."""
    if _max_units(step, max_step) == 1:
        return np.ones(m.majorant.shape, dtype=np.uint8)
    return units_from_lengths(m, step_lengths(m, voxel, tolerance, depth), step, max_step)


def _max_units(step: float, max_step: float) -> int:
    return max(1, min(MAX_UNITS, int(math.floor(max_step / step + 1e-9))))


def units_from_lengths(m: Medium, lengths: np.ndarray, step: float, max_step: float) -> np.ndarray:
    """:func:`step_units` from the macrocells' allowed lengths (:func:`step_lengths`): the base steps of ``step``
    voxels within each length, 1 to ``max_step``'s worth, then the least over the macrocells a segment can reach.
    Exact for a step of whole :data:`LENGTH_PARTS`-ths of a voxel (the 1-voxel camera march, the light volume's
    half-voxel rays), shorter for others (the length was rounded down)."""
    max_units = _max_units(step, max_step)
    if max_units == 1:
        return np.ones(m.majorant.shape, dtype=np.uint8)
    own = np.maximum(own_units(m, lengths, step, max_step), 1)  # an empty macrocell allows one step (above)
    # A segment starts anywhere in its macrocell and spans up to max_units base steps: the macrocells it may reach.
    edge = min(a / b for a, b in zip(m.density.shape, m.majorant.shape, strict=True))  # a macrocell's edge in voxels
    return _neighbourhood_min(own, max(1, int(math.ceil(max_units * step / edge))))


def own_units(m: Medium, lengths: np.ndarray, step: float, max_step: float) -> np.ndarray:
    """Each macrocell's own base steps of ``step`` voxels (1 to ``max_step``'s worth) from :func:`step_lengths`,
    without the neighbourhood's minimum, and 0 in empty macrocells: what :func:`units_along` reads along a ray."""
    own = np.clip(np.floor(lengths / (LENGTH_PARTS * float(step))), 1, _max_units(step, max_step)).astype(np.uint8)
    own[m.majorant <= 0.0] = 0
    return own


@njit(cache=True, inline="always")
def units_along(m: Medium, own: np.ndarray, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float,
                vx: float, vy: float, vz: float, t0: float, t1: float, h: float, n: int, least: int) -> int:
    """The base steps ``h`` a camera segment from ``t0`` along the ray may span, at most ``n`` and ending by
    ``t1``: the least :func:`own_units` of every occupied macrocell that the segment passes (a DDA over the
    macrocells from t0 to its end, which shrinks as they allow fewer steps; empty ones bound nothing, sigma_t is 0
    there), at least 1."""
    cx, cy, cz = own.shape
    sx, sy, sz = _sign(dx), _sign(dy), _sign(dz)
    ix, jy, kz = macrocell_of(m, ox + t0 * dx, oy + t0 * dy, oz + t0 * dz)
    ex, ey, ez = m.bsize[0] / cx, m.bsize[1] / cy, m.bsize[2] / cz
    tx = _next_boundary(ox, vx, m.bmin[0], ex, ix, sx)
    ty = _next_boundary(oy, vy, m.bmin[1], ey, jy, sy)
    tz = _next_boundary(oz, vz, m.bmin[2], ez, kz, sz)
    t_end = min(t0 + n * h, t1)
    while True:
        v = int(own[ix, jy, kz])
        if v != 0 and v < n:
            if v <= least:
                return least
            n = v
            t_end = min(t0 + n * h, t1)
        if min(tx, ty, tz) >= t_end:
            break
        if tx <= ty and tx <= tz:  # into the next macrocell along the axis whose boundary comes first
            ix, tx, inside = _cross(ix, sx, cx, ox, vx, m.bmin[0], ex)
        elif ty <= tz:
            jy, ty, inside = _cross(jy, sy, cy, oy, vy, m.bmin[1], ey)
        else:
            kz, tz, inside = _cross(kz, sz, cz, oz, vz, m.bmin[2], ez)
        if not inside:
            break
    return n


@njit(cache=True, inline="always")
def _cross(cell: int, step: int, cells: int, o: float, inv_d: float, bmin: float,
           edge: float) -> tuple[int, float, bool]:
    """One axis of :func:`units_along`'s walk: the next macrocell along it, the distance to where the ray leaves
    that one on this axis, and whether it is inside the grid."""
    cell += step
    return cell, _next_boundary(o, inv_d, bmin, edge, cell, step), 0 <= cell < cells
