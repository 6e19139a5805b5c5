"""Rendering from first interactions with a pluggable indirect-light estimate (paper Alg. 2, Sec. 3.6).

This is the structure of the neural renderer; the photon-map renderer is the same with the photon-map
estimate (Eq. 5) in place of the network, which is how the field's output is checked against its
ground truth with identical samples.

Stages over structure-of-arrays batches of work items (pixel, sample):

1. ``sample_first_interactions`` (camera rays, clipping and tracking fused into one numba pass, see
   :func:`sample_first_interactions`): one jittered camera ray per work item, clipped to the volume box and
   tracked to its first interaction by the camera estimator (below), with the albedo there; rays that miss
   the box or escape add the environment to L_e;
2. ``compact``: the interacting items are packed densely, no holes reach the estimators;
3. ``estimate_indirect``: the estimator's in-scattered indirect radiance Q(x, d, g) at every sample;
4. ``estimate_direct``: next-event estimation with ratio-tracked shadow rays, to one light per sample drawn by its
   unshadowed contribution ("one", the default) or to every light ("all"; :data:`LIGHT_SAMPLINGS`);
5. ``compose``: L_d = W a(x) * NEE, L_i = W a(x) * Q, accumulated per pixel and divided by spp.

The estimator we implement (and why it matches the path tracer's split). With delta tracking, the
first real collision x is sampled with pdf sigma_t T, and the path tracer weights everything scattered
there by the albedo a(x) = sigma_s / sigma_t. The light a path tracer gathers at x splits into paths
whose only scattering vertex is x (L_d) and paths with further vertices (L_i). Here

    L_d(x) = a(x) * sum_lights NEE(x)            (every light by NEE, weight 1; with "one", a light drawn
                                                 with probability p_k and divided by it: the same sum in
                                                 expectation)
    L_i(x) = a(x) * Q(x, d, g),   Q = integral p_g(d, w) L_scattered(x, w) dw

where L_scattered is radiance arriving at x that has scattered at least once: exactly what photons
stored from their second collision carry. The paper writes the composition as
``w_d L_d + w_i sigma_s L_i`` with MIS weights: with our disjoint split both weights are 1 (each path
class has a single estimator; MIS is only needed where two strategies estimate the same paths, as NEE
and phase sampling do for the environment inside the path tracer), and sigma_s becomes the albedo
because the delta-tracking pdf supplies the 1 / sigma_t. Each sample is a separate camera ray with its
own sub-pixel jitter (Alg. 2 reuses identical ray parameters; jittering antialiases at no cost).
Camera rays use the same random streams as the path tracer, so with the same seed and the "delta" camera
estimator the first interactions, and the NEE estimates for delta lights, are identical to the path tracer's.

The camera estimators (:data:`CAMERA_ESTIMATORS`). "delta" samples x as above, with weight W = 1: a ray
through a thin medium interacts with probability 1 - T(t_max), so a pixel is a hit-or-miss sample. "forced"
(the default) walks the whole ray with ratio tracking and resamples one of its tentative collisions
(:func:`photon_fields.runtime.transport.tracking.resampled_collision`): x is then distributed as before,
restricted to the ray (pdf sigma_t T / (1 - T(t_max)) in expectation), and W, the walk's unbiased estimate of
1 - T(t_max), weights it, so every ray that crosses the medium contributes; the environment behind the
volume is weighted by the walk's transmittance estimate instead of being seen or not. Both estimate the
same image (tests/runtime/wavefront/test_camera_estimators.py); docs/rendering.md has the derivation and
what each costs. "marched" (:mod:`photon_fields.runtime.wavefront.marched_camera`) replaces stages 1-2 by its own
walk, which also sums the ray marcher's cached single scattering over strata of the ray; its L_d adds that sum to
the correction W a(x) (NEE - cached)(x) at the picked x.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numba import njit, prange

from photon_fields.runtime.errors import check_choice
from photon_fields.runtime.progress import progress_bar
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.direct_light import LIGHT_SAMPLINGS, direct_light_batch
from photon_fields.runtime.transport.light_volume import LightVolume
from photon_fields.runtime.transport.medium import Medium, albedo_at, borrowed_medium
from photon_fields.runtime.transport.tracking import camera_collision, task_stride
from photon_fields.runtime.wavefront.batches import (
    DEFAULT_BATCH,
    Environment,
    RenderCancelledError,
    RenderResult,
    StageTimer,
    finish,
    scene_environment,
    work_batches,
)
from photon_fields.runtime.wavefront.depth_bounds import depth_bounds_for, ray_interval, unbounded
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.final_gather import gather_indirect
from photon_fields.runtime.wavefront.marched_camera import (
    compact_marched,
    correction_direct,
    correction_nee,
    march_camera_rays,
)
from photon_fields.runtime.wavefront.rays import camera_ray, clip_to_box


class IndirectEstimator(Protocol):
    """Q(x, d, g): in-scattered radiance that has scattered at least once, before the albedo at x.
    ``x`` (3, n) world positions, ``d`` (3, n) unit camera-ray travel directions; returns (3, n)."""

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray: ...


#: The camera estimators: how a camera ray's first interaction is sampled and weighted (docs/rendering.md).
#: "delta": delta tracking to the first real collision, weight 1 (the path tracer's first bounce, bit for bit);
#: "forced": one collision resampled from the ratio-tracking walk along the whole ray, weighted by the walk's
#: estimate W of the collision probability (runtime.transport.tracking), so that a ray through thin media
#: interacts with weight W instead of rarely with weight 1; "marched": the light volume's single scattering summed
#: over strata of the whole ray, corrected by NEE at three of them, where the field is asked too
#: (runtime.wavefront.marched_camera; needs the scene's light volume). The renderers (render_neural,
#: render_photon_mapped, and so the command line, the Python API and the viewer) also take "auto", their default
#: (runtime.wavefront.camera_choice: forced or marched, whichever has less noise per unit of work on the scene);
#: this module's functions take the three above, forced by default.
CAMERA_ESTIMATORS = ("delta", "forced", "marched")
DEFAULT_CAMERA_ESTIMATOR = "forced"
#: NEE at the first interactions (and at a final gather's bounce): "one" light per sample, drawn by its unshadowed
#: contribution, or "all" lights (runtime.transport.direct_light). "one" is the default: on the embedded two-light
#: scenes it halves the NEE stage for a few per cent more noise (docs/rendering.md); with one light both are the same.
DEFAULT_LIGHT_SAMPLING = "one"
#: "forced": a collision of weight W < FORCED_MIN_WEIGHT is kept with probability W / FORCED_MIN_WEIGHT and then
#: weighted FORCED_MIN_WEIGHT (Russian roulette on the weight), which bounds the field and NEE work per frame.
FORCED_MIN_WEIGHT = 0.25

#: Status of a work item after :func:`sample_first_interactions`.
MISSED_BOX, ESCAPED, INTERACTED = 0, 1, 2
#: Work items per parallel task of the fused kernel: the interacting items of a task are packed at its start,
#: then :func:`compact_first_interactions` closes the gaps between tasks (128 tasks for a 512x512 batch).
_BLOCK = 2048


@dataclass
class FirstInteractions:
    """Interacting work items of one batch, structure of arrays (``x``, ``d``, ``albedo`` (3, n): each
    coordinate contiguous). Before :func:`compact_first_interactions` this is the fused kernel's scratch, with
    task k's items at ``k * _BLOCK ..``; afterwards densely packed in work-item order."""

    pixel: np.ndarray  # int64 (n,): flat pixel index
    x: np.ndarray  # float64 (3, n): first real collision
    d: np.ndarray  # float64 (3, n): unit camera-ray travel direction
    albedo: np.ndarray  # float64 (3, n): sigma_s / sigma_t at x
    rng: np.ndarray  # uint64 (n,): random state after the camera jitter and the tracking (NEE goes on)
    weight: np.ndarray  # float64 (n,): the camera estimator's weight of the collision (1 for "delta")

    def __len__(self) -> int:
        return int(self.pixel.shape[0])

    @classmethod
    def empty(cls, n: int) -> FirstInteractions:
        return cls(np.empty(n, np.int64), np.empty((3, n)), np.empty((3, n)), np.empty((3, n)),
                   np.empty(n, np.uint64), np.empty(n))


