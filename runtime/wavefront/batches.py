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
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.emitters import environment_index
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.rays import RayBatch, clip_rays_to_volume, generate_camera_rays

DEFAULT_BATCH = 1 << 18


@dataclass
class RenderResult:
    layers: dict[str, np.ndarray]  # name -> (H, W, 3) float32
    timings_ms: dict[str, float] = field(default_factory=dict)
    stats: dict[str, float] = field(default_factory=dict)


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


def environment_radiance(scene: Scene) -> np.ndarray | None:
    """RGB radiance of the (merged) environment light, or None."""
    kind, _, rgb = scene.packed_lights()
    i = environment_index(kind)
    return rgb[i] if i >= 0 else None


def primary_ray_batches(scene: Scene, film: Film, timer: StageTimer, *, spp: int, seed: int, batch_size: int,
                        progress: bool, desc: str, first_sample: int = 0) -> Iterator[RayBatch]:
    """Yield compacted batches of camera rays clipped to the volume box. Rays that miss the box add
    the environment (if any) to L_e and are dropped at once.

    Work item ``w = sample * pixels + pixel`` owns random stream ``w``; this call covers samples
    ``first_sample .. first_sample + spp - 1``, so frames rendered with consecutive ``first_sample``
    add up to exactly the image of one render with all their samples (progressive accumulation)."""
    cam = scene.camera
    m = scene.medium()
    env = environment_radiance(scene)
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
                film.splat("L_e", rays.pixel[~hit], np.broadcast_to(env[:, None], (3, int((~hit).sum()))))
            with timer("compact"):
                rays = rays.compact(hit)
            yield rays
            bar.update(len(work))


def finish(film: Film, timer: StageTimer, spp: int, t_start: float, stats: dict[str, float]) -> RenderResult:
    """Close a render of ``spp`` new samples per pixel into ``film`` (which may hold earlier frames)."""
    film.samples += spp
    wall = time.perf_counter() - t_start
    timings = dict(timer.ms)
    timings["total"] = wall * 1e3
    n = film.width * film.height * spp
    return RenderResult(film.layers(), timings, {"samples": float(n), "samples_per_s": n / max(wall, 1e-9), **stats})
