"""Ray marcher with global shadows: the paper's ray-marching baseline (Sec. 4.3), single scattering only.

Parameters
----------
step : float (default 0.5)
    Step length along camera rays in voxels (of the smallest voxel edge).
shadow_step : float (default 1.0)
    Step length along shadow rays in voxels. Where sigma_t h reaches ~1 per voxel at sharp boundaries (bone in a
    CT transfer function, a shell's wall) the midpoint sum's error across a boundary is of order 1 and differs from
    ray to ray, and exp(-tau) averaged over such errors is biased high: single scattering reads bright there (the
    camera march errs the other way, less). A finer step shrinks the bias quickly (bench/README.md, ray marcher);
    the path tracer's trackers are unbiased.
spp : int
    Jittered passes per pixel (a random start offset along each ray removes wood-grain banding).
seed : int
    Jitter streams are keyed like the path tracer's: same seed, same image.

For each camera ray the marcher integrates, segment by segment,

    L_d = sum_k T_k * albedo_k * (1 - exp(-sigma_k h)) * sum_lights f_g(d . l) * Le * T_shadow(x_k -> light)

where ``T_k`` is the transmittance from the camera to the segment and ``T_shadow`` is a marched
transmittance towards each delta light ("global shadows"). The environment light is not marched (it
would need a sphere of shadow rays); it only appears unscattered, as ``L_e = T * L_env``. This is the
same single-scattering integral the path tracer estimates with ``max_depth = 1``; the two agree up to
the marcher's quadrature error, which the tests check. There is no L_i: multiple scattering is
exactly what ray marching leaves out.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit, prange

from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.emitters import delta_light_direction
from photon_fields.runtime.transport.medium import Medium, albedo_at, extinction_at, intersect_box
from photon_fields.runtime.transport.phase import hg_eval
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import TASK_ITEMS, empty_run
from photon_fields.runtime.wavefront.batches import (
    RenderResult,
    StageTimer,
    finish,
    primary_ray_batches,
    scene_environment,
)
from photon_fields.runtime.wavefront.film import Film

_T_MIN = 1e-4  # stop marching once the camera ray is this opaque: the rest cannot contribute
_TAU_MAX = 20.0  # a shadow ray this deep is dark (transmittance 2e-9)


@njit(cache=True, inline="always")
def march_transmittance(m: Medium, px: float, py: float, pz: float, lx: float, ly: float, lz: float, tend: float,
                        h: float, skip: bool, tau_max: float = _TAU_MAX) -> float:
    """exp(-integral of sigma_t) from p towards l over [0, min(tend, box exit)], midpoint rule; ``skip``: no
    lookups at the midpoints that lie in empty macrocells (:func:`empty_run`; the same sum): the walk jumps to the
    first midpoint past the empty run instead of stepping over each, so empty space costs one step per run.
    0 once the optical depth passes ``tau_max`` (the rest of the ray is not marched)."""
    t0, t1 = intersect_box(m, px, py, pz, lx, ly, lz)
    if t0 >= t1:
        return 1.0
    t1 = min(t1, tend)
    n = max(1, int(math.ceil((t1 - t0) / h)))
    hh = (t1 - t0) / n
    tau = 0.0
    empty_until = -math.inf
    k = 0
    while k < n:
        t = t0 + (k + 0.5) * hh
        if t < empty_until:
            # floor() never passes the first midpoint >= empty_until, and the test above is repeated there:
            # the same midpoints are summed as stepping one by one would, bit for bit
            k = max(k + 1, int(min(math.floor((empty_until - t0) / hh - 0.5), n)))
            continue
        k += 1
        x, y, z = px + t * lx, py + t * ly, pz + t * lz
        if skip:
            run = empty_run(m, x, y, z, lx, ly, lz)
            if run > 0.0:
                empty_until = t + run
                continue
        tau += extinction_at(m, x, y, z) * hh
        if tau > tau_max:
            return 0.0
    return math.exp(-tau)


@njit(cache=True)
def _march_items(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, o: np.ndarray, d: np.ndarray,
                 tmax: np.ndarray, states: np.ndarray, h: float, h_shadow: float, skip: bool, ld: np.ndarray,
                 trans: np.ndarray, lo: int, hi: int) -> None:
    """Rays lo..hi-1 of :func:`_march`, serially (``TASK_ITEMS`` in the tracking module says why)."""
    for i in range(lo, hi):
        states[i], jitter = next_float(states[i])
        dx, dy, dz = d[0, i], d[1, i], d[2, i]
        T = 1.0
        t = jitter * h  # first segment [0, jitter*h) is folded into the last partial one below
        t_prev = 0.0
        empty_until = -math.inf
        while t_prev < tmax[i] and T > _T_MIN:
            t_next = min(t, tmax[i])
            seg = t_next - t_prev
            tm = 0.5 * (t_prev + t_next)
            x, y, z = o[0, i] + tm * dx, o[1, i] + tm * dy, o[2, i] + tm * dz
            if skip and tm >= empty_until:
                run = empty_run(m, x, y, z, dx, dy, dz)
                if run > 0.0:
                    empty_until = tm + run
            if tm < empty_until:  # in empty space: sigma_t is 0 here, the sums stay as they are
                t_prev = t_next
                t = t_next + h
                continue
            sigma = extinction_at(m, x, y, z)
            if sigma > 0.0 and seg > 0.0:
                a0, a1, a2 = albedo_at(m, x, y, z)
                w = T * (1.0 - math.exp(-sigma * seg))
                for k in range(kind.shape[0]):
                    # The environment is not marched (module docstring): delta_light_direction gives it 0.
                    lx, ly, lz, scale, tend = delta_light_direction(kind[k], vec[k], x, y, z)
                    c = w * scale * hg_eval(g, dx * lx + dy * ly + dz * lz)
                    if c <= 0.0:
                        continue
                    c *= march_transmittance(m, x, y, z, lx, ly, lz, tend, h_shadow, skip)
                    ld[0, i] += c * a0 * rgb[k, 0]
                    ld[1, i] += c * a1 * rgb[k, 1]
                    ld[2, i] += c * a2 * rgb[k, 2]
                T *= math.exp(-sigma * seg)
            t_prev = t_next
            t = t_next + h
        trans[i] = T if T > _T_MIN else 0.0


@njit(cache=True, parallel=True)
def _march(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, o: np.ndarray, d: np.ndarray,
           tmax: np.ndarray, states: np.ndarray, h: float, h_shadow: float,
           skip: bool) -> tuple[np.ndarray, np.ndarray]:
    n = o.shape[1]
    ld = np.zeros((3, n))
    trans = np.ones(n)
    for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):
        _march_items(m, kind, vec, rgb, g, o, d, tmax, states, h, h_shadow, skip, ld, trans, task * TASK_ITEMS,
                     min(n, (task + 1) * TASK_ITEMS))
    return ld, trans


def render_ray_marched(scene: Scene, *, spp: int = 1, step: float = 0.5, shadow_step: float = 1.0, seed: int = 0,
                       batch_size: int = 1 << 17, progress: bool = True, skip_empty: bool = True) -> RenderResult:
    """Single scattering by ray marching: ``step`` and ``shadow_step`` are the camera and shadow ray step
    lengths in voxels; ``spp`` jittered passes per pixel. Layers L, L_e and L_d (L_i stays zero).
    ``skip_empty``: camera and shadow rays look nothing up in empty macrocells (the same image, sooner;
    False: every sample looked up, the reference the tests and ``bench_ray_marcher.py`` compare with)."""
    m = scene.medium()
    kind, vec, rgb = scene.packed_lights()
    env = scene_environment(scene)
    h = step * scene.volume.voxel_size
    hs = shadow_step * scene.volume.voxel_size
    film = Film(scene.camera.width, scene.camera.height)
    timer = StageTimer()
    t_start = time.perf_counter()
    for rays in primary_ray_batches(scene, film, timer, spp=spp, seed=seed, batch_size=batch_size,
                                    progress=progress, desc="ray marching"):
        with timer("march"):
            ld, trans = _march(m, kind, vec, rgb, scene.g, rays.o, rays.d, rays.tmax, rays.rng, h, hs, skip_empty)
        film.splat("L_d", rays.pixel, ld)
        if env is not None:
            film.splat("L_e", rays.pixel, trans[None, :] * env.radiance(rays.d))
    return finish(film, timer, spp, t_start, {})
