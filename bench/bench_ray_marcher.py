"""The ray marcher as a preview: its frame time against the other renderers at equal image size.

For each scene (default: every builtin) at ``--size`` (default 256x256), and at ``--resolution`` voxels per side
(default 96; the issue's case is a 200^3 brain, so also run ``--resolution 256``), in one process after a warm-up,
1 spp, median wall time of ``--repeats`` renders with all threads (the warm renderers alternated, a rotated order per
round):

- the preview (``shadows="volume"``, the default): its first frame, which marches the light-volume cells it reads
  (the volume is emptied before each), and a frame of the same scene after ``--fill-frames`` others (default 30: a
  progressive pass, a camera moving within what was seen: the cells are filled; each new jitter reads a few cells
  no frame read before, and a frame that fills them is partly a first frame), with the fraction of the light
  volume's cells filled; and the same warm frame with fixed 1-voxel steps (``max_step=1``: the preview before its
  adaptive segments);
- on a volume over 128 voxels a side, the preview of its interactive level (``runtime/scene/levels.py``, what the
  viewer shows first after each change): first and warm frames, and the 8-frame average's relative L2 and mean
  against the full volume's;
- the marcher with a shadow ray per sample and light (``shadows="march"``, the paper's baseline), same steps;
- the path tracer and, with ``--bundle SCENE=PATH``, the neural renderer (Alg. 2), for scale.

Output: a table and JSON (default ``bench/results/ray_marcher.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import (  # noqa: E402
    alternated_median_ms,
    finish_info,
    machine_info,
    median_ms,
    parse_scenes,
    streak_median_ms,
    write_report,
)

from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.ray_marcher import render_ray_marched  # noqa: E402
from photon_fields.runtime.scene.levels import interactive_level, scene_at_level  # noqa: E402
from photon_fields.runtime.scene.scene import builtin_scene, load_scene  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "ray_marcher.json"


def scene_row(scene: Any, est: Any, repeats: int, fill_frames: int, streak: int = 1) -> dict[str, Any]:
    """The preview cold; then ``fill_frames`` preview frames of other seeds with each of its step settings (each new
    jitter reads a few cells no frame read before: at 256^3 the fifteenth frame still fills some, and a warm frame
    that fills cells is a first frame in part); then, alternated (``alternated_median_ms``; with ``streak`` > 1 in
    streaks of that many frames per renderer, ``streak_median_ms``, the viewer's way), the preview warm with its
    adaptive segments and with fixed steps, the marched baseline, the path tracer and (with ``est``) the neural
    renderer with the forced camera estimator (its fastest frame) and with its default (``auto``)."""
    from photon_fields.runtime.renderers.ray_marcher import light_volume_settings, scene_light_volume
    from photon_fields.runtime.transport.light_volume import UNFILLED

    volumes = scene.shared_cache("light_volumes")
    row: dict[str, Any] = {}

    def cold(seed: int) -> Any:
        volumes.clear()
        return render_ray_marched(scene, spp=1, seed=seed, progress=False)

    row["preview_first_ms"] = median_ms(cold, repeats)
    for seed in range(fill_frames):
        for max_step in (None, 1.0):
            render_ray_marched(scene, spp=1, seed=1000 + seed, max_step=max_step, progress=False)
    level = interactive_level(scene.volume.dims)
    warm = level_row(scene, level, repeats, fill_frames, row) if level else {}
    warm |= {
        "preview_ms": lambda seed: render_ray_marched(scene, spp=1, seed=seed, progress=False),
        "preview_fixed_steps_ms": lambda seed: render_ray_marched(scene, spp=1, seed=seed, max_step=1.0,
                                                                  progress=False),
        "march_ms": lambda seed: render_ray_marched(scene, spp=1, seed=seed, shadows="march", progress=False),
        "path_tracer_ms": lambda seed: render_path_traced(scene, spp=1, seed=seed, progress=False),
    }
    if est is not None:
        from photon_fields.runtime.renderers.neural import render_neural

        # the neural renderer's fastest frame (forced), as in the tables before auto became the default
        warm["neural_ms"] = lambda seed: render_neural(scene, est, spp=1, seed=seed, progress=False, camera="forced")
        warm["neural_default_ms"] = lambda seed: render_neural(scene, est, spp=1, seed=seed, progress=False)
    row.update(alternated_median_ms(warm, repeats) if streak <= 1 else streak_median_ms(warm, repeats, streak))
    values = scene_light_volume(scene, *light_volume_settings(scene)).values
    row["light_volume_filled"] = float((values != UNFILLED).mean())
    row["light_volume_mb"] = values.nbytes / 1e6
    return row


def level_row(scene: Any, level: int, repeats: int, fill_frames: int, row: dict[str, Any]) -> dict[str, Any]:
    """Into ``row``: the interactive ``level``'s first preview frame (its light volume emptied before each; its
    medium and step grids kept, as after a camera move in the viewer) and its 8-frame average against the full
    volume's (relative L2, mean ratio); then ``fill_frames`` frames at the level. Returns its warm frame for the
    alternated timing."""
    volumes = scene_at_level(scene, level).shared_cache("light_volumes")

    def cold(seed: int) -> Any:
        volumes.clear()
        return render_ray_marched(scene, spp=1, seed=seed, progress=False, level=level)

    row["level"] = level
    row["level_first_ms"] = median_ms(cold, repeats)

    def average(lv: int) -> np.ndarray:
        return np.mean([render_ray_marched(scene, spp=1, seed=s, progress=False, level=lv).layers["L"]
                        for s in range(8)], 0)

    full, coarse = average(0), average(level)
    row["level_rel_l2"] = float(np.linalg.norm(coarse - full) / np.linalg.norm(full))
    row["level_mean_ratio"] = float(coarse.mean() / full.mean())
    for seed in range(fill_frames):
        render_ray_marched(scene, spp=1, seed=1000 + seed, progress=False, level=level)
    return {"level_ms": lambda seed: render_ray_marched(scene, spp=1, seed=seed, progress=False, level=level)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--scene-file", action="append", default=[], metavar="PATH",
                    help="also a scene JSON (a user's volume; its name keys --bundle), at its own resolution")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--resolution", type=int, default=96, help="voxels per side of the builtin volumes")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--fill-frames", type=int, default=30,
                    help="preview frames rendered before the warm ones are timed (their light volume filled)")
    ap.add_argument("--bundle", action="append", default=[], metavar="SCENE=PATH",
                    help="a bundle per scene for the neural renderer's row (trained at --resolution)")
    ap.add_argument("--streak", type=int, default=1,
                    help="warm frames per renderer in a row, the first not timed (1: every frame after another "
                         "renderer's; the viewer renders one renderer's frames in a row, its data warm)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    given = dict(b.split("=", 1) for b in args.bundle)
    info = machine_info()
    results: dict[str, Any] = {}
    print(f"{'scene':8s} {'preview 1st':>12s} {'preview':>8s} {'fixed steps':>12s} {'filled':>7s} {'march':>8s} "
          f"{'path tracer':>12s} {'neural':>8s} {'(auto)':>8s}  (ms, {args.size}x{args.size}, builtins at "
          f"{args.resolution}^3, 1 spp; neural: forced, and its default camera estimator)")
    scenes = [(name, lambda name=name: builtin_scene(name, args.resolution))
              for name in (parse_scenes(args.scenes) if args.scenes or not args.scene_file else [])]
    scenes += [(Path(path).stem, lambda path=path: load_scene(path)) for path in args.scene_file]
    for name, make in scenes:
        scene = make().with_overrides(width=args.size, height=args.size)
        est = None
        if name in given:
            from photon_fields.runtime.field.field import PhotonField

            est = PhotonField.load(given[name]).estimator()
        row = scene_row(scene, est, args.repeats, args.fill_frames, args.streak)
        results[name] = row
        neural = (f"{row['neural_ms']:8.1f} {row['neural_default_ms']:8.1f}" if "neural_ms" in row
                  else f"{'-':>8s} {'-':>8s}")
        print(f"{name:8s} {row['preview_first_ms']:12.0f} {row['preview_ms']:8.1f} "
              f"{row['preview_fixed_steps_ms']:12.1f} {row['light_volume_filled']:7.3f} {row['march_ms']:8.1f} "
              f"{row['path_tracer_ms']:12.1f} {neural}",
              flush=True)
        if "level" in row:
            print(f"{'':8s} level {row['level']}: first {row['level_first_ms']:.0f} ms, warm {row['level_ms']:.1f} ms; "
                  f"8-frame average against the full volume's: rel. L2 {row['level_rel_l2']:.3f}, mean "
                  f"{row['level_mean_ratio']:.3f}", flush=True)
    write_report(args.out, "ray_marcher", finish_info(info, {}), {"size": args.size, "resolution": args.resolution,
                                                                  "repeats": args.repeats,
                                                                  "fill_frames": args.fill_frames,
                                                                  "streak": args.streak,
                                                                  "scene_files": args.scene_file}, results=results)


if __name__ == "__main__":
    main()