@njit(cache=True)
def _first_interactions_block(m: Medium, eye: np.ndarray, origin: np.ndarray, du: np.ndarray, dv: np.ndarray,
                              width: int, n_pixels: int, start: int, count: int, s0: np.uint64, block: int, b: int,
                              forced: bool, w_min: float, near: np.ndarray, far: np.ndarray, tile: int,
                              pixel: np.ndarray, x: np.ndarray, d: np.ndarray, albedo: np.ndarray, rng: np.ndarray,
                              weight: np.ndarray, status: np.ndarray, transmit: np.ndarray,
                              counts: np.ndarray) -> None:
    """Task ``b`` of :func:`_first_interactions`, serially (``TASK_ITEMS`` in tracking.py says why the parallel
    kernel only calls this)."""
    m = borrowed_medium(m)  # no reference counting in the loop (runtime/borrowed.py)
    k = b * block
    inside = 0
    for i in range(b * block, min(count, (b + 1) * block)):
        dx, dy, dz, p, s = camera_ray(origin, du, dv, width, n_pixels, start + i, s0)
        hit, ox, oy, oz, tmax = clip_to_box(m, eye[0], eye[1], eye[2], dx, dy, dz)
        transmit[i] = 1.0
        if not hit:
            status[i] = MISSED_BOX
            continue
        inside += 1
        # The walk only where the tile's rays can meet an occupied macrocell (depth_bounds.py): the same samples.
        tmin, tmax = ray_interval(near, far, tile, width, p, eye, ox, oy, oz, dx, dy, dz, tmax)
        if not tmin < tmax:
            status[i] = ESCAPED
            continue
        t, w, transmit[i], s = camera_collision(m, ox, oy, oz, dx, dy, dz, tmin, tmax, s, forced, w_min)
        if not math.isfinite(t):
            status[i] = ESCAPED
            continue
        status[i] = INTERACTED
        ox += t * dx
        oy += t * dy
        oz += t * dz
        pixel[k] = p
        x[0, k], x[1, k], x[2, k] = ox, oy, oz
        d[0, k], d[1, k], d[2, k] = dx, dy, dz
        albedo[0, k], albedo[1, k], albedo[2, k] = albedo_at(m, ox, oy, oz)
        rng[k] = s
        weight[k] = w
        k += 1
    counts[b, 0] = k - b * block
    counts[b, 1] = inside


