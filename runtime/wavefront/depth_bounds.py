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

``TILE`` = 4: at 512x512 the bounds cost 1-3 ms on one core and take the forced estimator's first interactions
from 61-75 ms to 47-63 ms (bench/README.md); 8 and 16 pixels bound less, 1 and 2 cost more than they save. The
renderers compute them once per camera and resolution (:func:`depth_bounds_for`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

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


@njit(cache=True)
def _corner_pixel(px: float, py: float, pz: float, fwd: np.ndarray, f2: float, du: np.ndarray, du2: float,
                  dv: np.ndarray, dv2: float, odu: float, odv: float) -> tuple[float, float, float]:
    """(depth along the view axis, pixel x, pixel y) of the point (px, py, pz) relative to the eye: the inverse of
    ``camera_ray``'s ``origin + x du + y dv`` (du, dv orthogonal to each other and to the view axis)."""
    depth = (px * fwd[0] + py * fwd[1] + pz * fwd[2]) / f2
    if depth <= _BEHIND:
        return depth, 0.0, 0.0
    u = ((px * du[0] + py * du[1] + pz * du[2]) / depth - odu) / du2
    v = ((px * dv[0] + py * dv[1] + pz * dv[2]) / depth - odv) / dv2
    return depth, u, v


@njit(cache=True)
def _rasterize(majorant: np.ndarray, bmin: np.ndarray, bsize: np.ndarray, eye: np.ndarray, origin: np.ndarray,
               du: np.ndarray, dv: np.ndarray, width: int, height: int, tile: int) -> tuple[np.ndarray, np.ndarray]:
    """The bounds of every tile (module docstring), serially: 1-3 ms for a 48^3 grid at 512x512."""
    tx = (width + tile - 1) // tile
    ty = (height + tile - 1) // tile
    near = np.full((ty, tx), np.inf)
    far = np.full((ty, tx), -np.inf)
    du2 = du[0] * du[0] + du[1] * du[1] + du[2] * du[2]
    dv2 = dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]
    odu = origin[0] * du[0] + origin[1] * du[1] + origin[2] * du[2]
    odv = origin[0] * dv[0] + origin[1] * dv[1] + origin[2] * dv[2]
    fwd = origin - (odu / du2) * du - (odv / dv2) * dv  # the view axis (origin's part orthogonal to du, dv)
    f2 = fwd[0] * fwd[0] + fwd[1] * fwd[1] + fwd[2] * fwd[2]
    cx, cy, cz = majorant.shape
    hx, hy, hz = bsize[0] / cx, bsize[1] / cy, bsize[2] / cz
    all_near = np.inf
    all_far = -np.inf
    for i in range(cx):
        x0 = bmin[0] + i * hx
        for j in range(cy):
            y0 = bmin[1] + j * hy
            for k in range(cz):
                if not majorant[i, j, k] > 0.0:
                    continue
                z0 = bmin[2] + k * hz
                gx = max(x0 - eye[0], 0.0, eye[0] - x0 - hx)
                gy = max(y0 - eye[1], 0.0, eye[1] - y0 - hy)
                gz = max(z0 - eye[2], 0.0, eye[2] - z0 - hz)
                lo = math.sqrt(gx * gx + gy * gy + gz * gz) - MARGIN
                fx = max(abs(x0 - eye[0]), abs(x0 + hx - eye[0]))
                fy = max(abs(y0 - eye[1]), abs(y0 + hy - eye[1]))
                fz = max(abs(z0 - eye[2]), abs(z0 + hz - eye[2]))
                hi = math.sqrt(fx * fx + fy * fy + fz * fz) + MARGIN
                umin = vmin = np.inf
                umax = vmax = -np.inf
                behind = False
                for c in range(8):
                    depth, u, v = _corner_pixel(x0 + hx * (c & 1) - eye[0], y0 + hy * ((c >> 1) & 1) - eye[1],
                                                z0 + hz * (c >> 2) - eye[2], fwd, f2, du, du2, dv, dv2, odu, odv)
                    if depth <= _BEHIND:
                        behind = True
                        break
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


def camera_depth_bounds(m: Medium, camera: Camera, tile: int = TILE) -> DepthBounds:
    """The depth bounds of ``camera``'s tiles over ``m``'s occupied macrocells (module docstring)."""
    origin, du, dv = camera.image_plane()
    near, far = _rasterize(m.majorant, m.bmin, m.bsize, np.ascontiguousarray(camera.eye, dtype=np.float64),
                           np.ascontiguousarray(origin, dtype=np.float64), np.ascontiguousarray(du, dtype=np.float64),
                           np.ascontiguousarray(dv, dtype=np.float64), camera.width, camera.height, int(tile))
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
        hit = (m, camera_depth_bounds(m, cam))
    cache[key] = hit  # the newest last
    while len(cache) > KEPT:
        del cache[next(iter(cache))]
    return hit[1]
