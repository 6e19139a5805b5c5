"""Reference volumetric path tracer (wavefront), the ground truth the neural renderer is judged against.

Parameters
----------
spp : int >= 1
    Samples per pixel.
max_depth : int >= 1 (default 16)
    Maximum number of scattering vertices on a path ("max path length 16" in the paper's Table 2), with
    or without NEE: the image holds exactly the light of paths with 1 .. ``max_depth`` scattering
    vertices. ``max_depth = 1`` is single scattering.
nee : bool (default True)
    Next-event estimation at every vertex, combined with phase sampling by MIS (power heuristic)
    for the environment light. ``False`` = pure phase sampling (only the environment is reachable);
    both converge to the same image at every ``max_depth``, which the tests check.

What ``max_depth`` cuts, per estimator:

- NEE: vertex ``k < max_depth`` splits the environment between its NEE sample (weight ``w_nee``) and its
  phase-sampled continuation, which escapes with weight ``1 - w_nee``. The last vertex has no
  continuation, so its NEE sample takes the full weight (``env_mis=False``); otherwise the escape share of
  the last vertex would be lost (35 % of single scattering under a constant environment at g = -0.4).
- Pure phase sampling: a path's light is picked up when it escapes after its last vertex, so the last
  vertex still samples a direction and flies once more; that flight only counts if it escapes (a
  collision would be vertex ``max_depth + 1``).
rr_depth : int (default 3)
    Russian roulette starts after this many vertices; survival probability = max throughput
    component, capped at 0.95.
batch_size : int
    Work items (pixel samples) per wavefront batch; bounds memory.
seed : int
    Random streams are keyed by (seed, sample, pixel): same seed, same image, for any batch size or
    thread count.

Stages of one batch, each a function over a structure-of-arrays :class:`photon_fields.runtime.wavefront.rays.RayBatch`:
``generate_camera_rays`` -> ``clip_rays_to_volume`` -> repeat { ``sample_free_flights`` (delta
tracking) -> ``add_escaped_radiance`` -> ``scatter_at_interactions`` (albedo) ->
``add_direct_light`` (NEE + ratio-tracked shadow rays) -> ``russian_roulette`` ->
``sample_phase_directions`` (HG) } with compaction after every stage that terminates rays.

Radiance is split by the number of scattering vertices: L_e (0), L_d (1), L_i (>= 2); see
:mod:`photon_fields.runtime.wavefront.film`.
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit, prange

from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.direct_light import direct_light_batch, mis_weight_phase
from photon_fields.runtime.transport.environment_map import EnvMap
from photon_fields.runtime.transport.medium import Medium, albedo_at, intersect_box
from photon_fields.runtime.transport.phase import sample_hg
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import delta_track_batch
from photon_fields.runtime.wavefront.batches import (
    DEFAULT_BATCH,
    Environment,
    RenderResult,
    StageTimer,
    finish,
    primary_ray_batches,
    scene_environment,
)
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.rays import RayBatch

# --- stages -----------------------------------------------------------------------------------------


def sample_free_flights(m: Medium, rays: RayBatch) -> np.ndarray:
    """Distance to the next real collision along each ray (inf: escapes the box). Delta tracking."""
    return delta_track_batch(m, rays.o, rays.d, np.zeros(len(rays)), rays.tmax, rays.rng)


def add_escaped_radiance(film: Film, rays: RayBatch, escaped: np.ndarray, env: Environment | None,
                         nee: bool) -> None:
    """Escaping rays pick up the environment along their direction, MIS-weighted against NEE for rays that
    scattered (the NEE pdf of the escape direction: 1 / (4 pi) for the constant environment, the map's p_w)."""
    if env is None or not np.any(escaped):
        return
    pdf = rays.pdf[escaped]
    depth = rays.depth[escaped]
    radiance, pdf_light = env.radiance_and_pdf(rays.d[:, escaped])
    # Camera rays (depth 0) carry pdf = inf, so their weight is 1 as it must be: NEE cannot reach them.
    w = _mis_weights(pdf, pdf_light) if nee else np.ones(pdf.shape[0])
    film.splat_by_depth(depth, rays.pixel[escaped], rays.beta[:, escaped] * radiance * w)


@njit(cache=True)
def _mis_weights(pdf: np.ndarray, pdf_light: np.ndarray) -> np.ndarray:
    w = np.empty(pdf.shape[0])
    for i in range(pdf.shape[0]):
        w[i] = mis_weight_phase(pdf[i], pdf_light[i])
    return w


@njit(cache=True, parallel=True)
def _scatter(m: Medium, o: np.ndarray, d: np.ndarray, t: np.ndarray, beta: np.ndarray, depth: np.ndarray) -> None:
    for i in prange(o.shape[1]):
        o[0, i] += t[i] * d[0, i]
        o[1, i] += t[i] * d[1, i]
        o[2, i] += t[i] * d[2, i]
        a0, a1, a2 = albedo_at(m, o[0, i], o[1, i], o[2, i])
        beta[0, i] *= a0
        beta[1, i] *= a1
        beta[2, i] *= a2
        depth[i] += 1


def scatter_at_interactions(m: Medium, rays: RayBatch, t: np.ndarray) -> None:
    """Move rays to their collision and weight by the albedo (delta tracking's estimator: a real
    collision scatters with probability sigma_s / sigma_t, folded into the throughput)."""
    _scatter(m, rays.o, rays.d, t, rays.beta, rays.depth)


def add_direct_light(film: Film, m: Medium, lights: tuple[np.ndarray, np.ndarray, np.ndarray, EnvMap], g: float,
                     rays: RayBatch, last_vertex: bool = False) -> np.ndarray:
    """NEE at every vertex; contributions go to L_d or L_i by vertex count. Returns the radiance (3, n).
    At a path's last vertex (``last_vertex``) no phase-sampled escape follows, so the environment's NEE
    sample takes the full weight instead of its MIS share. ``lights``: the packed lights and the environment map."""
    kind, vec, rgb, env = lights
    li = direct_light_batch(m, kind, vec, rgb, env, g, rays.o, rays.d, rays.rng, not last_vertex)
    film.splat_by_depth(rays.depth, rays.pixel, rays.beta * li)
    return li


@njit(cache=True, parallel=True)
def _roulette(beta: np.ndarray, depth: np.ndarray, states: np.ndarray, rr_depth: int) -> np.ndarray:
    n = beta.shape[1]
    alive = np.empty(n, dtype=np.bool_)
    for i in prange(n):
        q = max(beta[0, i], beta[1, i], beta[2, i])
        if q <= 0.0:
            alive[i] = False
            continue
        alive[i] = True
        if depth[i] >= rr_depth:
            q = min(q, 0.95)
            states[i], u = next_float(states[i])
            if u >= q:
                alive[i] = False
            else:
                beta[0, i] /= q
                beta[1, i] /= q
                beta[2, i] /= q
    return alive


def russian_roulette(rays: RayBatch, rr_depth: int) -> np.ndarray:
    """Mask of surviving rays (throughputs of survivors are divided by their survival probability)."""
    return _roulette(rays.beta, rays.depth, rays.rng, rr_depth)


@njit(cache=True, parallel=True)
def _phase_sample(m: Medium, g: float, o: np.ndarray, d: np.ndarray, pdf: np.ndarray, tmax: np.ndarray,
                  states: np.ndarray) -> None:
    for i in prange(o.shape[1]):
        s, u1 = next_float(states[i])
        s, u2 = next_float(s)
        states[i] = s
        d[0, i], d[1, i], d[2, i], pdf[i] = sample_hg(g, d[0, i], d[1, i], d[2, i], u1, u2)
        _, t1 = intersect_box(m, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i])
        tmax[i] = max(t1, 0.0)