@njit(cache=True, parallel=True)
def _first_interactions(m: Medium, eye: np.ndarray, origin: np.ndarray, du: np.ndarray, dv: np.ndarray, width: int,
                        n_pixels: int, start: int, count: int, seed: int, block: int, forced: bool, w_min: float,
                        near: np.ndarray, far: np.ndarray, tile: int, pixel: np.ndarray, x: np.ndarray, d: np.ndarray,
                        albedo: np.ndarray, rng: np.ndarray, weight: np.ndarray, status: np.ndarray,
                        transmit: np.ndarray) -> np.ndarray:
    """Work items ``start .. start + count - 1``: camera ray, clip, tracking, albedo, in one pass per item.

    ``forced`` False ("delta"): delta tracking, the same inlined arithmetic as ``generate_camera_rays`` ->
    ``clip_rays_to_volume`` -> ``delta_track_batch`` and the same random draws, so the collisions equal the
    path tracer's bit for bit; weight 1. ``forced`` True: the collision resampled from the ratio-tracking walk
    with weight W (:func:`resampled_collision`), kept with probability min(1, W / w_min) and then weighted
    max(W, w_min); ``transmit`` gets each item's estimate of the transmittance to the box exit (1 for a
    miss). Task k packs its interacting items at ``k * block``; returns per task (interacting items, items
    inside the box)."""
    nblocks = (count + block - 1) // block
    counts = np.zeros((nblocks, 2), np.int64)
    s0 = np.uint64(seed)
    stride = task_stride(nblocks)
    for task in prange(nblocks):
        b = (task * stride) % nblocks
        _first_interactions_block(m, eye, origin, du, dv, width, n_pixels, start, count, s0, block, b, forced, w_min,
                                  near, far, tile, pixel, x, d, albedo, rng, weight, status, transmit, counts)
    return counts


