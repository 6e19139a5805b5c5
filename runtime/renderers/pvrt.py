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
``rotation`` (3x3: turns the whole lighting).
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit, prange

from photon_fields.runtime.pvrt.constants import DEFAULT_LIGHT_GRID
from photon_fields.runtime.pvrt.lighting import scene_lighting
from photon_fields.runtime.pvrt.radiance import light_volumes, radiance_volume
from photon_fields.runtime.pvrt.transfer import Transfer
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.medium import Medium, albedo_at, extinction_at
from photon_fields.runtime.transport.phase import hg_eval
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import empty_run
from photon_fields.runtime.wavefront.batches import RenderResult, StageTimer, finish
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.rays import clip_rays_to_volume, generate_camera_rays

_T_MIN = 1e-4  # as the ray marcher: stop once the camera ray is this opaque


@njit(cache=True, inline="always")
def _cell_coords(m: Medium, x: float, y: float, z: float, g: tuple) -> tuple[int, int, int, float, float, float]:
    """Lower corner and fractions of the trilinear stencil of a cell-centred grid of shape ``g`` at world x."""
    out_i = np.empty(3, dtype=np.int64)
    out_f = np.empty(3)
    for a, p in enumerate((x, y, z)):
        n = g[a]
        u = min(max((p - m.bmin[a]) / m.bsize[a] * n - 0.5, 0.0), n - 1.0)
        i = min(int(u), n - 2)
        out_i[a] = i
        out_f[a] = u - i
    return out_i[0], out_i[1], out_i[2], out_f[0], out_f[1], out_f[2]


@njit(cache=True, inline="always")
def _trilinear(vol: np.ndarray, i: int, j: int, k: int, fx: float, fy: float, fz: float) -> float:
    c00 = vol[i, j, k] * (1 - fx) + vol[i + 1, j, k] * fx
    c10 = vol[i, j + 1, k] * (1 - fx) + vol[i + 1, j + 1, k] * fx
    c01 = vol[i, j, k + 1] * (1 - fx) + vol[i + 1, j, k + 1] * fx
    c11 = vol[i, j + 1, k + 1] * (1 - fx) + vol[i + 1, j + 1, k + 1] * fx
    return (c00 * (1 - fy) + c10 * fy) * (1 - fz) + (c01 * (1 - fy) + c11 * fy) * fz


@njit(cache=True)
def _march_ray(m: Medium, rad: np.ndarray, lights: np.ndarray, travel: np.ndarray, rgb: np.ndarray, g: float,
               ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmax: float, jitter: float,
               h: float, out: np.ndarray) -> float:
    """One camera ray: adds L_d to out[0:3], L_i to out[3:6]; returns its transmittance."""
    rg = (rad.shape[0], rad.shape[1], rad.shape[2])
    lg = (lights.shape[1], lights.shape[2], lights.shape[3])
    T = 1.0
    t = jitter * h
    t_prev = 0.0
    empty_until = -math.inf
    while t_prev < tmax and T > _T_MIN:
        t_next = min(t, tmax)
        seg = t_next - t_prev
        tm = 0.5 * (t_prev + t_next)
        x, y, z = ox + tm * dx, oy + tm * dy, oz + tm * dz
        if tm >= empty_until:
            run = empty_run(m, x, y, z, dx, dy, dz)
            if run > 0.0:
                empty_until = tm + run
        if tm < empty_until:
            t_prev = t_next
            t = t_next + h
            continue
        sigma = extinction_at(m, x, y, z)
        if sigma > 0.0 and seg > 0.0:
            a0, a1, a2 = albedo_at(m, x, y, z)
            w = T * (1.0 - math.exp(-sigma * seg))
            i, j, k, fx, fy, fz = _cell_coords(m, x, y, z, rg)
            r = np.zeros(6)
            occ = _trilinear(rad[:, :, :, 6], i, j, k, fx, fy, fz)
            if occ > 0.0:  # interpolated photon energy / interpolated D_v (radiance.CHANNELS)
                for c in range(6):
                    r[c] = _trilinear(rad[:, :, :, c], i, j, k, fx, fy, fz) / occ
            if lights.shape[0] > 0:
                i, j, k, fx, fy, fz = _cell_coords(m, x, y, z, lg)
                for li in range(lights.shape[0]):
                    ph = hg_eval(g, -(dx * travel[li, 0] + dy * travel[li, 1] + dz * travel[li, 2]))
                    tr = _trilinear(lights[li], i, j, k, fx, fy, fz) * ph
                    r[0] += tr * rgb[li, 0]
                    r[1] += tr * rgb[li, 1]
                    r[2] += tr * rgb[li, 2]
            out[0] += w * a0 * r[0]
            out[1] += w * a1 * r[1]
            out[2] += w * a2 * r[2]
            out[3] += w * a0 * r[3]
            out[4] += w * a1 * r[4]
            out[5] += w * a2 * r[5]
            T *= math.exp(-sigma * seg)
        t_prev = t_next
        t = t_next + h
    return T if T > _T_MIN else 0.0


@njit(cache=True, parallel=True)
def _march(m: Medium, rad: np.ndarray, lights: np.ndarray, travel: np.ndarray, rgb: np.ndarray, g: float,
           o: np.ndarray, d: np.ndarray, tmax: np.ndarray, states: np.ndarray,
           h: float) -> tuple[np.ndarray, np.ndarray]:
    n = o.shape[1]
    out = np.zeros((6, n))
    trans = np.ones(n)
    for i in prange(n):
        states[i], jitter = next_float(states[i])
        acc = np.zeros(6)
        trans[i] = _march_ray(m, rad, lights, travel, rgb, g, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i],
                              tmax[i], jitter, h, acc)
        for c in range(6):
            out[c, i] = acc[c]
    return out, trans


def render_pvrt(scene: Scene, *, transfer: Transfer, spp: int = 1, seed: int = 0, batch_size: int = 1 << 18,
                progress: bool = True, step: float = 1.0, direct: str = "nee", light_grid: int = DEFAULT_LIGHT_GRID,
                sky=None, rotation: np.ndarray | None = None) -> RenderResult:  # noqa: ANN001  (sky: SkyFunction)
    """Render ``scene`` (its lights, plus ``sky``) from ``transfer`` (module docstring). ``stats`` records the
    notes of the lighting's projection (e.g. the NEE fall-back of a directional light)."""
    timer = StageTimer()
    t_start = time.perf_counter()
    transfer.check_scene(scene)
    m = scene.medium()
    with timer("project_lighting"):
        lighting = scene_lighting(scene.lights, transfer.basis, sky=sky, direct=direct, rotation=rotation)
    with timer("radiance_volume"):
        rad = radiance_volume(transfer, lighting, scene.camera.eye, scene.g)
    with timer("light_volumes"):
        lights = light_volumes(m, lighting.nee_directions, light_grid, float(scene.volume.voxel_size))
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
            out, trans = _march(m, rad, lights, travel, rgb, float(scene.g), rays.o, rays.d, rays.tmax, rays.rng, h)
        film.splat("L_d", rays.pixel, out[:3])
        film.splat("L_i", rays.pixel, out[3:])
        if see_sky:
            film.splat("L_e", rays.pixel, trans[None, :] * sky_at(rays.d))
    result = finish(film, timer, spp, t_start, {})
    result.stats["notes"] = "; ".join(lighting.notes)  # type: ignore[assignment]
    return result
