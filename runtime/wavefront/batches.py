"""Wavefront plumbing shared by every renderer: the result type, per-stage timers and the primary-ray
stage (generate camera rays, clip them to the volume box, let misses see the environment, compact).

Work items are numbered ``w = sample * n_pixels + pixel`` and processed in batches of ``batch_size``,
which bounds memory whatever the resolution and spp (a 1280x720 16 spp frame is 56 batches of 2^18).
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from photon_fields.runtime.progress import progress_bar
from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.scene.lights import ENVIRONMENT_MAP
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.emitters import ENVIRONMENT_PDF, environment_index
from photon_fields.runtime.transport.environment_map import EnvMap, env_map_eval_batch
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.rays import RayBatch, camera_directions, clip_rays_to_volume, generate_camera_rays

DEFAULT_BATCH = 1 << 18
#: Work items per batch of a render that may be cancelled between batches (the viewer's resting frames): a quarter of
#: a 512x512 frame, so a camera move waits for at most that much of a frame that is thrown away; the same image
#: bit for bit, ~3 % slower than whole-frame batches (bench/README.md, "A resting frame cancelled by a move").
CANCELLABLE_BATCH = 1 << 16


class RenderCancelledError(Exception):
    """A render's ``cancel()`` said stop (checked before each batch): its samples are incomplete, discard them."""


@dataclass
class RenderResult:
    layers: dict[str, np.ndarray]  # name -> (H, W, 3) float32
    timings_ms: dict[str, float] = field(default_factory=dict)
    stats: dict[str, float | str] = field(default_factory=dict)  # numbers, and what a renderer chose (names)


class StageTimer:
    """Accumulates wall time per named stage (reported in ms): ``with timer("stage"): ...``."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        t = time.perf_counter()
        try:
            yield
        finally:
            self.ms[name] += (time.perf_counter() - t) * 1e3


@dataclass(frozen=True)
class Environment:
    """What rays that leave the volume see: the scene's (merged) environment, constant (``env_map`` None: radiance
    ``rgb`` from every direction) or a map (``env_map``: radiance by direction). Every renderer's escape handling
    goes through :meth:`radiance` (and the path tracer's MIS through :meth:`radiance_and_pdf`), so a new
    environment kind changes this class, not the renderers."""

    rgb: np.ndarray  # (3,): the constant radiance (ones for a map: its radiance is in the table)
    env_map: EnvMap | None = None

    def radiance_and_pdf(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Radiance (3, n) arriving along the unit directions ``d`` (3, n) (the rays' travel directions) and the
        solid-angle pdf (n,) with which NEE samples those directions (the MIS weight of an escape needs it)."""
        if self.env_map is None:
            n = d.shape[1]
            return np.broadcast_to(self.rgb[:, None], (3, n)), np.full(n, ENVIRONMENT_PDF)
        rgb, pdf = env_map_eval_batch(self.env_map, np.ascontiguousarray(d, dtype=np.float64))
        return rgb * self.rgb[:, None], pdf

    def radiance(self, d: np.ndarray) -> np.ndarray:
        """Radiance (3, n) arriving along the unit directions ``d`` (3, n)."""
        return self.radiance_and_pdf(d)[0]

    def behind_camera_rays(self, camera: Camera, work: np.ndarray, seed: int) -> np.ndarray:
        """Radiance (3, n) behind the camera rays of work items ``work`` under ``seed`` (their directions
        regenerated, :func:`photon_fields.runtime.wavefront.rays.camera_directions`, for a map only)."""
        if self.env_map is None:
            return np.broadcast_to(self.rgb[:, None], (3, work.shape[0]))
        return self.radiance(camera_directions(camera, work, seed))


def scene_environment(scene: Scene) -> Environment | None:
    """The scene's (merged) environment light, or None."""
    kind, _, rgb = scene.packed_lights()
    i = environment_index(kind)
    if i < 0:
        return None
    return Environment(rgb[i], scene.packed_environment_map() if kind[i] == ENVIRONMENT_MAP else None)


def primary_ray_batches(scene: Scene, film: Film, timer: StageTimer, *, spp: int, seed: int, batch_size: int,
                        progress: bool, desc: str, first_sample: int = 0) -> Iterator[RayBatch]:
    """Yield compacted batches of camera rays clipped to the volume box. Rays that miss the box add
    the environment (if any) to L_e and are dropped at once.

    Work item ``w = sample * pixels + pixel`` owns random stream ``w``; this call covers samples
    ``first_sample .. first_sample + spp - 1``, so frames rendered with consecutive ``first_sample``
    add up to exactly the image of one render with all their samples (progressive accumulation)."""
    cam = scene.camera
    m = scene.medium()
    env = scene_environment(scene)
    n_pixels = cam.width * cam.height
    first, total = first_sample * n_pixels, n_pixels * spp
    with progress_bar(total=total, desc=desc, unit="spl", unit_scale=True, enabled=progress) as bar:
        for start in range(first, first + total, batch_size):
            work = np.arange(start, min(start + batch_size, first + total), dtype=np.int64)
            with timer("generate_camera_rays"):
                rays = generate_camera_rays(cam, work, seed)
            with timer("clip_rays_to_volume"):
                hit = clip_rays_to_volume(m, rays)
            if env is not None and not np.all(hit):
                film.splat("L_e", rays.pixel[~hit], env.radiance(rays.d[:, ~hit]))
            with timer("compact"):
                rays = rays.compact(hit)
            yield rays
            bar.update(len(work))


def work_batches(first: int, total: int, batch: int, split: int | None = None) -> Iterator[tuple[int, int]]:
    """``(start, count)`` of the batches of work items ``first .. first + total``, at most ``batch`` each, none
    straddling work item ``split`` (where the final gather starts), so each batch is gathered or not as a whole."""
    end = first + total
    bounds = [first, end] if split is None or not first < split < end else [first, split, end]
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        for start in range(lo, hi, batch):
            yield start, min(batch, hi - start)


def finish(film: Film, timer: StageTimer, spp: int, t_start: float, stats: dict[str, float]) -> RenderResult:
    """Close a render of ``spp`` new samples per pixel into ``film`` (which may hold earlier frames)."""
    film.samples += spp
    wall = time.perf_counter() - t_start
    timings = dict(timer.ms)
    timings["total"] = wall * 1e3
    n = film.width * film.height * spp
    return RenderResult(film.layers(), timings, {"samples": float(n), "samples_per_s": n / max(wall, 1e-9), **stats})
