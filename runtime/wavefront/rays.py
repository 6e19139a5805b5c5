"""Structure-of-arrays ray batches and the camera ray-generation stage.

A :class:`RayBatch` stores one array per attribute (``o`` and ``d`` as (3, n) so that each coordinate is
contiguous). Stages are functions over a whole batch; rays that terminate are removed by
:meth:`RayBatch.compact` so no later stage sees holes (pbrt-v4's wavefront queues, in numpy form).

Work items are numbered ``w = sample * n_pixels + pixel``; the item's random stream is ``w`` under the
render seed (:mod:`photon_fields.runtime.transport.rng`), so images do not depend on how work is split into batches,
nor on the order in which they are taken (:func:`tiled_work`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields

import numpy as np
from numba import njit, prange

from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.transport.medium import Medium, intersect_box
from photon_fields.runtime.transport.rng import next_float, stream_state

#: Edge, in pixels, of the square tiles :func:`tiled_work` hands out work in: 16 x 16 = 256 rays, one task of the
#: ray marcher's kernel (``tracking.TASK_ITEMS``); 8 and 32 measured within 10 % of it (bench/README.md).
PIXEL_TILE = 16


@dataclass
class RayBatch:
    pixel: np.ndarray  # int64 (n,): flat pixel index (row-major, y down)
    o: np.ndarray  # float64 (3, n): origin (on or inside the volume box once clipped)
    d: np.ndarray  # float64 (3, n): unit travel direction
    tmax: np.ndarray  # float64 (n,): distance to the box exit along d
    beta: np.ndarray  # float64 (3, n): path throughput
    rng: np.ndarray  # uint64 (n,): per-ray random state
    depth: np.ndarray  # int64 (n,): number of scattering vertices so far
    pdf: np.ndarray  # float64 (n,): pdf of the last phase-sampled direction (inf: camera ray / delta)

    def __len__(self) -> int:
        return int(self.pixel.shape[0])

    def compact(self, keep: np.ndarray) -> RayBatch:
        """The rays where ``keep`` is true, densely packed (``take`` on the index list: faster than boolean
        indexing of the (3, n) arrays)."""
        idx = np.flatnonzero(keep)
        return RayBatch(**{f.name: getattr(self, f.name).take(idx, axis=-1) for f in fields(self)})


@functools.lru_cache(maxsize=8)
def tile_order(width: int, height: int, tile: int = PIXEL_TILE) -> np.ndarray:
    """The image's flat pixels (row-major) in tile order, a permutation of ``0 .. width * height - 1``: bands of
    ``tile`` rows from the top, each band's tiles from the left, each tile's pixels row by row (the last band and
    the last tile of a band as high and as wide as the image leaves them).

    Why: a ray that marches through a large volume reads a new cache line of the density grid and of the light
    volume at almost every step. Its neighbours on the same image row read the same lines, but the rows above and
    below come thousands of rays later, when those lines are gone. Taken a tile at a time, a line serves the rays
    of several rows while it is still cached (bench/README.md: the preview at 256^3 1.4-1.8x faster; at 96^3 the
    volume stays cached and nothing changes)."""
    q = np.arange(width * height, dtype=np.int64)
    band = q // (tile * width)
    rows = np.minimum(tile, height - band * tile)  # rows in this band
    r = q - band * (tile * width)
    col = r // (tile * rows)  # tile column: every tile before the band's last is tile pixels wide
    j = r - col * (tile * rows)
    cols = np.minimum(tile, width - col * tile)  # this tile's width
    order = (band * tile + j // cols) * width + col * tile + j % cols
    order.flags.writeable = False  # cached: shared by every frame of this size
    return order


def tiled_work(first: int, count: int, order: np.ndarray) -> np.ndarray:
    """Work items for positions ``first .. first + count - 1`` of a render taken in the pixel order ``order``
    (:func:`tile_order`): position ``sample * n + i`` is item ``sample * n + order[i]`` (n = ``order.size``). The
    items, and so every sample, are those of ``first .. first + count - 1`` in row order when the positions cover
    whole samples; a batch of at most n positions holds each pixel at most once (``Film.splat``'s ``distinct``)."""
    return _tiled_work(int(first), int(count), order)


@njit(cache=True)
def _tiled_work(first: int, count: int, order: np.ndarray) -> np.ndarray:
    n = order.shape[0]
    work = np.empty(count, np.int64)
    sample, i = divmod(first, n)
    for k in range(count):
        work[k] = sample * n + order[i]
        i += 1
        if i == n:
            sample, i = sample + 1, 0
    return work


@njit(cache=True, inline="always")
def camera_ray(origin: np.ndarray, du: np.ndarray, dv: np.ndarray, width: int, n_pixels: int, w: int,
               seed: np.uint64) -> tuple[float, float, float, int, np.uint64]:
    """Work item ``w``'s jittered primary ray: (unit direction dx, dy, dz, flat pixel, random state after the
    two jitter draws). The only copy of the arithmetic, so every renderer's camera rays agree bit for bit
    (the fused first-interaction kernel of :mod:`photon_fields.runtime.wavefront.first_interaction` inlines it too)."""
    p = w % n_pixels
    s = stream_state(seed, np.uint64(w))
    s, ju = next_float(s)
    s, jv = next_float(s)
    x = (p % width) + ju
    y = (p // width) + jv
    dx = origin[0] + x * du[0] + y * dv[0]
    dy = origin[1] + x * du[1] + y * dv[1]
    dz = origin[2] + x * du[2] + y * dv[2]
    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx * inv, dy * inv, dz * inv, p, s


@njit(cache=True, parallel=True)
def _camera_rays(origin: np.ndarray, du: np.ndarray, dv: np.ndarray, width: int, n_pixels: int,
                 work: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = work.shape[0]
    d = np.empty((3, n))
    pixel = np.empty(n, dtype=np.int64)
    states = np.empty(n, dtype=np.uint64)
    for i in prange(n):
        d[0, i], d[1, i], d[2, i], pixel[i], states[i] = camera_ray(origin, du, dv, width, n_pixels, work[i],
                                                                   np.uint64(seed))
    return d, pixel, states


def camera_directions(camera: Camera, work: np.ndarray, seed: int) -> np.ndarray:
    """The unit directions (3, n) of work items ``work``'s camera rays under ``seed``: :func:`camera_ray` again
    (the same jitter draws), for the environment seen behind them by renderers whose fused kernels keep no
    direction."""
    origin, du, dv = camera.image_plane()
    return _camera_rays(origin, du, dv, camera.width, camera.width * camera.height,
                        np.ascontiguousarray(work, dtype=np.int64), int(seed))[0]


def generate_camera_rays(camera: Camera, work: np.ndarray, seed: int) -> RayBatch:
    """Stage 1: one jittered primary ray per work item (unclipped: tmax = inf)."""
    origin, du, dv = camera.image_plane()
    d, pixel, states = _camera_rays(origin, du, dv, camera.width, camera.width * camera.height,
                                    np.ascontiguousarray(work, dtype=np.int64), int(seed))
    n = d.shape[1]
    o = np.repeat(camera.eye.reshape(3, 1), n, axis=1)
    return RayBatch(pixel, o, d, np.full(n, np.inf), np.ones((3, n)), states, np.zeros(n, dtype=np.int64),
                    np.full(n, np.inf))


@njit(cache=True, inline="always")
def clip_to_box(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float,
                dz: float) -> tuple[bool, float, float, float, float]:
    """(hits the box, origin moved to the box entry, distance to the box exit from there); the only copy
    of the arithmetic (see :func:`camera_ray`). A miss returns the origin unmoved and 0."""
    t0, t1 = intersect_box(m, ox, oy, oz, dx, dy, dz)
    if t0 < t1:
        return True, ox + t0 * dx, oy + t0 * dy, oz + t0 * dz, t1 - t0
    return False, ox, oy, oz, 0.0


@njit(cache=True, parallel=True)
def _clip(m: Medium, o: np.ndarray, d: np.ndarray, tmax: np.ndarray) -> np.ndarray:
    n = o.shape[1]
    hit = np.empty(n, dtype=np.bool_)
    for i in prange(n):
        hit[i], o[0, i], o[1, i], o[2, i], tmax[i] = clip_to_box(m, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i],
                                                                 d[2, i])
    return hit


def clip_rays_to_volume(m: Medium, rays: RayBatch) -> np.ndarray:
    """Move each origin to its box entry point (in place) and set ``tmax`` to the box exit distance.
    Returns the mask of rays that intersect the box."""
    return _clip(m, rays.o, rays.d, rays.tmax)
