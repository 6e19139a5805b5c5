"""A deterministic, noise-free depth per pixel of a volume, for reprojecting denoiser history.

Temporal denoisers reproject each pixel's history along the image motion of "the" world point it sees
(Iglesias-Guitian et al. Sec. 6, "Optical Flow Estimation"). In a participating medium a camera ray has no
single surface point; the paper takes "the closest world coordinate ... of the first real collision according
to delta tracking", one random collision per frame, and calls it a heuristic. A random depth changes from
frame to frame and would shake the reprojection, and the renderers output none, so we use a quantile
(default: the median) of the same first-collision distribution instead, computed exactly along the centre ray
of the pixel: with ``tau(t)`` the optical depth from the box entry and ``T_exit`` the transmittance of the
whole ray, the distance ``t*`` with

    1 - exp(-tau(t*)) = quantile (1 - T_exit),   i.e.   tau(t*) = -ln(1 - quantile (1 - T_exit)),

where that fraction of the rays that collide at all have collided. It is the paper's choice without its noise,
and it follows the densest visible layer (the 0.25 and 0.75 quantiles warped 64-spp frames no better than the
median in development runs). A ray whose collision probability
``1 - T_exit`` is below ``min_opacity`` (1e-3: the wisps of a thin medium still need their depth) sees the
background at infinity, which reprojects with the camera's rotation only.

Cost: the march runs on a coarse copy of the extinction, the mean of ``sigma_t`` at the voxel centres of each
``block``^3 block (``block = 2``: a 96^3 volume becomes 48^3 cells; more above 256 voxels a side, so that the grid
stays within :data:`MAX_CELLS_SIDE` cells a side), with a 3-D DDA (Amanatides & Woo 1987)
over its cells, inside which ``sigma_t`` is constant and ``tau`` grows linearly, so ``t*`` is exact for the
coarse grid; from an empty cell the walk leaps over the largest empty cube of cells ahead of it
(:func:`photon_fields.runtime.transport.medium.leap_distances` on the coarse grid). One walk per ray, for
``T_exit``, ending once the ray is opaque; it records its segments of medium, and ``t*`` is found among them
(the same arithmetic as a second walk to ``tau(t*)``, which it replaced); one parallel region. Each ray is walked
only between the depth bounds of its 4x4-pixel tile over the coarse grid's cells with medium
(:mod:`photon_fields.runtime.wavefront.depth_bounds`, as the renderers' camera walks), and not at all in a tile
that sees none.
``stride = 2`` (default) marches one ray per 2x2 pixels, through the block's centre, and gives the block's
pixels its depth: 4x cheaper, with no measurable change in the denoised orbits (development runs, vortex and
shell). Milliseconds per 512x512 frame: bench/README.md (``bench/bench_denoise.py``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.denoise.reprojection import EYE, HEIGHT, WIDTH, pack_view, pixel_direction
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.transport.medium import Medium, block_extinction, leap_distances
from photon_fields.runtime.wavefront.depth_bounds import grid_depth_bounds, occupied_cells, unbounded

DEFAULT_BLOCK = 2  # voxels per coarse cell edge, at least (:func:`auto_block`)
#: The coarse grid's longest side in cells, at most, with the automatic block: a 512^3 volume's 256^3 grid at block 2
#: took 0.35 s of leap tables and 134 MB at every transfer-function edit (bench/README.md, viewer).
MAX_CELLS_SIDE = 128
DEFAULT_MIN_OPACITY = 1e-3  # collision probability below which a pixel sees the background at infinity
DEFAULT_QUANTILE = 0.5  # of the first-collision distribution along the ray
DEFAULT_STRIDE = 2  # one ray per stride x stride pixels
_TAU_OPAQUE = 12.0  # exp(-12) = 6e-6: the rest of the ray cannot move the median


def auto_block(shape: tuple[int, ...]) -> int:
    """The block for a volume of this shape: :data:`DEFAULT_BLOCK`, or more where the grid's longest side would pass
    :data:`MAX_CELLS_SIDE` cells (up to 256^3 voxels: 2)."""
    return max(DEFAULT_BLOCK, math.ceil(max(shape) / MAX_CELLS_SIDE))


def coarse_extinction(m: Medium, block: int = DEFAULT_BLOCK) -> np.ndarray:
    """Mean extinction over ``block``^3 voxel blocks (the grid is padded at the far ends by repeating the border
    voxels), from the transfer function's extinction table at the voxel values: ``sigma_t`` at each voxel centre,
    where trilinear (or, in a categorical medium, nearest) lookup returns the voxel's own value."""
    return block_extinction(m, block)


