"""The preview in the viewer's rhythm: a resting view, a small camera move, again; with and without the light
volume's margin filled between views (the viewer's idle time, ``runtime/viewer/idle_work.py``).

For each scene (default: head and vortex) at ``--resolution`` voxels per side (default 256) and ``--size`` (256x256):
the first view's ``PREVIEW_FRAMES`` preview frames (what the viewer averages at rest, seeds as the viewer's), then
``--views`` more views, each the camera orbited ``--step`` degrees further, with their frames. Run twice on fresh
scenes (a cold light volume): as the preview renders alone, and with
:func:`photon_fields.runtime.transport.light_volume.fill_margin` after each view's frames (not timed in the frames;
its own time is reported). Per view: the first frame (the one a user waits for after the move), the view's frames
in all; and the sums over the views after the first.

Output: a table and JSON (default ``bench/results/preview_orbit.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.renderers.ray_marcher import (  # noqa: E402
    light_volume_settings,
    render_ray_marched,
    scene_light_volume,
)
from photon_fields.runtime.scene.camera import orbit_camera  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402
from photon_fields.runtime.transport.light_volume import fill_margin  # noqa: E402
from photon_fields.runtime.viewer.field_in_use import PREVIEW_FRAMES  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "preview_orbit.json"


def orbit_run(scene: Scene, views: int, step: float, margins: bool) -> list[dict[str, float]]:
    """Per view: first-frame and all-frames milliseconds, and the margin fill's after it (0 without margins)."""
    kind, vec, _ = scene.packed_lights()
    rows = []
    for k in range(views + 1):
        view = scene.with_overrides(camera=orbit_camera(scene.camera, step * k))
        frames = []
        for n in range(PREVIEW_FRAMES):
            t = time.perf_counter()
            render_ray_marched(view, spp=1, seed=1000 * k + n, progress=False)
            frames.append((time.perf_counter() - t) * 1e3)
        fill_ms = 0.0
        if margins:
            t = time.perf_counter()
            fill_margin(scene.medium(), kind, vec, scene_light_volume(scene, *light_volume_settings(scene)))
            fill_ms = (time.perf_counter() - t) * 1e3
        rows.append({"first_ms": frames[0], "frames_ms": sum(frames), "margin_fill_ms": fill_ms})
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["head", "vortex"], help="builtin scenes")
    ap.add_argument("--resolution", type=int, default=256, help="voxels per side of the builtin volumes")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--views", type=int, default=6, help="views after the first")
    ap.add_argument("--step", type=float, default=5.0, help="degrees the camera orbits between views")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    info = machine_info()
    render_ray_marched(builtin_scene("head", 24), spp=1, progress=False)  # compile or load the kernels first
    results: dict[str, Any] = {}
    print(f"{'scene':8s} {'margins':>8s} {'1st view':>9s} {'next views: 1st frames':>23s} {'all frames':>11s} "
          f"{'margin fills':>13s}  (ms; {PREVIEW_FRAMES} frames a view, {args.views} views {args.step:g} degrees "
          f"apart, {args.size}^2, {args.resolution}^3)")
    for name in parse_scenes(args.scenes):
        results[name] = {}
        for margins in (False, True):
            scene = builtin_scene(name, args.resolution).with_overrides(width=args.size, height=args.size)
            rows = orbit_run(scene, args.views, args.step, margins)
            later = rows[1:]
            summary = {"views": rows, "first_view_ms": rows[0]["frames_ms"],
                       "later_first_frames_ms": sum(r["first_ms"] for r in later),
                       "later_frames_ms": sum(r["frames_ms"] for r in later),
                       "later_margin_fills_ms": sum(r["margin_fill_ms"] for r in later)}
            results[name]["with_margins" if margins else "without"] = summary
            print(f"{name:8s} {'yes' if margins else 'no':>8s} {summary['first_view_ms']:9.0f} "
                  f"{summary['later_first_frames_ms']:23.0f} {summary['later_frames_ms']:11.0f} "
                  f"{summary['later_margin_fills_ms']:13.0f}", flush=True)
    write_report(args.out, "preview_orbit", finish_info(info, {}),
                 {"resolution": args.resolution, "size": args.size, "views": args.views, "step": args.step,
                  "frames_per_view": PREVIEW_FRAMES}, results=results)


if __name__ == "__main__":
    main()
