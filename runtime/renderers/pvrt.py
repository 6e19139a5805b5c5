"""The PVRT renderer (paper Sec. 7): relighting from a precomputed transfer (``pfn-train pvrt``).

Per frame (after a light or camera change): project the lighting into the basis (Sec. 7.1,
``runtime/pvrt/lighting.py``), evaluate the view-dependent radiance volume with early evaluation in CPCA space
(Sec. 7.2, ``runtime/pvrt/radiance.py``), march each directional light's light volume (its direct term by NEE,
the fall-back for a delta the basis cannot represent), then ray-march the camera rays (Sec. 7.3):

    L_d = sum_s T_s (1 - exp(-sigma_s dt)) albedo_s [R_direct(x_s) + sum_lights f_g(w_o, l) E T_light(x_s)]
    L_i = sum_s T_s (1 - exp(-sigma_s dt)) albedo_s R_ms(x_s)
    L_e = T_exit * sky(w)

with ``R`` the radiance volume (trilinear, cell-centred, D_v-weighted: ``runtime/pvrt/radiance.py``), sigma and
albedo from the full-resolution medium, the same segment quadrature and jittered start as
``runtime/renderers/ray_marcher.py`` and its empty-space skipping (``tracking.empty_run``). Layers L, L_d, L_i, L_e
as the other renderers.

Parameters: ``transfer`` (a :class:`photon_fields.runtime.pvrt.transfer.Transfer`, checked against the scene),
``step`` (camera step in voxels), ``direct`` ("nee": directional lights' direct term from light volumes, "transfer":
from the basis), ``light_grid`` (light-volume cells along the longest side), ``sky`` (a callable sky, Python API),
``rotation`` (3x3: turns the whole lighting), ``skip_empty`` (see :func:`render_pvrt`).
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit, prange

from photon_fields.runtime.pvrt.constants import DEFAULT_LIGHT_GRID
from photon_fields.runtime.pvrt.lighting import scene_lighting
from photon_fields.runtime.pvrt.radiance import grid_coord, light_volumes, radiance_volume
from photon_fields.runtime.pvrt.transfer import Transfer
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.medium import Medium, extinction_albedo_at
from photon_fields.runtime.transport.phase import hg_eval
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import TASK_ITEMS, empty_run, task_stride
from photon_fields.runtime.wavefront.batches import RenderResult, StageTimer, finish
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.rays import clip_rays_to_volume, generate_camera_rays

_T_MIN = 1e-4  # as the ray marcher: stop once the camera ray is this opaque


@njit(cache=True, inline="always")
def _stencil(m: Medium, x: float, y: float, z: float, gx: int, gy: int,
             gz: int) -> tuple[int, int, int, float, float, float]:
    """Lower corner and fractions of the trilinear stencil of a cell-centred (gx, gy, gz) grid over the box at x."""
    i, fx = grid_coord(x, m.bmin[0], m.bsize[0], gx)
    j, fy = grid_coord(y, m.bmin[1], m.bsize[1], gy)
    k, fz = grid_coord(z, m.bmin[2], m.bsize[2], gz)
    return i, j, k, fx, fy, fz


@njit(cache=True, inline="always")
def _trilinear(vol: np.ndarray, i: int, j: int, k: int, fx: float, fy: float, fz: float) -> float:
    c00 = vol[i, j, k] * (1 - fx) + vol[i + 1, j, k] * fx
    c10 = vol[i, j + 1, k] * (1 - fx) + vol[i + 1, j + 1, k] * fx
    c01 = vol[i, j, k + 1] * (1 - fx) + vol[i + 1, j, k + 1] * fx
    c11 = vol[i, j + 1, k + 1] * (1 - fx) + vol[i + 1, j + 1, k + 1] * fx
    return (c00 * (1 - fy) + c10 * fy) * (1 - fz) + (c01 * (1 - fy) + c11 * fy) * fz


@njit(cache=True, inline="always")
def _radiance_at(rad: np.ndarray, i: int, j: int, k: int, fx: float, fy: float, fz: float, r: np.ndarray) -> None:
    """r[0:6] = the D_v-weighted trilinear radiance (radiance.CHANNELS): the interpolated photon energy of each
    channel over the interpolated D_v (channel 6), 0 where D_v interpolates to 0. All channels share the
    stencil's weights, and a corner's channels are adjacent in memory."""
    for c in range(7):
        r[c] = 0.0
    for corner in range(8):
        a, b, e = corner & 1, (corner >> 1) & 1, corner >> 2
        w = (fx if a else 1.0 - fx) * (fy if b else 1.0 - fy) * (fz if e else 1.0 - fz)
        for c in range(7):
            r[c] += w * rad[i + a, j + b, k + e, c]
    if r[6] > 0.0:
        inv = 1.0 / r[6]
        for c in range(6):
            r[c] *= inv
    else:
        for c in range(6):
            r[c] = 0.0


@njit(cache=True)
def _march_items(m: Medium, rad: np.ndarray, lights: np.ndarray, travel: np.ndarray, rgb: np.ndarray, g: float,
                 o: np.ndarray, d: np.ndarray, tmax: np.ndarray, states: np.ndarray, h: float, skip: bool,
                 out: np.ndarray, trans: np.ndarray, lo: int, hi: int) -> None:
    """Camera rays lo..hi-1 of :func:`_march`, serially (``TASK_ITEMS`` in the tracking module says why): L_d into
    out[0:3], L_i into out[3:6], the transmittance into ``trans``. Segment s of a ray spans [t_{s-1}, t_s] with
    t_s = (jitter + s) h (t_{-1} = 0), sampled at its midpoint; over an empty run (:func:`empty_run`) the walk
    jumps to the first segment whose midpoint is past it (the midpoints it passes have sigma_t = 0 and add
    nothing), so empty space costs one step per run, not one per segment (``skip`` False: every midpoint looked
    up, the same sums). (The rays are not a kernel of their own: an inlined call per ray took and released a
    reference to each of its 13 arrays.)"""
    r = np.empty(7)  # one sample's radiance, reused by every sample of the task
    nl = lights.shape[0]
    for ray in range(lo, hi):
        states[ray], jitter = next_float(states[ray])
        ox, oy, oz, dx, dy, dz = o[0, ray], o[1, ray], o[2, ray], d[0, ray], d[1, ray], d[2, ray]
        t_end = tmax[ray]
        T = 1.0
        s = 0
        t_prev = 0.0
        empty_until = -math.inf
        while t_prev < t_end and T > _T_MIN:
            t_next = min((jitter + s) * h, t_end)
            seg = t_next - t_prev
            tm = 0.5 * (t_prev + t_next)
            x, y, z = ox + tm * dx, oy + tm * dy, oz + tm * dz
            if skip and tm >= empty_until:
                run = empty_run(m, x, y, z, dx, dy, dz)
                if run > 0.0:
                    empty_until = tm + run
            if tm < empty_until:  # floor() never passes the first s with (jitter + s - 0.5) h >= empty_until
                s = max(s + 1, int(min(math.floor(empty_until / h - jitter + 0.5), t_end / h + 2.0)))
                t_prev = (jitter + s - 1) * h
                continue
            sigma, a0, a1, a2 = extinction_albedo_at(m, x, y, z)
            if sigma > 0.0 and seg > 0.0:
                w = T * (1.0 - math.exp(-sigma * seg))
                i, j, k, fx, fy, fz = _stencil(m, x, y, z, rad.shape[0], rad.shape[1], rad.shape[2])
                _radiance_at(rad, i, j, k, fx, fy, fz, r)
                if nl > 0:
                    i, j, k, fx, fy, fz = _stencil(m, x, y, z, lights.shape[1], lights.shape[2], lights.shape[3])
                    for li in range(nl):
                        ph = hg_eval(g, -(dx * travel[li, 0] + dy * travel[li, 1] + dz * travel[li, 2]))
                        tr = _trilinear(lights[li], i, j, k, fx, fy, fz) * ph
                        r[0] += tr * rgb[li, 0]
                        r[1] += tr * rgb[li, 1]
                        r[2] += tr * rgb[li, 2]
                out[0, ray] += w * a0 * r[0]
                out[1, ray] += w * a1 * r[1]
                out[2, ray] += w * a2 * r[2]
                out[3, ray] += w * a0 * r[3]
                out[4, ray] += w * a1 * r[4]
                out[5, ray] += w * a2 * r[5]
                T *= math.exp(-sigma * seg)
            s += 1
            t_prev = t_next
        trans[ray] = T if T > _T_MIN else 0.0


@njit(cache=True, parallel=True)
def _march(m: Medium, rad: np.ndarray, lights: np.ndarray, travel: np.ndarray, rgb: np.ndarray, g: float,
           o: np.ndarray, d: np.ndarray, tmax: np.ndarray, states: np.ndarray, h: float,
           skip: bool) -> tuple[np.ndarray, np.ndarray]:
    n = o.shape[1]
    out = np.zeros((6, n))
    trans = np.ones(n)
    tasks = (n + TASK_ITEMS - 1) // TASK_ITEMS
    stride = task_stride(tasks)
    for task in prange(tasks):
        b = (task * stride) % tasks  # blocks spread over the image (task_stride)
        _march_items(m, rad, lights, travel, rgb, g, o, d, tmax, states, h, skip, out, trans, b * TASK_ITEMS,
                     min(n, (b + 1) * TASK_ITEMS))
    return out, trans


def render_pvrt(scene: Scene, *, transfer: Transfer, spp: int = 1, seed: int = 0, batch_size: int = 1 << 18,
                progress: bool = True, step: float = 1.0, direct: str = "nee", light_grid: int = DEFAULT_LIGHT_GRID,
                sky=None, rotation: np.ndarray | None = None,  # noqa: ANN001  (sky: SkyFunction)
                skip_empty: bool = True) -> RenderResult:
    """Render ``scene`` (its lights, plus ``sky``) from ``transfer`` (module docstring). ``stats`` records the
    notes of the lighting's projection (e.g. the NEE fall-back of a directional light). ``skip_empty``: camera
    and shadow rays look nothing up in empty macrocells and the light volumes march only the cells a camera sample
    in the medium can read (the same image, sooner; False: every sample and cell, the reference of the tests)."""
    timer = StageTimer()
    t_start = time.perf_counter()
    transfer.check_scene(scene)
    m = scene.medium()
    with timer("project_lighting"):
        lighting = scene_lighting(scene.lights, transfer.basis, sky=sky, direct=direct, rotation=rotation)
    with timer("radiance_volume"):
        rad = radiance_volume(transfer, lighting, scene.camera.eye, scene.g)
    with timer("light_volumes"):
        lights = light_volumes(m, lighting.nee_directions, light_grid, float(scene.volume.voxel_size), skip_empty)
    cam = scene.camera
    film = Film(cam.width, cam.height)
    h = step * scene.volume.voxel_size
    n_pixels = cam.width * cam.height
    travel = np.ascontiguousarray(lighting.nee_directions, dtype=np.float64)
    rgb = np.ascontiguousarray(lighting.nee_rgb, dtype=np.float64)

    def sky_at(dirs: np.ndarray) -> np.ndarray:  # (3, n) view directions -> (3, n) what they see
        v = np.broadcast_to(lighting.constant_sky[:, None], dirs.shape).astype(np.float64)
        if lighting.sky is not None:
            v = lighting.sky(np.ascontiguousarray(dirs.T)).T
        return v

    see_sky = lighting.sky is not None or np.any(lighting.constant_sky > 0)
    for start in range(0, n_pixels * spp, batch_size):
        work = np.arange(start, min(start + batch_size, n_pixels * spp), dtype=np.int64)
        with timer("generate_camera_rays"):
            rays = generate_camera_rays(cam, work, seed)
            hit = clip_rays_to_volume(m, rays)
        if see_sky and not np.all(hit):
            film.splat("L_e", rays.pixel[~hit], sky_at(rays.d[:, ~hit]))
        rays = rays.compact(hit)
        with timer("march"):
            out, trans = _march(m, rad, lights, travel, rgb, float(scene.g), rays.o, rays.d, rays.tmax, rays.rng, h,
                                skip_empty)
        film.splat("L_d", rays.pixel, out[:3])
        film.splat("L_i", rays.pixel, out[3:])
        if see_sky:
            film.splat("L_e", rays.pixel, trans[None, :] * sky_at(rays.d))
    result = finish(film, timer, spp, t_start, {})
    result.stats["notes"] = "; ".join(lighting.notes)  # type: ignore[assignment]
    return result