class DepthEstimator:
    """First-collision-quantile depth maps of one medium (module docstring); the coarse grid is built once.

    ``block`` (voxels per coarse cell; None: :func:`auto_block`), ``min_opacity``, ``quantile`` and ``stride`` as
    in the module docstring; ``leap`` False walks empty cells one by one, ``bounds`` False walks every ray through
    the whole box (the same depths, slower: for tests and benches)."""

    def __init__(self, medium: Medium, *, block: int | None = None, min_opacity: float = DEFAULT_MIN_OPACITY,
                 quantile: float = DEFAULT_QUANTILE, stride: int = DEFAULT_STRIDE, leap: bool = True,
                 bounds: bool = True) -> None:
        block = auto_block(medium.density.shape) if block is None else block
        for name, v in (("block", block), ("stride", stride)):
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 64:
                raise InputError(f"depth {name}", f"must be an integer in [1, 64], got {v!r}")
        for name, v in (("min_opacity", min_opacity), ("quantile", quantile)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < v < 1.0:
                raise InputError(f"depth {name}", f"must be a number in (0, 1), got {v!r}")
        self.quantile = float(quantile)
        self.stride = int(stride)
        self.grid = coarse_extinction(medium, block)
        # Per direction octant, the largest empty cube of coarse cells at each cell (the majorant grid's table,
        # runtime.transport.medium): walks jump over empty space. Where the medium's macrocells are these very cells
        # (the same block, sides it divides: 96^3 to 512^3 volumes of even sides) its table serves: a macrocell with
        # a zero majorant has sigma_t = 0 at every voxel of its trilinear support, so its cell's mean is 0 too (it may
        # leap less, never into medium: the same depths), and an edit's first frame saves its 8 sweeps (~50 ms at
        # 256^3).
        same_cells = medium.majorant.shape == self.grid.shape and all(n % block == 0 for n in medium.density.shape)
        self.leap = medium.leap if leap and same_cells else leap_distances(self.grid, leap)
        self.bmin = np.ascontiguousarray(medium.bmin, dtype=np.float64)
        self.bsize = np.ascontiguousarray(medium.bsize, dtype=np.float64)
        # Coarse cells per world unit: a cell is ``block`` voxels wide (the last one may reach past the box).
        self.per_unit = np.asarray(medium.density.shape, dtype=np.float64) / (self.bsize * block)
        self.min_opacity = float(min_opacity)
        self.grid_size = np.asarray(self.grid.shape, np.float64) / self.per_unit  # may reach past the box
        self.bounds = bool(bounds)
        self.cells = occupied_cells(self.grid) if self.bounds else None  # for every camera's bounds, found once

    def depth(self, camera: Camera) -> np.ndarray:
        """(H, W) float32 distance from the eye along each pixel's centre ray (with ``stride`` > 1: its block's
        centre ray) to the quantile of the first collision, inf where the pixel sees (almost) no medium."""
        out = np.empty((camera.height, camera.width), dtype=np.float32)
        b = grid_depth_bounds(self.cells, self.bmin, self.grid_size, camera) if self.cells is not None else unbounded()
        _depth_image(self.grid, self.leap, self.bmin, self.bsize, self.per_unit, pack_view(camera),
                     self.min_opacity, self.quantile, self.stride, b.near, b.far, b.tile, out)
        return out


@njit(cache=True, inline="always")
def _box(bmin: np.ndarray, bsize: np.ndarray, ox: float, oy: float, oz: float, dx: float, dy: float,
         dz: float) -> tuple[float, float]:
    """Slab test (t_near clamped to 0, t_far); t_near >= t_far is a miss."""
    t0, t1 = 0.0, math.inf
    for a in range(3):
        o = (ox, oy, oz)[a]
        d = (dx, dy, dz)[a]
        lo = bmin[a]
        hi = bmin[a] + bsize[a]
        if abs(d) < 1e-300:
            if o < lo or o > hi:
                return 1.0, 0.0
            continue
        ta = (lo - o) / d
        tb = (hi - o) / d
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    return t0, t1


@njit(cache=True, inline="always")
def _axis(o: float, d: float, bmin: float, per_unit: float, n: int, t: float) -> tuple[int, int, float, float]:
    """DDA set-up on one axis at distance ``t``: (cell, step, distance of the next cell boundary, distance
    per cell)."""
    p = (o + t * d - bmin) * per_unit
    c = min(max(int(math.floor(p)), 0), n - 1)
    if d > 0.0:
        return c, 1, (bmin + (c + 1) / per_unit - o) / d, 1.0 / (per_unit * d)
    if d < 0.0:
        return c, -1, (bmin + c / per_unit - o) / d, -1.0 / (per_unit * d)
    return c, 0, math.inf, math.inf


@njit(cache=True, inline="always")
def _walk(grid: np.ndarray, leap: np.ndarray, bmin: np.ndarray, per_unit: np.ndarray, ox: float, oy: float,
          oz: float, dx: float, dy: float, dz: float, t0: float, t1: float, tau_stop: float,
          segs: np.ndarray) -> tuple[float, float, int]:
    """3-D DDA over the coarse cells from ``t0`` to ``t1``: (optical depth reached, distance where it reached
    ``tau_stop``, or inf if it never did, segments recorded). From an empty cell it jumps to where the ray leaves
    the empty cube ``leap`` holds for its direction octant, and sets the DDA up again there.

    Every segment of medium it crosses (up to ``segs.shape[0]``; -1: more than that) is recorded in ``segs`` as
    (distance where it starts, optical depth before it, its optical depth, sigma_t), so that
    :func:`_replay` finds where the walk reaches a smaller optical depth without walking again."""
    nx, ny, nz = grid.shape
    nudge = 1e-9 * (t1 - t0)  # a set-up at distance t finds the cell the ray enters, not the one behind it
    cx, sx, nxt, dtx = _axis(ox, dx, bmin[0], per_unit[0], nx, t0 + nudge)
    cy, sy, nyt, dty = _axis(oy, dy, bmin[1], per_unit[1], ny, t0 + nudge)
    cz, sz, nzt, dtz = _axis(oz, dz, bmin[2], per_unit[2], nz, t0 + nudge)
    octant = (sx >= 0) + 2 * (sy >= 0) + 4 * (sz >= 0)
    tau = 0.0
    t = t0
    n = 0
    while t < t1:
        sigma = grid[cx, cy, cz]
        r = int(leap[octant, cx, cy, cz])
        if r >= 2:
            # The r^3 cells from this one towards the ray's octant are empty: leave them on the axis whose r-th
            # boundary comes first (unless rounding left no progress to make: then step as usual).
            exit_t = min(nxt + (r - 1) * dtx, nyt + (r - 1) * dty, nzt + (r - 1) * dtz)
            if exit_t > t:
                if exit_t >= t1:
                    break
                t = exit_t
                cx, sx, nxt, dtx = _axis(ox, dx, bmin[0], per_unit[0], nx, t + nudge)
                cy, sy, nyt, dty = _axis(oy, dy, bmin[1], per_unit[1], ny, t + nudge)
                cz, sz, nzt, dtz = _axis(oz, dz, bmin[2], per_unit[2], nz, t + nudge)
                continue
        t_end = min(nxt, nyt, nzt, t1)
        if sigma > 0.0 and t_end > t:
            seg = sigma * (t_end - t)
            if 0 <= n < segs.shape[0]:
                segs[n, 0], segs[n, 1], segs[n, 2], segs[n, 3] = t, tau, seg, sigma
                n += 1
            else:
                n = -1
            if tau + seg >= tau_stop:
                return tau_stop, t + (tau_stop - tau) / sigma, n
            tau += seg
        t = t_end
        if nxt <= nyt and nxt <= nzt:
            cx += sx
            nxt += dtx
            if cx < 0 or cx >= nx:
                break
        elif nyt <= nzt:
            cy += sy
            nyt += dty
            if cy < 0 or cy >= ny:
                break
        else:
            cz += sz
            nzt += dtz
            if cz < 0 or cz >= nz:
                break
    return tau, math.inf, n


@njit(cache=True, inline="always")
def _replay(segs: np.ndarray, n: int, tau_stop: float) -> float:
    """Where the walk that recorded ``n`` segments reached optical depth ``tau_stop`` (inf if it never did): the
    same comparisons and arithmetic as :func:`_walk`'s, on its recorded values, so the same distance."""
    for k in range(n):
        t, tau, seg, sigma = segs[k, 0], segs[k, 1], segs[k, 2], segs[k, 3]
        if tau + seg >= tau_stop:
            return t + (tau_stop - tau) / sigma
    return math.inf


@njit(cache=True, parallel=True)
def _depth_image(grid: np.ndarray, leap: np.ndarray, bmin: np.ndarray, bsize: np.ndarray, per_unit: np.ndarray,
                 view: np.ndarray, min_opacity: float, quantile: float, stride: int, near: np.ndarray,
                 far: np.ndarray, tile: int, out: np.ndarray) -> None:
    """One depth per ``stride`` x ``stride`` block of pixels, along the ray through the centre of the pixels the
    block covers (module docstring), written to each of its pixels of ``out`` (H, W); walked only within the depth
    bounds ``near`` / ``far`` of its tile (``tile`` pixels a side) of the coarse grid's occupied cells."""
    height, width = out.shape
    h, w = -(-height // stride), -(-width // stride)
    ox, oy, oz = view[EYE], view[EYE + 1], view[EYE + 2]
    nty, ntx = near.shape
    for py in prange(h):
        # A ray crosses at most nx + ny + nz cells: room for every segment of its walk.
        segs = np.empty((grid.shape[0] + grid.shape[1] + grid.shape[2] + 4, 4))
        cy = 0.5 * (stride * py + min(stride * (py + 1), view[HEIGHT]))
        ty = min(int(cy) // tile, nty - 1)
        for px in range(w):
            cx = 0.5 * (stride * px + min(stride * (px + 1), view[WIDTH]))
            tx = min(int(cx) // tile, ntx - 1)
            depth = math.inf
            if not near[ty, tx] < math.inf:
                _fill_block(out, py, px, stride, depth)
                continue
            dx, dy, dz = pixel_direction(view, cx, cy)
            t0, t_exit = _box(bmin, bsize, ox, oy, oz, dx, dy, dz)
            t0 = max(t0, near[ty, tx])
            t1 = min(t_exit, far[ty, tx])
            if t0 < t1:
                tau_exit, _, n = _walk(grid, leap, bmin, per_unit, ox, oy, oz, dx, dy, dz, t0, t1, _TAU_OPAQUE,
                                       segs)
                opacity = 1.0 - math.exp(-tau_exit)
                if opacity >= min_opacity:
                    tau_half = -math.log(1.0 - quantile * opacity)
                    if n >= 0:  # the quantile lies on the walk so far (tau_half < tau_exit): no second walk
                        t_half = _replay(segs, n, tau_half)
                    else:
                        _, t_half, _ = _walk(grid, leap, bmin, per_unit, ox, oy, oz, dx, dy, dz, t0, t1, tau_half,
                                             segs[:0])
                    depth = t_half if t_half < math.inf else t_exit
            _fill_block(out, py, px, stride, depth)


@njit(cache=True, inline="always")
def _fill_block(out: np.ndarray, py: int, px: int, stride: int, depth: float) -> None:
    """Every pixel of block (py, px) of ``out`` gets ``depth``."""
    for y in range(stride * py, min(stride * (py + 1), out.shape[0])):
        for x in range(stride * px, min(stride * (px + 1), out.shape[1])):
            out[y, x] = depth