def sample_phase_directions(m: Medium, g: float, rays: RayBatch) -> None:
    """Continue every path in an HG-sampled direction; the phase/pdf ratio is 1 (perfect importance
    sampling), so the throughput is unchanged. Records the pdf for MIS and the new box exit."""
    _phase_sample(m, g, rays.o, rays.d, rays.pdf, rays.tmax, rays.rng)


# --- driver -----------------------------------------------------------------------------------------


def trace_paths(film: Film, scene: Scene, m: Medium, rays: RayBatch, *, max_depth: int, nee: bool,
                rr_depth: int, timer: StageTimer) -> None:
    """Run the bounce loop of one batch of clipped camera rays to completion. All rays of a batch
    advance in lockstep, so after bounce ``b`` every live ray has ``b + 1`` scattering vertices. Flight
    ``max_depth`` (0-based) only happens without NEE and only counts escapes (see the module docstring)."""
    lights = (*scene.packed_lights(), scene.packed_environment_map())
    env = scene_environment(scene)
    for bounce in range(max_depth + 1):
        if len(rays) == 0:
            return
        with timer("sample_free_flights"):
            t = sample_free_flights(m, rays)
        escaped = np.isinf(t)
        with timer("add_escaped_radiance"):
            add_escaped_radiance(film, rays, escaped, env, nee)
        if bounce == max_depth:  # the escape-only flight after the last vertex (pure phase sampling)
            return
        with timer("compact"):
            rays, t = rays.compact(~escaped), t[~escaped]
        with timer("scatter_at_interactions"):
            scatter_at_interactions(m, rays, t)
        last_vertex = bounce + 1 == max_depth
        if nee:
            with timer("add_direct_light"):
                add_direct_light(film, m, lights, scene.g, rays, last_vertex)
            if last_vertex:
                return
        with timer("russian_roulette"):
            alive = russian_roulette(rays, rr_depth)
        with timer("compact"):
            rays = rays.compact(alive)
        with timer("sample_phase_directions"):
            sample_phase_directions(m, scene.g, rays)


def render_path_traced(scene: Scene, *, spp: int = 16, max_depth: int = 16, nee: bool = True, rr_depth: int = 3,
                       seed: int = 0, batch_size: int = DEFAULT_BATCH, progress: bool = True) -> RenderResult:
    """Path-trace ``scene`` with ``spp`` samples per pixel (parameters in the module docstring): layers L, L_e,
    L_d (one scattering vertex) and L_i (two or more), per-stage timings, and how many paths entered the
    volume."""
    m = scene.medium()
    film = Film(scene.camera.width, scene.camera.height)
    timer = StageTimer()
    t_start = time.perf_counter()
    n_paths = 0
    for rays in primary_ray_batches(scene, film, timer, spp=spp, seed=seed, batch_size=batch_size,
                                    progress=progress, desc="path tracing"):
        n_paths += len(rays)
        trace_paths(film, scene, m, rays, max_depth=max_depth, nee=nee, rr_depth=rr_depth, timer=timer)
    return finish(film, timer, spp, t_start, {"paths_in_volume": float(n_paths)})
