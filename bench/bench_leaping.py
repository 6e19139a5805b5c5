"""Empty-space leaping: what the walk over the majorant grid costs with and without it, per macrocell size.

For each scene (default: every builtin) at ``--size`` (default 256x256), in one process, for each configuration of
the medium (``--configs``, default ``4:step`` = the walk before leaping, ``4:leap``, ``2:step``, ``2:leap`` = the
default, ``1:leap``; ``MACROCELL:step|leap``):

- ``sample_first_interactions`` of the neural renderer with each camera estimator (forced, delta): the camera rays'
  walks, the stage issue 14 asks to make cheaper;
- the path tracer at 1 spp (every flight and shadow ray walks the grid);
- CPU milliseconds on one numba thread (``time.process_time``: robust to other processes on the machine, the
  figure to compare configurations by) and wall milliseconds with all threads, the median of ``--repeats``.

Leaping changes no sample (tests/runtime/transport/test_leaping.py), the macrocell size changes the majorants and
hence the samples, not their mean. Ratios are against the first configuration. Output: a table and JSON (default
``bench/results/leaping.json``) with the machine record.
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
import numpy as np  # noqa: E402
from common import finish_info, machine_info, median_ms, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402
from photon_fields.runtime.transport.medium import build_medium  # noqa: E402
from photon_fields.runtime.wavefront.first_interaction import FirstInteractions, sample_first_interactions  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "leaping.json"
DEFAULT_CONFIGS = ["4:step", "4:leap", "2:step", "2:leap", "1:leap"]


def config(value: str) -> tuple[int, bool]:
    cell, _, mode = value.partition(":")
    if not cell.isdigit() or int(cell) < 1 or mode not in ("step", "leap"):
        raise argparse.ArgumentTypeError(f"expected MACROCELL:step or MACROCELL:leap, got {value!r}")
    return int(cell), mode == "leap"


def measure(scene: Scene, repeats: int) -> dict[str, float]:
    n = scene.camera.width * scene.camera.height
    scratch, status, transmit = FirstInteractions.empty(n), np.empty(n, np.uint8), np.empty(n)
    m = scene.medium()

    def first(camera: str) -> Callable[[int], Any]:
        return lambda seed: sample_first_interactions(scene, m, 0, n, seed, scratch, status, transmit, camera)

    def path_traced(seed: int) -> Any:
        return render_path_traced(scene, spp=1, seed=seed, progress=False)

    out = {}
    threads = numba.get_num_threads()
    for label, fn in (("forced", first("forced")), ("delta", first("delta")), ("path_tracer", path_traced)):
        numba.set_num_threads(1)
        out[f"{label}_cpu_ms"] = median_ms(fn, repeats, time.process_time)
        numba.set_num_threads(threads)
        out[f"{label}_wall_ms"] = median_ms(fn, repeats, time.perf_counter)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="*", default=None, help="builtin scenes (default: all)")
    ap.add_argument("--size", type=int, default=256, help="image edge in pixels (default 256)")
    ap.add_argument("--configs", nargs="+", type=config, default=[config(c) for c in DEFAULT_CONFIGS],
                    help="MACROCELL:step|leap (default: %(default)s)")
    ap.add_argument("--repeats", type=int, default=7, help="timed repetitions, median kept (default 7)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output")
    args = ap.parse_args(argv)
    info = machine_info()
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes):
        base = builtin_scene(name).with_overrides(width=args.size, height=args.size)
        rows = {}
        for cell, leap in args.configs:
            scene = base.with_overrides()
            scene._cache["medium"] = build_medium(base.volume, base.tf, cell, leap=leap)
            rows[f"{cell}:{'leap' if leap else 'step'}"] = measure(scene, args.repeats)
        first = next(iter(rows.values()))
        print(f"\n{name} ({args.size}x{args.size}); x = speedup over {next(iter(rows))}")
        head = "".join(f"{h:>14s} " for h in ("forced cpu", "delta cpu", "PT 1spp cpu"))
        print(f"  {'config':8s} {head}  wall ms (forced/delta/PT)")
        for key, row in rows.items():
            for label in ("forced", "delta", "path_tracer"):
                row[f"{label}_cpu_speedup"] = first[f"{label}_cpu_ms"] / row[f"{label}_cpu_ms"]
            cells = [f"{row[f'{lab}_cpu_ms']:6.1f} {row[f'{lab}_cpu_speedup']:4.2f}x"
                     for lab in ("forced", "delta", "path_tracer")]
            walls = "/".join(f"{row[f'{lab}_wall_ms']:.1f}" for lab in ("forced", "delta", "path_tracer"))
            print(f"  {key:8s} {cells[0]:>14s} {cells[1]:>14s} {cells[2]:>14s}   {walls}", flush=True)
        results[name] = rows
    info = finish_info(info, {})
    write_report(args.out, "leaping", info, {"size": args.size, "repeats": args.repeats,
                                             "configs": [f"{c}:{'leap' if lp else 'step'}" for c, lp in args.configs]},
                 results=results)


if __name__ == "__main__":
    main()
