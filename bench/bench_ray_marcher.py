"""The ray marcher as a preview: its time with and without empty-space skipping, against the other renderers.

For each scene (default: every builtin) at ``--size`` (default 256x256), and at ``--resolution`` voxels per side
(default 96; the issue's case is a 200^3 brain, so also run ``--resolution 256``), in one process after a warm-up:

- the ray marcher at 1 spp (default steps: 0.5 voxel along camera rays, 1 voxel along shadow rays) with
  ``skip_empty`` (camera and shadow rays look nothing up in empty macrocells; the same image bit for bit,
  tests/runtime/renderers/test_ray_marcher.py) and without (every sample looked up: the marcher before);
- the path tracer at 1 spp and, with ``--bundle SCENE=PATH``, the neural renderer at 1 spp, for scale;
- the median wall time of ``--repeats`` renders with all threads, and CPU time on one numba thread
  (``time.process_time``: robust to other processes) for the marcher.

Output: a table and JSON (default ``bench/results/ray_marcher.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402
from common import finish_info, machine_info, median_ms, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.ray_marcher import render_ray_marched  # noqa: E402
from photon_fields.runtime.scene.scene import builtin_scene  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "ray_marcher.json"


def one_thread_cpu_ms(fn: Callable[[int], Any], repeats: int) -> float:
    """CPU milliseconds of ``fn`` on one numba thread."""
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return median_ms(fn, repeats, time.process_time)
    finally:
        numba.set_num_threads(old)


def scene_row(scene: Any, est: Any, repeats: int) -> dict[str, Any]:
    """The marcher with and without skipping, the path tracer and (with ``est``) the neural renderer."""
    row: dict[str, Any] = {}
    for skip in (True, False):
        def march(seed: int, skip: bool = skip) -> Any:
            return render_ray_marched(scene, spp=1, seed=seed, progress=False, skip_empty=skip)

        key = "skip" if skip else "every"
        row[f"marcher_{key}_ms"] = median_ms(march, repeats)
        row[f"marcher_{key}_cpu1_ms"] = one_thread_cpu_ms(march, repeats)
    row["speedup"] = row["marcher_every_ms"] / row["marcher_skip_ms"]
    row["speedup_cpu1"] = row["marcher_every_cpu1_ms"] / row["marcher_skip_cpu1_ms"]
    row["path_tracer_ms"] = median_ms(lambda seed: render_path_traced(scene, spp=1, seed=seed, progress=False),
                                      repeats)
    if est is not None:
        from photon_fields.runtime.renderers.neural import render_neural

        row["neural_ms"] = median_ms(lambda seed: render_neural(scene, est, spp=1, seed=seed, progress=False),
                                     repeats)
    return row


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--resolution", type=int, default=96, help="voxels per side of the builtin volumes")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--bundle", action="append", default=[], metavar="SCENE=PATH",
                    help="a bundle per scene for the neural renderer's row (at the default resolution only)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    given = dict(b.split("=", 1) for b in args.bundle)
    info = machine_info()
    results: dict[str, Any] = {}
    print(f"{'scene':8s} {'marcher, skip':>14s} {'marcher, every':>15s} {'speedup':>8s} {'1 thread CPU':>13s} "
          f"{'path tracer':>12s} {'neural':>8s}   (ms, {args.size}x{args.size}, {args.resolution}^3, 1 spp)")
    for name in parse_scenes(args.scenes):
        scene = builtin_scene(name, args.resolution).with_overrides(width=args.size, height=args.size)
        est = None
        if name in given:
            from photon_fields.runtime.field.field import PhotonField

            est = PhotonField.load(given[name]).estimator()
        row = scene_row(scene, est, args.repeats)
        results[name] = row
        neural = f"{row['neural_ms']:8.0f}" if "neural_ms" in row else f"{'-':>8s}"
        print(f"{name:8s} {row['marcher_skip_ms']:14.0f} {row['marcher_every_ms']:15.0f} {row['speedup']:7.1f}x "
              f"{row['speedup_cpu1']:12.1f}x {row['path_tracer_ms']:12.0f} {neural}", flush=True)
    write_report(args.out, "ray_marcher", finish_info(info, {}), {"size": args.size, "resolution": args.resolution,
                                                                  "repeats": args.repeats}, results=results)


if __name__ == "__main__":
    main()
