"""Fly-around sequences: one renderer, N views orbiting the scene camera's target, numbered files and timings.

The paper's 2000-frame timing protocol in miniature, for any renderer: ``render_frame(scene) -> RenderResult``
renders one view, and :func:`render_orbit` moves the camera (:func:`photon_fields.runtime.scene.camera.orbit_camera`),
writes each frame as an EXR + PNG and keeps the first frame's exposure for all of them, so the sequence does
not flicker.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.io.atomic import atomic_write_text
from photon_fields.runtime.scene.camera import orbit_camera
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.wavefront.batches import RenderResult


def orbit_frame_paths(out: Path, frames: int) -> list[Path]:
    """``dir/name.exr`` -> ``dir/name_0000.exr`` ... for ``frames`` frames."""
    width = max(4, len(str(frames - 1)))
    return [out.with_name(f"{out.stem}_{i:0{width}d}{out.suffix}") for i in range(frames)]


def orbit_timings_path(out: Path) -> Path:
    """``dir/name.exr`` -> ``dir/name_timings.json``, the orbit's timings and exposure."""
    return out.with_name(f"{out.stem}_timings.json")


def render_orbit(scene: Scene, render_frame: Callable[[Scene], RenderResult], out: Path, *, frames: int,
                 spp: int = 1, degrees: float = 360.0, exposure: float | None = None,
                 progress: bool = True) -> dict[str, Any]:
    """Render ``frames`` views orbiting the scene camera's target by ``degrees`` in all with ``render_frame``,
    each to a numbered EXR + PNG beside ``out`` (:func:`orbit_frame_paths`); ``exposure`` in stops, or None
    for the first frame's automatic exposure, kept for all frames. ``spp`` is recorded, not used: it is
    whatever ``render_frame`` renders. Returns and writes (:func:`orbit_timings_path`) per-frame wall times
    and their mean / median / 95th percentile, and per-stage milliseconds per frame."""
    from tqdm import tqdm

    from photon_fields.runtime.io.images import auto_exposure_stops, write_image_set

    paths = orbit_frame_paths(out, frames)
    walls: list[float] = []
    stages: dict[str, float] = {}
    for i in tqdm(range(frames), desc="orbit", unit="frame", disable=not progress, leave=False):
        cam = orbit_camera(scene.camera, degrees * i / frames)
        t0 = time.perf_counter()
        result = render_frame(scene.with_overrides(camera=cam))
        walls.append(time.perf_counter() - t0)
        for k, v in result.timings_ms.items():
            stages[k] = stages.get(k, 0.0) + v
        if exposure is None:
            exposure = auto_exposure_stops(result.layers["L"])
        write_image_set(paths[i], result.layers, metadata={"photon_fields.frame": str(i)}, exposure=exposure)
    w = np.asarray(walls)
    summary = {"frames": frames, "spp": spp, "size": [scene.camera.width, scene.camera.height], "degrees": degrees,
               "exposure_stops": exposure, "frame_s": walls, "mean_s": float(w.mean()), "median_s": float(np.median(w)),
               "p95_s": float(np.percentile(w, 95)), "fps": float(1.0 / w.mean()),
               "stage_ms_per_frame": {k: v / frames for k, v in stages.items()},
               "files": [str(p) for p in paths]}
    timing_path = orbit_timings_path(out)
    atomic_write_text(timing_path, json.dumps(summary, indent=2) + "\n")
    summary["timings_file"] = str(timing_path)
    return summary