@njit(cache=True, parallel=True)
def _pack(counts: np.ndarray, block: int, src_pixel: np.ndarray, src_x: np.ndarray, src_d: np.ndarray,
          src_albedo: np.ndarray, src_rng: np.ndarray, src_weight: np.ndarray, pixel: np.ndarray, x: np.ndarray,
          d: np.ndarray, albedo: np.ndarray, rng: np.ndarray, weight: np.ndarray) -> None:
    nblocks = counts.shape[0]
    offsets = np.zeros(nblocks, np.int64)
    for b in range(1, nblocks):
        offsets[b] = offsets[b - 1] + counts[b - 1, 0]
    for b in prange(nblocks):
        for j in range(counts[b, 0]):
            i, o = b * block + j, offsets[b] + j
            pixel[o] = src_pixel[i]
            rng[o] = src_rng[i]
            weight[o] = src_weight[i]
            for c in range(3):
                x[c, o] = src_x[c, i]
                d[c, o] = src_d[c, i]
                albedo[c, o] = src_albedo[c, i]


def check_light_sampling(name: str) -> bool:
    """Whether ``name`` samples one light per vertex; refuses names not in :data:`LIGHT_SAMPLINGS` in one line."""
    return check_choice("light sampling", name, LIGHT_SAMPLINGS) == "one"


def check_camera_estimator(name: str) -> bool:
    """Whether ``name`` weights its collisions (forced, marched: not delta tracking's weight 1); refuses names not in
    :data:`CAMERA_ESTIMATORS` in one line."""
    return check_choice("camera estimator", name, CAMERA_ESTIMATORS) != "delta"


def sample_first_interactions(scene: Scene, m: Medium, start: int, count: int, seed: int,
                              scratch: FirstInteractions, status: np.ndarray, transmit: np.ndarray,
                              camera: str = DEFAULT_CAMERA_ESTIMATOR, depth_bounds: bool = True) -> np.ndarray:
    """Stages 1-2 fused: for work items ``start .. start + count - 1`` generate the jittered camera ray, clip it
    to the volume box, sample its first interaction with the ``camera`` estimator (:data:`CAMERA_ESTIMATORS`)
    and look up the albedo there, in one numba pass that writes only the interacting items (into ``scratch``,
    per task; ``status`` (count,) gets each item's MISSED_BOX / ESCAPED / INTERACTED, ``transmit`` (count,)
    its weight for the environment behind the volume). Returns the per-task counts for
    :func:`compact_first_interactions`: (interacting, inside the box) per task.

    Why fused: the separate stages built a RayBatch of every camera ray (8 arrays, most of them unused
    here), clipped it, compacted it, tracked it and compacted again; the rays that miss the box or escape
    (70-90 % on the builtin scenes) only cost their tracking; what is left is the tracking itself, the path
    tracer's first bounce.

    ``depth_bounds``: each ray walks only the part of it where its tile of the image can meet an occupied macrocell
    (:mod:`photon_fields.runtime.wavefront.depth_bounds`, computed once per scene object); the same samples, bit
    for bit, as the walk of the whole ray (False)."""
    forced = check_camera_estimator(camera)
    if camera == "marched":
        raise ValueError("the marched estimator samples its own first interactions (marched_camera.march_camera_rays)")
    cam = scene.camera
    origin, du, dv = cam.image_plane()
    bounds = depth_bounds_for(scene, m) if depth_bounds else unbounded()
    return _first_interactions(m, np.ascontiguousarray(cam.eye, dtype=np.float64), origin, du, dv, cam.width,
                               cam.width * cam.height, int(start), int(count), int(seed), _BLOCK, forced,
                               FORCED_MIN_WEIGHT, bounds.near, bounds.far, bounds.tile, scratch.pixel, scratch.x,
                               scratch.d, scratch.albedo, scratch.rng, scratch.weight, status, transmit)


