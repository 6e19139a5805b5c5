"""Per-tile depth bounds of the medium seen by a camera: where along its rays a walk can meet anything.

A camera ray's walk over the majorant grid (:mod:`photon_fields.runtime.transport.tracking`) draws random numbers
only in occupied macrocells (majorant > 0); in empty ones it leaps or steps and computes every boundary in closed
form from the plane's index. So a walk started later or stopped earlier, anywhere in empty space, gives the same
samples bit for bit. What it saves is the walk through empty space in front of and behind the medium, and the whole
walk of the rays that meet no occupied macrocell at all (about 60 % of the tiles of the embedded scenes' views).

The bounds come from rasterizing the occupied macrocells into tiles of ``TILE`` x ``TILE`` pixels: each occupied
macrocell in front of the eye projects (its eight corners) to a rectangle of pixels, widened by one pixel on every
side (the camera jitters within the pixel), and every tile the rectangle touches gets

    near = min(near, distance from the eye to the macrocell's box)
    far  = max(far, distance from the eye to the macrocell's farthest corner)

A ray of the tile that crosses the macrocell enters it no nearer than ``near`` and leaves it no farther than
``far`` (the entry and exit points lie in the box), and a ray whose pixel the rectangle does not cover cannot
cross it (the projection of a box in front of a pinhole is the convex hull of its corners' projections). A
macrocell with a corner at or behind the eye's image plane (the eye inside or beside the volume) cannot be
projected: it widens every tile's bounds instead. Tiles no occupied macrocell covers keep ``near = inf``: their
rays escape (or miss the box) without a walk.

Only the *boundary* macrocells (occupied, with an empty or outside face neighbour) are rasterized, and the
interior ones only when they may hold the eye (a corner at or behind its image plane). That gives valid bounds:
a ray that meets the occupied macrocells first does so at a point of a boundary macrocell (of the closed boxes
holding the entry point, one is empty or outside the grid, and a chain of face neighbours among them leads from it
to an occupied one), and leaves them last at one, unless it starts inside them, in a macrocell that holds the eye
and widens every tile. Most occupied macrocells of a solid medium are interior ones, so this is several times
cheaper, for bounds that differ in a few tiles at most (bench/README.md). Which cells are boundary and which interior
does not depend on the camera: :func:`occupied_cells` lists them once per grid (kept with the medium), and a
camera's rasterization visits the boundary list, and the interior one only where the box reaches behind the eye's
image plane (no interior cell can otherwise).

``TILE`` = 4: at 512x512 the bounds take the forced estimator's first interactions
from 61-75 ms to 47-63 ms (bench/README.md); 8 and 16 pixels bound less, 1 and 2 cost more than they save. The
renderers compute them once per camera and resolution (:func:`depth_bounds_for`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from photon_fields.runtime.denoise.reprojection import EYE, FWD, HEIGHT, WIDTH, pack_view, project_direction
from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.medium import Medium

#: Tile edge in pixels.
TILE = 4
#: Distance (world units; the box's longest side is 1) by which the bounds are widened against rounding: a walk
#: that starts this much earlier in empty space changes nothing.
MARGIN = 1e-7
#: Cameras whose bounds :func:`depth_bounds_for` keeps per medium.
KEPT = 8
#: Depth along the view axis (world units) at or below which a corner counts as behind the eye (and widens every
#: tile): above it, a corner's pixel coordinates stay far inside int64 when floored.
_BEHIND = 1e-6
#: Pixel coordinates are clamped to +-this before flooring (a corner just in front of the eye projects far away).
_FAR_PIXEL = float(1 << 40)


@dataclass(frozen=True)
class DepthBounds:
    """``near`` / ``far`` (float64 (tiles_y, tiles_x)): eye distances outside which no ray of the tile meets an
    occupied macrocell (``near`` inf: none does), for tiles of ``tile`` x ``tile`` pixels."""

    tile: int
    near: np.ndarray
    far: np.ndarray


@njit(cache=True, inline="always")
def _interior(majorant: np.ndarray, i: int, j: int, k: int) -> bool:
    """Macrocell (i, j, k) and its six face neighbours are occupied (a neighbour outside the grid is not)."""
    cx, cy, cz = majorant.shape
    return (0 < i < cx - 1 and 0 < j < cy - 1 and 0 < k < cz - 1 and majorant[i - 1, j, k] > 0.0
            and majorant[i + 1, j, k] > 0.0 and majorant[i, j - 1, k] > 0.0 and majorant[i, j + 1, k] > 0.0
            and majorant[i, j, k - 1] > 0.0 and majorant[i, j, k + 1] > 0.0)


@njit(cache=True)
def _list_cells(majorant: np.ndarray, cells: np.ndarray, interior: np.ndarray) -> None:
    """The occupied macrocells in index order into ``cells`` (n, 3), each one's :func:`_interior` into ``interior``."""
    cx, cy, cz = majorant.shape
    n = 0
    for i in range(cx):
        for j in range(cy):
            for k in range(cz):
                if majorant[i, j, k] > 0.0:
                    cells[n, 0], cells[n, 1], cells[n, 2] = i, j, k
                    interior[n] = _interior(majorant, i, j, k)
                    n += 1


