"""Helpers shared by the benchmarks: machine facts, contention measurement, scene lists, JSON reports.

Figures are only comparable within one run and on a quiet machine; every report records the CPU model
and its instruction-set flags, the core count, numba's threading layer, the load and how many cores other
processes kept busy, and flags the run as ``machine_busy`` when that foreign load exceeds ``BUSY_FRACTION``
of the usable cores.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np

from photon_fields.runtime.eval.machine import cpu_info
from photon_fields.runtime.eval.timing import Contention  # noqa: F401  (re-exported for the benchmarks)
from photon_fields.runtime.scene.scene import BUILTIN_SCENES

BUSY_FRACTION = 0.2  # foreign load (in cores per usable core) above which a scene's figures are flagged


def machine_info() -> dict[str, Any]:
    """What the figures depend on: the CPU (model, ISA extensions, flags: figures from different CPUs are
    not comparable), core counts (numba's prange scales with threads), versions."""
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count()
    return {"cpu": cpu_info(), "cpu_count": os.cpu_count(), "usable_cores": usable,
            "numba_threads": numba.get_num_threads(),
            "platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__,
            "load_avg_start": load_average()}


def load_average() -> list[float] | None:
    """1/5/15-minute load averages (they include this benchmark's own threads)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def finish_info(info: dict[str, Any], results: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Facts only known after the run: numba's threading layer, the load, whether it was disturbed."""
    try:
        layer = numba.threading_layer()
    except ValueError:  # no parallel kernel ran
        layer = None
    usable = info["usable_cores"] or 1
    disturbed = {name: r["other_cores"] for name, r in results.items()
                 if r.get("other_cores") is not None and r["other_cores"] > BUSY_FRACTION * usable}
    if disturbed:
        print(f"warning: other processes kept cores busy during {disturbed} (cores, of {usable}): "
              "those figures are pessimistic, numba's parallel kernels most of all")
    return {**info, "numba_threading_layer": layer, "load_avg_end": load_average(),
            "machine_busy": bool(disturbed)}


def add_reference_args(ap: argparse.ArgumentParser) -> None:
    """The options of a bench that scores images against the path tracer: ``--scenes`` (default: all builtins),
    ``--size`` (square images, default 256) and ``--ref-spp`` (the reference's samples, default 512)."""
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--ref-spp", type=int, default=512)


def parse_scenes(values: list[str] | None) -> list[str]:
    if not values:
        return list(BUILTIN_SCENES)
    names = [s for v in values for s in v.split(",") if s]
    unknown = [s for s in names if s not in BUILTIN_SCENES]
    if unknown:
        raise SystemExit(f"unknown scene(s) {unknown}; builtin scenes: {', '.join(BUILTIN_SCENES)}")
    return names


def write_report(path: Path, bench: str, info: dict[str, Any], config: dict[str, Any], **sections: Any) -> None:
    """Write ``{"bench", "created", "machine", "config", **sections}`` as indented JSON and say where."""
    doc = {"bench": bench, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": info, "config": config,
           **sections}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"\nwrote {path}")


def alternated_median_ms(fns: dict[str, Callable[[int], Any]], repeats: int) -> dict[str, float]:
    """Median wall time in ms of each ``fns[name](seed)`` over seeds 1 .. ``repeats``, after one warm-up call each:
    round r calls every function once, starting at the r-th (rotated order), so that neither the machine's drift
    nor what the previous call left in the caches favours one of them."""
    for fn in fns.values():
        fn(0)
    names = list(fns)
    times: dict[str, list[float]] = {name: [] for name in names}
    for r in range(repeats):
        for name in names[r % len(names):] + names[:r % len(names)]:
            t0 = time.perf_counter()
            fns[name](r + 1)
            times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(t)) * 1e3 for name, t in times.items()}


def streak_median_ms(fns: dict[str, Callable[[int], Any]], repeats: int, streak: int) -> dict[str, float]:
    """Median wall time in ms of each ``fns[name](seed)``, frames taken ``streak`` in a row per function (a new seed
    each, the first of each streak not timed), in ``repeats`` rounds with the order rotated as in
    :func:`alternated_median_ms`: a viewer renders one method frame after frame, with that method's data warm in
    the caches, which frame-by-frame alternation (each frame after another method's) does not see."""
    names = list(fns)
    times: dict[str, list[float]] = {name: [] for name in names}
    seed = 0
    for r in range(repeats):
        for name in names[r % len(names):] + names[:r % len(names)]:
            for k in range(streak):
                seed += 1
                t0 = time.perf_counter()
                fns[name](seed)
                if k > 0:
                    times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(t)) * 1e3 for name, t in times.items()}


def median_ms(fn: Callable[[int], Any], repeats: int, clock: Callable[[], float] = time.perf_counter) -> float:
    """Median time in ms of ``fn(seed)`` for seeds 1 .. ``repeats``, after one warm-up call ``fn(0)``, on
    ``clock`` (``time.process_time`` for CPU time)."""
    fn(0)
    times = []
    for r in range(repeats):
        t0 = clock()
        fn(r + 1)
        times.append(clock() - t0)
    return float(np.median(times)) * 1e3