def compact_first_interactions(scratch: FirstInteractions, counts: np.ndarray) -> FirstInteractions:
    """Stage 3: the interacting items, densely packed in work-item order (no holes reach the estimators)."""
    out = FirstInteractions.empty(int(counts[:, 0].sum()))
    _pack(counts, _BLOCK, scratch.pixel, scratch.x, scratch.d, scratch.albedo, scratch.rng, scratch.weight,
          out.pixel, out.x, out.d, out.albedo, out.rng, out.weight)
    return out


def render_first_interaction(scene: Scene, estimator: IndirectEstimator | None, *, spp: int = 1, seed: int = 0,
                             batch_size: int = DEFAULT_BATCH, progress: bool = True, desc: str = "rendering",
                             direct: bool = True, film: Film | None = None, first_sample: int = 0,
                             camera: str = DEFAULT_CAMERA_ESTIMATOR,
                             final_gather_after: int | None = None,
                             cancel: Callable[[], bool] | None = None,
                             light_sampling: str = DEFAULT_LIGHT_SAMPLING,
                             light_volume: LightVolume | None = None) -> RenderResult:
    """Render ``spp`` samples per pixel (stages in the module docstring) with the ``camera`` estimator and NEE's
    ``light_sampling`` (:data:`LIGHT_SAMPLINGS`). The "marched" estimator reads the scene's ``light_volume`` (the
    ray marcher's, ``runtime.renderers.ray_marcher.camera_light_volume``; filled where its rays need it).

    ``cancel``: asked before each batch; when it returns True the render stops with
    :class:`photon_fields.runtime.wavefront.batches.RenderCancelledError` (the film holds part of the samples).

    ``final_gather_after``: samples from this index on (counting ``first_sample``'s; 0: all, None: none) take one
    real bounce from x before asking the estimator (:mod:`photon_fields.runtime.wavefront.final_gather`): less of
    the estimator's bias, more noise and time per sample. The result's ``stats["final_gather_spp"]`` counts them.

    ``estimator`` None skips stage 4 (L_i = 0) and ``direct`` False stage 5 (L_d = 0): the benchmarks time
    L_d and L_i alone this way. ``film`` accumulates into an existing film (its sample count grows by
    ``spp``) and ``first_sample`` selects the samples' random streams: frames with consecutive
    ``first_sample`` equal one render with all their samples (:mod:`photon_fields.runtime.wavefront.batches`).
    """

    m = scene.medium()
    kind, vec, rgb = scene.packed_lights()
    env_map = scene.packed_environment_map()
    env = scene_environment(scene)
    film = film if film is not None else Film(scene.camera.width, scene.camera.height)
    if (film.width, film.height) != (scene.camera.width, scene.camera.height):
        raise ValueError(f"film is {film.width}x{film.height}, camera {scene.camera.width}x{scene.camera.height}")
    timer = StageTimer()
    t_start = time.perf_counter()
    n_pixels = film.width * film.height
    first, total = first_sample * n_pixels, n_pixels * spp
    batch = min(batch_size, total)
    forced = check_camera_estimator(camera)
    marched = camera == "marched"
    if marched and light_volume is None:
        raise ValueError("the marched camera estimator needs the scene's light volume")
    bounds = depth_bounds_for(scene, m) if marched else None
    one_light = check_light_sampling(light_sampling)
    scratch, status, transmit = FirstInteractions.empty(batch), np.empty(batch, np.uint8), np.empty(batch)
    distinct = batch <= n_pixels  # consecutive work items: no pixel twice in one batch (Film.splat)
    n_rays = n_samples = 0
    gather_from = None if final_gather_after is None or estimator is None else final_gather_after * n_pixels
    with progress_bar(total=total, desc=desc, unit="spl", unit_scale=True, enabled=progress) as bar:
        for start, count in work_batches(first, total, batch, gather_from):
            if cancel is not None and cancel():
                raise RenderCancelledError(f"cancelled before work item {start}")
            cached = None
            if marched:
                with timer("sample_first_interactions"):
                    items = march_camera_rays(scene, m, light_volume, np.arange(start, start + count), seed, bounds,
                                              cancel)
                status[:count], transmit[:count] = items.status, items.transmit
                n_rays += int(np.count_nonzero(items.status != MISSED_BOX))
            else:
                with timer("sample_first_interactions"):
                    counts = sample_first_interactions(scene, m, start, count, seed, scratch, status, transmit,
                                                       camera)
                n_rays += int(counts[:, 1].sum())
            if env is not None:
                splat_environment(film, env, status[:count], transmit[:count], start, n_pixels, distinct, forced,
                                  scene, seed)
            with timer("compact"):
                if marched:  # several picks per ray, in runs of distinct pixels
                    picks, cached = compact_marched(items, start, n_pixels)
                    fi = FirstInteractions(picks.pixel, picks.x, picks.d, picks.albedo, picks.rng, picks.weight)
                    run = picks.rays
                else:
                    fi = compact_first_interactions(scratch, counts)
                    run = len(fi)
            n_samples += run
            bar.update(count)
            if len(fi) == 0:
                continue
            throughput = fi.albedo * fi.weight if forced else fi.albedo
            if estimator is not None:
                with timer("estimate_indirect"):
                    if gather_from is not None and start >= gather_from:
                        q = gather_indirect(m, (kind, vec, rgb, env_map), scene.g, fi.x, fi.d, fi.rng, estimator,
                                            forced, FORCED_MIN_WEIGHT, timer, one_light)
                    else:
                        q = estimator(fi.x, fi.d, scene.g)
                with timer("compose"):
                    splat_runs(film, "L_i", fi.pixel, q, distinct, throughput, run)
            if direct:
                with timer("estimate_direct"):
                    if cached is None:
                        nee = direct_light_batch(m, kind, vec, rgb, env_map, scene.g, fi.x, fi.d, fi.rng, False,
                                                 one_light)
                    else:  # marched_camera's correction: NEE (its own shadow rays) less the cached light at each pick
                        nee = correction_direct(correction_nee(scene, m, (kind, vec, rgb, env_map), fi.x, fi.d, fi.rng,
                                                               one_light), cached)
                with timer("compose"):
                    splat_runs(film, "L_d", fi.pixel, nee, distinct, throughput, run)
                    if cached is not None:
                        film.splat("L_d", fi.pixel[:run], cached.strata, distinct)
    gathered = 0 if gather_from is None else max(0, first + total - max(first, gather_from)) // n_pixels
    return finish(film, timer, spp, t_start, {"rays_in_volume": float(n_rays), "samples_in_volume": float(n_samples),
                                             "compaction_removed": 1.0 - n_samples / max(n_rays, 1),
                                             "final_gather_spp": float(gathered)})


