"""Rendering from first interactions with a pluggable indirect-light estimate (paper Alg. 2, Sec. 3.6).

This is the structure of the neural renderer; the photon-map renderer is the same with the photon-map
estimate (Eq. 5) in place of the network, which is how the field's output is checked against its
ground truth with identical samples.

Stages over structure-of-arrays batches (``runtime.wavefront.primary_ray_batches`` supplies the first):

1. ``generate_camera_rays`` + ``clip_rays_to_volume``: rays that miss the box are dropped at once;
2. ``sample_first_interactions``: one delta-tracked first interaction per work item (pixel, sample);
   rays that escape add the environment to L_e;
3. ``compact``: no holes reach the estimators;
4. ``estimate_indirect``: the estimator's in-scattered indirect radiance Q(x, d, g) at every sample;
5. ``estimate_direct``: next-event estimation to every light with ratio-tracked shadow rays;
6. ``compose``: L_d = a(x) * NEE, L_i = a(x) * Q, accumulated per pixel and divided by spp.

The estimator we implement (and why it matches the path tracer's split). With delta tracking, the
first real collision x is sampled with pdf sigma_t T, and the path tracer weights everything scattered
there by the albedo a(x) = sigma_s / sigma_t. The light a path tracer gathers at x splits into paths
whose only scattering vertex is x (L_d) and paths with further vertices (L_i). Here

    L_d(x) = a(x) * sum_lights NEE(x)            (every light by NEE, weight 1)
    L_i(x) = a(x) * Q(x, d, g),   Q = integral p_g(d, w) L_scattered(x, w) dw

where L_scattered is radiance arriving at x that has scattered at least once: exactly what photons
stored from their second collision carry. The paper writes the composition as
``w_d L_d + w_i sigma_s L_i`` with MIS weights: with our disjoint split both weights are 1 (each path
class has a single estimator; MIS is only needed where two strategies estimate the same paths, as NEE
and phase sampling do for the environment inside the path tracer), and sigma_s becomes the albedo
because the delta-tracking pdf supplies the 1 / sigma_t. Each sample is a separate camera ray with its
own sub-pixel jitter (Alg. 2 reuses identical ray parameters; jittering antialiases at no cost).
Camera rays use the same random streams as the path tracer, so with the same seed the first
interactions, and the NEE estimates for delta lights, are identical to the path tracer's.
"""

from __future__ import annotations

import time
from typing import Protocol

import numpy as np
from numba import njit, prange

from runtime.direct_light import direct_light_batch
from runtime.film import Film
from runtime.medium import Medium, albedo_at
from runtime.rays import RayBatch
from runtime.scene import Scene
from runtime.tracking import delta_track_batch
from runtime.wavefront import DEFAULT_BATCH, RenderResult, StageTimer, environment_radiance, finish, primary_ray_batches


class IndirectEstimator(Protocol):
    """Q(x, d, g): in-scattered radiance that has scattered at least once, before the albedo at x.
    ``x`` (3, n) world positions, ``d`` (3, n) unit camera-ray travel directions; returns (3, n)."""

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray: ...


@njit(cache=True, parallel=True)
def _move_and_albedo(m: Medium, o: np.ndarray, d: np.ndarray, t: np.ndarray) -> np.ndarray:
    n = o.shape[1]
    albedo = np.empty((3, n))
    for i in prange(n):
        o[0, i] += t[i] * d[0, i]
        o[1, i] += t[i] * d[1, i]
        o[2, i] += t[i] * d[2, i]
        albedo[0, i], albedo[1, i], albedo[2, i] = albedo_at(m, o[0, i], o[1, i], o[2, i])
    return albedo


def sample_first_interactions(m: Medium, rays: RayBatch) -> tuple[np.ndarray, np.ndarray]:
    """Delta-track every ray; move the ones that interact to their collision (in place).
    Returns (mask of interacting rays, albedo (3, n) at the collisions of all rays; undefined elsewhere)."""
    t = delta_track_batch(m, rays.o, rays.d, np.zeros(len(rays)), rays.tmax, rays.rng)
    hit = np.isfinite(t)
    albedo = _move_and_albedo(m, rays.o, rays.d, np.where(hit, t, 0.0))
    return hit, albedo


def render_first_interaction(scene: Scene, estimator: IndirectEstimator | None, *, spp: int = 1, seed: int = 0,
                             batch_size: int = DEFAULT_BATCH, progress: bool = True, desc: str = "rendering",
                             direct: bool = True, film: Film | None = None, first_sample: int = 0) -> RenderResult:
    """Render ``spp`` samples per pixel (stages in the module docstring).

    ``estimator`` None skips stage 4 (L_i = 0) and ``direct`` False stage 5 (L_d = 0): the benchmarks time
    L_d and L_i alone this way. ``film`` accumulates into an existing film (its sample count grows by
    ``spp``) and ``first_sample`` selects the samples' random streams: frames with consecutive
    ``first_sample`` equal one render with all their samples (:mod:`runtime.wavefront`).
    """
    m = scene.medium()
    kind, vec, rgb = scene.packed_lights()
    env = environment_radiance(scene)
    film = film if film is not None else Film(scene.camera.width, scene.camera.height)
    if (film.width, film.height) != (scene.camera.width, scene.camera.height):
        raise ValueError(f"film is {film.width}x{film.height}, camera {scene.camera.width}x{scene.camera.height}")
    timer = StageTimer()
    t_start = time.perf_counter()
    n_rays = n_samples = 0
    for rays in primary_ray_batches(scene, film, timer, spp=spp, seed=seed, batch_size=batch_size,
                                    progress=progress, desc=desc, first_sample=first_sample):
        n_rays += len(rays)
        with timer("sample_first_interactions"):
            hit, albedo = sample_first_interactions(m, rays)
        if env is not None and not np.all(hit):
            film.splat("L_e", rays.pixel[~hit], np.broadcast_to(env[:, None], (3, int((~hit).sum()))))
        with timer("compact"):
            rays, albedo = rays.compact(hit), albedo[:, hit]
        n_samples += len(rays)
        if len(rays) == 0:
            continue
        if estimator is not None:
            with timer("estimate_indirect"):
                q = estimator(rays.o, rays.d, scene.g)
            with timer("compose"):
                film.splat("L_i", rays.pixel, albedo * q)
        if direct:
            with timer("estimate_direct"):
                nee = direct_light_batch(m, kind, vec, rgb, scene.g, rays.o, rays.d, rays.rng, False)
            with timer("compose"):
                film.splat("L_d", rays.pixel, albedo * nee)
    return finish(film, timer, spp, t_start, {"rays_in_volume": float(n_rays), "samples_in_volume": float(n_samples),
                                             "compaction_removed": 1.0 - n_samples / max(n_rays, 1)})