@dataclass(frozen=True)
class OccupiedCells:
    """A grid's occupied cells (:func:`occupied_cells`): their indices (n, 3), the boundary ones first, how many those
    are, and the grid's shape."""

    cells: np.ndarray
    n_boundary: int
    shape: tuple[int, int, int]


def occupied_cells(grid: np.ndarray) -> OccupiedCells:
    """The cells > 0 of ``grid`` that :func:`grid_depth_bounds` rasterizes, found once (a grid's cells do not change
    with the camera; the viewer asks for new bounds every moving frame)."""
    g = np.ascontiguousarray(grid, np.float64)
    n = int(np.count_nonzero(g > 0.0))
    cells, interior = np.empty((n, 3), np.int64), np.empty(n, np.bool_)
    _list_cells(g, cells, interior)
    return OccupiedCells(np.concatenate((cells[~interior], cells[interior])), int(n - interior.sum()),
                         (int(g.shape[0]), int(g.shape[1]), int(g.shape[2])))


@njit(cache=True)
def _rasterize(cells: np.ndarray, n_boundary: int, cx: int, cy: int, cz: int, bmin: np.ndarray, bsize: np.ndarray,
               view: np.ndarray, tile: int) -> tuple[np.ndarray, np.ndarray]:
    """The bounds of every tile of ``view`` (:func:`photon_fields.runtime.denoise.reprojection.pack_view`; module
    docstring) over the boundary cells (the first ``n_boundary`` of ``cells``), and the interior ones where the box
    reaches behind the eye's image plane (else none of them can), serially."""
    width, height = int(view[WIDTH]), int(view[HEIGHT])
    ex, ey, ez = view[EYE], view[EYE + 1], view[EYE + 2]
    tx = (width + tile - 1) // tile
    ty = (height + tile - 1) // tile
    near = np.full((ty, tx), np.inf)
    far = np.full((ty, tx), -np.inf)
    hx, hy, hz = bsize[0] / cx, bsize[1] / cy, bsize[2] / cz
    all_near = np.inf
    all_far = -np.inf
    fx_, fy_, fz_ = view[FWD], view[FWD + 1], view[FWD + 2]
    box_depth = (bmin[0] - ex) * fx_ + (bmin[1] - ey) * fy_ + (bmin[2] - ez) * fz_ + min(bsize[0] * fx_, 0.0) \
        + min(bsize[1] * fy_, 0.0) + min(bsize[2] * fz_, 0.0)  # the box's nearest corner along the view axis
    n = cells.shape[0] if box_depth <= _BEHIND else n_boundary
    for c in range(n):
        i, j, k = cells[c, 0], cells[c, 1], cells[c, 2]
        x0 = bmin[0] + i * hx
        y0 = bmin[1] + j * hy
        z0 = bmin[2] + k * hz
        if c >= n_boundary:
            # Covered by the boundary macrocells (module docstring) unless it may hold the eye: the nearest of its
            # corners along the view axis, in closed form.
            depth = (x0 - ex) * fx_ + (y0 - ey) * fy_ + (z0 - ez) * fz_ + min(hx * fx_, 0.0) \
                + min(hy * fy_, 0.0) + min(hz * fz_, 0.0)
            if depth > _BEHIND:
                continue
        gx = max(x0 - ex, 0.0, ex - x0 - hx)
        gy = max(y0 - ey, 0.0, ey - y0 - hy)
        gz = max(z0 - ez, 0.0, ez - z0 - hz)
        lo = math.sqrt(gx * gx + gy * gy + gz * gz) - MARGIN
        fx = max(abs(x0 - ex), abs(x0 + hx - ex))
        fy = max(abs(y0 - ey), abs(y0 + hy - ey))
        fz = max(abs(z0 - ez), abs(z0 + hz - ez))
        hi = math.sqrt(fx * fx + fy * fy + fz * fz) + MARGIN
        umin = vmin = np.inf
        umax = vmax = -np.inf
        behind = False
        for q in range(8):
            vx, vy, vz = x0 + hx * (q & 1) - ex, y0 + hy * ((q >> 1) & 1) - ey, z0 + hz * (q >> 2) - ez
            if vx * view[FWD] + vy * view[FWD + 1] + vz * view[FWD + 2] <= _BEHIND:
                behind = True
                break
            u, v, _ = project_direction(view, vx, vy, vz)
            u = min(max(u, -_FAR_PIXEL), _FAR_PIXEL)
            v = min(max(v, -_FAR_PIXEL), _FAR_PIXEL)
            umin, umax = min(umin, u), max(umax, u)
            vmin, vmax = min(vmin, v), max(vmax, v)
        if behind:
            all_near, all_far = min(all_near, lo), max(all_far, hi)
            continue
        # Pixels whose jittered rays (x in [p, p + 1)) can reach the rectangle, one pixel wider each side.
        a0 = max(math.floor(umin) - 1, 0)
        a1 = min(math.floor(umax) + 1, width - 1)
        b0 = max(math.floor(vmin) - 1, 0)
        b1 = min(math.floor(vmax) + 1, height - 1)
        if a0 > a1 or b0 > b1:
            continue  # beside the image
        for b in range(b0 // tile, b1 // tile + 1):
            for a in range(a0 // tile, a1 // tile + 1):
                near[b, a] = min(near[b, a], lo)
                far[b, a] = max(far[b, a], hi)
    if all_far >= 0.0:
        for b in range(ty):
            for a in range(tx):
                near[b, a] = min(near[b, a], all_near)
                far[b, a] = max(far[b, a], all_far)
    return near, far


@njit(cache=True, inline="always")
def ray_interval(near: np.ndarray, far: np.ndarray, tile: int, width: int, pixel: int, eye: np.ndarray, ox: float,
                 oy: float, oz: float, dx: float, dy: float, dz: float, tmax: float) -> tuple[float, float]:
    """The part [t0, t1] of a camera ray of ``pixel``, entering the box at o (its distances from there), where its
    tile's rays can meet an occupied macrocell; t0 >= t1: nowhere."""
    ty = (pixel // width) // tile
    tx = (pixel % width) // tile
    entry = (ox - eye[0]) * dx + (oy - eye[1]) * dy + (oz - eye[2]) * dz
    return max(0.0, near[ty, tx] - entry), min(tmax, far[ty, tx] - entry)


def camera_depth_bounds(m: Medium, camera: Camera, tile: int = TILE) -> DepthBounds:
    """The depth bounds of ``camera``'s tiles over ``m``'s occupied macrocells (module docstring)."""
    return grid_depth_bounds(m.majorant, m.bmin, m.bsize, camera, tile)


def grid_depth_bounds(grid: np.ndarray | OccupiedCells, bmin: np.ndarray, size: np.ndarray, camera: Camera,
                      tile: int = TILE) -> DepthBounds:
    """The depth bounds of ``camera``'s tiles over the cells > 0 of any ``grid`` of equal boxes spanning
    ``[bmin, bmin + size]`` (the majorant grid, or the depth maps' coarse extinction); ``grid`` may be its
    :func:`occupied_cells`, found once for many cameras."""
    cells = grid if isinstance(grid, OccupiedCells) else occupied_cells(grid)
    near, far = _rasterize(cells.cells, cells.n_boundary, *cells.shape, np.asarray(bmin, np.float64),
                           np.asarray(size, np.float64), pack_view(camera), int(tile))
    return DepthBounds(int(tile), near, far)


def unbounded() -> DepthBounds:
    """Bounds that bound nothing (one tile over any image, near 0, far inf): the walks of the whole ray, for
    comparisons."""
    return DepthBounds(1 << 30, np.zeros((1, 1)), np.full((1, 1), np.inf))


def depth_bounds_for(scene: Scene, m: Medium) -> DepthBounds:
    """:func:`camera_depth_bounds` of ``scene``'s camera over ``m``, kept with the scene's medium for the last
    :data:`KEPT` cameras (the viewer makes a scene object per frame; a resting view reuses its bounds)."""
    cache = scene.shared_cache("depth_bounds")
    cam = scene.camera
    key = (id(m), *cam.eye.tolist(), *cam.target.tolist(), *cam.up.tolist(), cam.fov, cam.fov_axis, cam.width,
           cam.height)
    hit = cache.pop(key, None)
    if hit is None or hit[0] is not m:
        occupied = scene.shared_cache("occupied_macrocells")  # the last medium's cells, for every camera over it
        if occupied.get("medium") is not m:
            occupied.update(medium=m, cells=occupied_cells(m.majorant))
        hit = (m, grid_depth_bounds(occupied["cells"], m.bmin, m.bsize, cam))
    cache[key] = hit  # the newest last
    while len(cache) > KEPT:
        del cache[next(iter(cache))]
    return hit[1]