def splat_runs(film: Film, layer: str, pixel: np.ndarray, rgb: np.ndarray, distinct: bool, weight: np.ndarray,
               run: int) -> None:
    """``film.splat`` of contributions that come in runs of ``run`` distinct pixels (the marched estimator's picks,
    pick-major): each run added as distinct when the batch's pixels are."""
    for a in range(0, pixel.shape[0], max(run, 1)):
        film.splat(layer, pixel[a:a + run], rgb[:, a:a + run], distinct, weight=weight[:, a:a + run])


def splat_environment(film: Film, env: Environment, status: np.ndarray, transmit: np.ndarray, start: int,
                      n_pixels: int, distinct: bool, forced: bool, scene: Scene, seed: int) -> None:
    """L_e of one batch: the environment behind every ray that misses the box and, inside it, behind every
    ray that escapes ("delta", in that order, as the separate stages added them) or weighted by each ray's
    transmittance estimate ("forced"), from :meth:`Environment.behind_camera_rays`."""
    def radiance(items: np.ndarray) -> np.ndarray:
        return env.behind_camera_rays(scene.camera, items + start, seed)

    if not forced:
        for which in (MISSED_BOX, ESCAPED):
            items = np.flatnonzero(status == which)
            film.splat("L_e", (items + start) % n_pixels, radiance(items), distinct)
        return
    seen = np.flatnonzero(transmit > 0.0)
    film.splat("L_e", (seen + start) % n_pixels, radiance(seen), distinct,
               weight=np.broadcast_to(transmit[seen][None, :], (3, seen.shape[0])))
