"""Reference path tracer throughput: samples per second and frame times per builtin scene.

For each scene, :func:`runtime.renderers.path_tracer.render_path_traced` renders a ``--size`` frame (default
256x256) at each of ``--spp`` (default 1 and 16 samples per pixel) with ``max_depth`` 16, NEE on, the
default batch size. A tiny render (16x16, 1 spp) of the same scene runs first, so numba compilation
or cache loading is not timed. Each frame is rendered ``--repeats`` times with the same seed (identical
work) and the fastest run is kept, with its per-stage wall times (``RenderResult.timings_ms``).

Samples per second counts every pixel sample, including camera rays that miss the volume box (they
cost almost nothing), as ``RenderResult.stats["samples_per_s"]`` does; ``paths_in_volume`` tells how
many samples actually entered the medium.

Parameters (command line)
-------------------------
--size WxH      frame size, or a single number for a square frame (default 256x256)
--spp LIST      samples per pixel, comma-separated (default 1,16)
--max-depth N   maximum scattering vertices per path (default 16)
--scenes S      builtin scenes, comma- or space-separated (default: all)
--repeats R     renders per configuration, fastest kept (default 3)
--seed S        render seed (default 0)
--out PATH      JSON output (default bench/results/pathtracer.json next to this script)

Output: a table on stdout and the JSON file described in ``bench/README.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

# bench/ is on sys.path when this file is run as a script, so the sibling module imports directly.
from common import Contention, finish_info, machine_info, parse_scenes, write_report

from photon_fields.runtime.renderers.path_tracer import RenderResult, render_path_traced
from photon_fields.runtime.scene.scene import BUILTIN_SCENES, Scene, builtin_scene

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "pathtracer.json"
WARMUP_SIZE = 16


def parse_size(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        w, h = (int(p) for p in (parts * 2 if len(parts) == 1 else parts))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT or N, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"width and height must be positive, got {text!r}")
    return w, h


def parse_spp(text: str) -> list[int]:
    try:
        spp = [int(s) for s in text.split(",") if s]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None
    if not spp or min(spp) < 1:
        raise argparse.ArgumentTypeError(f"samples per pixel must be positive, got {text!r}")
    return spp


def render(scene: Scene, spp: int, max_depth: int, seed: int) -> RenderResult:
    return render_path_traced(scene, spp=spp, max_depth=max_depth, seed=seed, progress=False)


def bench_scene(name: str, size: tuple[int, int], spp_list: list[int], max_depth: int, repeats: int,
                seed: int) -> dict[str, Any]:
    base = builtin_scene(name)
    t0 = time.perf_counter()
    render(base.with_overrides(width=WARMUP_SIZE, height=WARMUP_SIZE), 1, max_depth, seed)
    warmup_s = time.perf_counter() - t0
    scene = base.with_overrides(width=size[0], height=size[1])
    scene.medium()  # build the majorant grid outside the timings (render_path_traced would time it)
    res: dict[str, Any] = {"warmup_s": warmup_s, "frames": {}}
    for spp in spp_list:
        runs = [render(scene, spp, max_depth, seed) for _ in range(repeats)]
        best = min(runs, key=lambda r: r.timings_ms["total"])
        res["frames"][str(spp)] = {
            "spp": spp,
            "frame_ms": best.timings_ms["total"],
            "frame_ms_all": [r.timings_ms["total"] for r in runs],
            "samples_per_s": best.stats["samples_per_s"],
            "samples": best.stats["samples"],
            "paths_in_volume": best.stats["paths_in_volume"],
            "stages_ms": {k: v for k, v in best.timings_ms.items() if k != "total"},
        }
    # The headline rate comes from the largest frame: the least dominated by per-batch overheads.
    res["samples_per_s"] = res["frames"][str(max(spp_list))]["samples_per_s"]
    return res


def print_table(results: dict[str, dict[str, Any]], spp_list: list[int]) -> None:
    head = f"{'scene':<8} {'samples/s':>12} " + " ".join(f"{f'{s} spp ms':>11}" for s in spp_list)
    print(head)
    print("-" * len(head))
    for name, r in results.items():
        frames = " ".join(f"{r['frames'][str(s)]['frame_ms']:>11.1f}" for s in spp_list)
        print(f"{name:<8} {r['samples_per_s']:>12,.0f} {frames}")
    # Per-stage breakdown of the largest frame: where the time goes.
    spp = str(max(spp_list))
    stages = sorted({k for r in results.values() for k in r["frames"][spp]["stages_ms"]})
    print(f"\nstage times (ms) at {spp} spp")
    print(f"{'stage':<26}" + "".join(f"{name:>10}" for name in results))
    for st in stages:
        print(f"{st:<26}" + "".join(f"{r['frames'][spp]['stages_ms'].get(st, 0.0):>10.1f}" for r in results.values()))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=parse_size, default=(256, 256), help="WxH or N (default 256x256)")
    ap.add_argument("--spp", type=parse_spp, default=[1, 16], help="comma-separated spp (default 1,16)")
    ap.add_argument("--max-depth", type=int, default=16)
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--repeats", type=int, default=3, help="renders per configuration, fastest kept")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"JSON output (default {DEFAULT_OUT})")
    args = ap.parse_args(argv)
    if args.repeats < 1 or args.max_depth < 1:
        ap.error("--repeats and --max-depth must be at least 1")
    scenes = parse_scenes(args.scenes)
    info = machine_info()
    w, h = args.size
    print(f"path tracer benchmark: {w}x{h}, spp {args.spp}, max_depth {args.max_depth}, best of {args.repeats}; "
          f"{info['usable_cores']} usable cores, numba threads {info['numba_threads']}", flush=True)
    results: dict[str, dict[str, Any]] = {}
    for name in scenes:
        print(f"  {name} ...", flush=True)
        with Contention() as c:
            results[name] = bench_scene(name, args.size, args.spp, args.max_depth, args.repeats, args.seed)
        results[name]["other_cores"] = c.other_cores
    print()
    print_table(results, args.spp)
    info = finish_info(info, results)
    write_report(args.out, "pathtracer", info,
                 {"width": w, "height": h, "spp": args.spp, "max_depth": args.max_depth, "repeats": args.repeats,
                  "seed": args.seed, "scenes": scenes, "available_scenes": list(BUILTIN_SCENES)}, scenes=results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
