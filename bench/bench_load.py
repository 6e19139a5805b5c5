"""Frames on a busy machine: every renderer's frame time idle and with another process holding a core.

Issue 14 measured, on an Intel machine, a 64x64 path-traced frame at 622 ms with one core taken by another process
against 7 ms idle (numba's parallel regions each waiting for a descheduled worker). This bench measures it on the
machine at hand, for each renderer at ``--size`` (default 64 and 256) and each competitor (``--competitors``):

- ``busy``: a pure-Python busy loop (one core, no threads);
- ``blas``: numpy matrix products (OpenBLAS with its own thread pool);
- ``numba``: another process path-tracing in a loop with numba's threads (what a background retrain or a second
  viewer would be);
- ``pinned``: the busy loop pinned to the last core (``taskset``), if ``taskset`` exists.

Renderers: the path tracer at 1 and 16 spp, the neural renderer's L_d (first interactions + NEE: the field's own
cost is onnxruntime's and measured by ``bench_field.py``) with the forced camera estimator, the ray marcher. Figures:
median wall ms of ``--repeats`` frames (a median, not the best: a user sees typical frames), with numba's threads at
their default and at 1, and the ratio loaded / idle. Issue 14's goal: ratio <= 2.5 for every renderer. Output: a
table and JSON (default ``bench/results/load.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numba  # noqa: E402
from common import finish_info, machine_info, median_ms, write_report  # noqa: E402

from photon_fields.runtime.renderers.neural import render_neural  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.ray_marcher import render_ray_marched  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "load.json"
COMPETITORS = {
    "busy": "while True: pass",
    "blas": "import numpy as np\na = np.random.rand(1500, 1500)\nwhile True: a @ a",
    "numba": ("from photon_fields.runtime.scene.scene import builtin_scene\n"
              "from photon_fields.runtime.renderers.path_tracer import render_path_traced\n"
              "s = builtin_scene('vortex').with_overrides(width=128, height=128)\n"
              "while True: render_path_traced(s, spp=4, progress=False)"),
}


def renderers(scene: Scene) -> dict[str, Callable[[int], Any]]:
    return {
        "path tracer 1 spp": lambda seed: render_path_traced(scene, spp=1, seed=seed, progress=False),
        "path tracer 16 spp": lambda seed: render_path_traced(scene, spp=16, seed=seed, progress=False),
        "neural L_d 1 spp": lambda seed: render_neural(scene, None, spp=1, seed=seed, progress=False,
                                                       camera="forced"),
        "ray marcher": lambda seed: render_ray_marched(scene, progress=False),
    }


def start_competitor(name: str) -> subprocess.Popen | None:
    if name == "idle":
        return None
    if name == "pinned":
        last = str(max(os.sched_getaffinity(0)))
        proc = subprocess.Popen(["taskset", "-c", last, sys.executable, "-c", COMPETITORS["busy"]])
    else:
        proc = subprocess.Popen([sys.executable, "-c", COMPETITORS[name]])
    time.sleep(4.0 if name == "numba" else 0.5)  # the numba competitor loads its kernels first
    return proc


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="vortex", help="builtin scene (default vortex)")
    ap.add_argument("--sizes", nargs="+", type=int, default=[64, 256], help="image edges (default 64 256)")
    choices = [*COMPETITORS, "pinned"]
    ap.add_argument("--competitors", nargs="+", choices=choices, default=choices, help="competing processes")
    ap.add_argument("--repeats", type=int, default=9, help="frames per measurement, median kept (default 9)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output")
    args = ap.parse_args(argv)
    if "pinned" in args.competitors and shutil.which("taskset") is None:
        print("taskset not found: no 'pinned' competitor")
        args.competitors.remove("pinned")
    info = machine_info()
    default_threads = numba.get_num_threads()
    results: dict[str, Any] = {}
    for size in args.sizes:
        scene = builtin_scene(args.scene).with_overrides(width=size, height=size)
        fns = renderers(scene)
        table: dict[str, dict[str, float]] = {}
        for competitor in ["idle", *args.competitors]:
            proc = start_competitor(competitor)
            try:
                for threads in sorted({default_threads, 1}, reverse=True):
                    numba.set_num_threads(threads)
                    for label, fn in fns.items():
                        table.setdefault(f"{label}, {threads} threads", {})[competitor] = median_ms(fn, args.repeats)
            finally:
                numba.set_num_threads(default_threads)
                if proc is not None:
                    proc.kill()
                    proc.wait()
        print(f"\n{args.scene} {size}x{size}: median ms (loaded / idle)")
        print(f"  {'renderer':34s} {'idle':>8s} " + " ".join(f"{c:>16s}" for c in args.competitors))
        for key, row in table.items():
            for c in args.competitors:
                row[f"{c}_ratio"] = row[c] / row["idle"]
            cells = " ".join(f"{row[c]:8.1f} ({row[f'{c}_ratio']:4.1f}x)" for c in args.competitors)
            print(f"  {key:34s} {row['idle']:8.1f} {cells}", flush=True)
        results[f"{size}"] = table
    info = finish_info(info, {})
    write_report(args.out, "load", info, {"scene": args.scene, "sizes": args.sizes, "competitors": args.competitors,
                                          "repeats": args.repeats}, results=results)


if __name__ == "__main__":
    main()
