"""Fly-around sequences: one renderer, N views orbiting the scene camera's target, numbered files and timings.

The paper's 2000-frame timing protocol in miniature, for any renderer: ``render_frame(scene) -> RenderResult``
renders one view, and :func:`render_orbit` moves the camera (:func:`photon_fields.runtime.scene.camera.orbit_camera`),
writes each frame as an EXR + PNG and keeps the first frame's exposure for all of them, so the sequence does
not flicker.

With a ``denoiser`` (:class:`photon_fields.runtime.denoise.wrls.WRLSDenoiser`, the temporal WRLS denoiser) each
frame's L goes through it, with the frame's camera and the scene's depth map
(:class:`photon_fields.runtime.denoise.depth.DepthEstimator`): the EXR's ``L`` and the PNG are then the denoised
frame, the EXR also holds the renderer's ``L`` as ``L_noisy`` (beside its L_d / L_i / L_e), and a PNG of it is
written as ``name_0000_noisy.png``. The timings file adds the denoiser's and the depth map's milliseconds.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.atomic import atomic_write_text
from photon_fields.runtime.progress import progress_bar
from photon_fields.runtime.scene.camera import orbit_camera
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.wavefront.batches import RenderResult

if TYPE_CHECKING:
    from photon_fields.runtime.denoise.wrls import WRLSDenoiser


def orbit_frame_paths(out: Path, frames: int) -> list[Path]:
    """``dir/name.exr`` -> ``dir/name_0000.exr`` ... for ``frames`` frames."""
    width = max(4, len(str(frames - 1)))
    return [out.with_name(f"{out.stem}_{i:0{width}d}{out.suffix}") for i in range(frames)]


def orbit_noisy_png_path(frame: Path) -> Path:
    """``dir/name_0000.exr`` -> ``dir/name_0000_noisy.png``, the undenoised frame's preview (with a denoiser)."""
    return frame.with_name(f"{frame.stem}_noisy.png")


def orbit_timings_path(out: Path) -> Path:
    """``dir/name.exr`` -> ``dir/name_timings.json``, the orbit's timings and exposure."""
    return out.with_name(f"{out.stem}_timings.json")


def render_orbit(scene: Scene, render_frame: Callable[[Scene], RenderResult], out: Path, *, frames: int,
                 spp: int = 1, degrees: float = 360.0, exposure: float | None = None,
                 progress: bool = True, denoiser: WRLSDenoiser | None = None,
                 record: dict[str, Any] | None = None) -> dict[str, Any]:
    """Render ``frames`` views orbiting the scene camera's target by ``degrees`` in all with ``render_frame``,
    each to a numbered EXR + PNG beside ``out`` (:func:`orbit_frame_paths`); ``exposure`` in stops, or None
    for the first frame's automatic exposure, kept for all frames. ``spp`` is recorded, not used: it is
    whatever ``render_frame`` renders. Returns and writes (:func:`orbit_timings_path`) per-frame wall times
    and their mean / median / 95th percentile, and per-stage milliseconds per frame.

    ``denoiser``: a :class:`photon_fields.runtime.denoise.wrls.WRLSDenoiser` of the scene camera's size, reset
    first, through which every frame's L goes (module docstring); ``frame_s`` stays the render's time, the
    denoiser's and the depth map's are ``denoise_ms`` and ``depth_ms`` per frame. ``render_frame`` should then
    draw fresh samples for every frame (a different seed per call): with one seed for all frames the noise of
    consecutive views is strongly correlated, and averaging it over time removes little. ``record``: more
    entries for the timings file (e.g. the method and seeds)."""

    from photon_fields.runtime.io.images import auto_exposure_stops, tonemap_srgb, write_image_set, write_png

    paths = orbit_frame_paths(out, frames)
    walls: list[float] = []
    stages: dict[str, float] = {}
    denoise_ms: list[float] = []
    depth_ms: list[float] = []
    depth_of = None
    if denoiser is not None:
        from photon_fields.runtime.denoise.depth import DepthEstimator

        if (denoiser.width, denoiser.height) != (scene.camera.width, scene.camera.height):
            raise InputError("orbit denoiser", f"is for {denoiser.width}x{denoiser.height} frames, the orbit renders "
                             f"{scene.camera.width}x{scene.camera.height}")
        denoiser.reset()
        depth_of = denoiser.depth_estimator or DepthEstimator(scene.medium())
    for i in progress_bar(range(frames), desc="orbit", unit="frame", enabled=progress):
        cam = orbit_camera(scene.camera, degrees * i / frames)
        t0 = time.perf_counter()
        result = render_frame(scene.with_overrides(camera=cam))
        walls.append(time.perf_counter() - t0)
        for k, v in result.timings_ms.items():
            stages[k] = stages.get(k, 0.0) + v
        layers = result.layers
        if denoiser is not None and depth_of is not None:
            t0 = time.perf_counter()
            depth = depth_of.depth(cam)
            t1 = time.perf_counter()
            clean = denoiser.denoise(layers["L"], camera=cam, depth=depth)
            depth_ms.append((t1 - t0) * 1e3)
            denoise_ms.append((time.perf_counter() - t1) * 1e3)
            layers = {**layers, "L": clean, "L_noisy": layers["L"]}
        if exposure is None:
            exposure = auto_exposure_stops(layers["L"])
        meta = {"photon_fields.frame": str(i)}
        if denoiser is not None:
            meta["photon_fields.denoiser"] = "wrls"
        write_image_set(paths[i], layers, metadata=meta, exposure=exposure)
        if denoiser is not None:
            write_png(orbit_noisy_png_path(paths[i]), tonemap_srgb(layers["L_noisy"], exposure))
    w = np.asarray(walls)
    summary = {**(record or {}), "frames": frames, "spp": spp, "size": [scene.camera.width, scene.camera.height],
               "degrees": degrees,
               "exposure_stops": exposure, "frame_s": walls, "mean_s": float(w.mean()), "median_s": float(np.median(w)),
               "p95_s": float(np.percentile(w, 95)), "fps": float(1.0 / w.mean()),
               "stage_ms_per_frame": {k: v / frames for k, v in stages.items()},
               "files": [str(p) for p in paths]}
    if denoiser is not None:
        summary["denoiser"] = {"name": "wrls", "params": asdict(denoiser.params), "denoise_ms": denoise_ms,
                               "depth_ms": depth_ms, "mean_denoise_ms": float(np.mean(denoise_ms)),
                               "mean_depth_ms": float(np.mean(depth_ms))}
    timing_path = orbit_timings_path(out)
    atomic_write_text(timing_path, json.dumps(summary, indent=2) + "\n")
    summary["timings_file"] = str(timing_path)
    return summary
