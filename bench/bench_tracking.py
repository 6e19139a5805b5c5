"""Delta / ratio tracking throughput: the pure-numpy wavefront baseline against the numba kernels.

The product rule is "pure numpy wavefront code is the baseline; hot loops may be compiled with numba if
a benchmark shows it pays". This is that benchmark for the innermost loop of every renderer.

For each builtin scene's medium, ``--rays`` random rays cross the volume box: origins uniformly on a
sphere around the box, aimed at uniform points inside it, clipped to the box with
:func:`runtime.rays.clip_rays_to_volume` (so every ray spans [0, box exit]). Both back ends track the
same rays with the same random streams (``runtime.rng.stream_states``):

- numpy: :mod:`runtime.tracking_numpy` (global majorant, vectorized over the active rays);
- numba: :mod:`runtime.tracking` (``delta_track_batch`` / ``ratio_track_batch``: majorant-grid DDA,
  ``prange`` over rays, so it uses all of numba's threads);
- numba_global: the same numba kernels on a medium built with a single macrocell, i.e. with the
  numpy baseline's global majorant. ``numba_global / numpy`` is what compilation alone buys;
  ``numba / numba_global`` is what the majorant grid buys on top (the DDA is what does not vectorize).

numba is compiled (or loaded from its cache) before any timing. Each measurement is repeated
``--repeats`` times and the best wall time is kept (the least disturbed run). The escape fraction and
the mean transmittance of both back ends are reported as well: they estimate the same quantity, so
they should agree to within Monte Carlo noise (a cheap guard against benchmarking a broken kernel).

Parameters (command line)
-------------------------
--rays N      rays per measurement (default 2**18)
--repeats R   timed repetitions per measurement, best kept (default 3)
--scenes S    builtin scenes, comma- or space-separated (default: all)
--seed S      seed of the rays and random streams (default 0)
--out PATH    JSON output (default bench/results/tracking.json next to this script)

Output: a table on stdout and the JSON file described in ``bench/README.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np

from runtime.medium import Medium, build_medium
from runtime.rays import RayBatch, clip_rays_to_volume
from runtime.rng import stream_states
from runtime.scene import BUILTIN_SCENES, builtin_scene
from runtime.tracking import delta_track_batch, ratio_track_batch
from runtime.tracking_numpy import delta_track_numpy, ratio_track_numpy

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "tracking.json"
BUSY_FRACTION = 0.2  # foreign load (in cores per usable core) above which a scene's figures are flagged
SPHERE_RADIUS = 1.5  # the box's longest side is 1, so its half-diagonal is at most ~0.87

Tracker = Callable[[Medium, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def machine_info() -> dict[str, Any]:
    """What the figures depend on: core counts (numba's prange scales with threads), versions."""
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        usable = os.cpu_count()
    return {"cpu_count": os.cpu_count(), "usable_cores": usable, "numba_threads": numba.get_num_threads(),
            "platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(), "numpy": np.__version__, "numba": numba.__version__,
            "load_avg_start": load_average()}


def load_average() -> list[float] | None:
    """1/5/15-minute load averages (they include this benchmark's own threads)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


def _busy_cpu_seconds() -> float | None:
    """CPU seconds spent busy by the whole machine since boot (Linux /proc/stat), else None."""
    try:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    user, nice, system, _idle, _iowait, irq, softirq, steal = fields
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


class Contention:
    """Measures how many cores *other* processes kept busy while the block ran (machine busy time
    minus this process's CPU time, over wall time): ``with Contention() as c: ...; c.other_cores``.
    Numba's prange kernels synchronize at the end of every stage, so one descheduled worker stalls
    the stage: even half a core of foreign load distorts the numba figures far more than numpy's."""

    def __enter__(self) -> Contention:
        self.other_cores: float | None = None
        self._t, self._busy, self._own = time.perf_counter(), _busy_cpu_seconds(), _own_cpu_seconds()
        return self

    def __exit__(self, *exc: object) -> None:
        busy = _busy_cpu_seconds()
        wall = time.perf_counter() - self._t
        if busy is not None and self._busy is not None and wall > 0:
            other = (busy - self._busy) - (_own_cpu_seconds() - self._own)
            self.other_cores = round(max(other, 0.0) / wall, 3)


def _own_cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system  # all threads of this process, numba's workers included


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


def random_box_rays(m: Medium, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` rays from a sphere around the box towards uniform interior points, clipped to the box.
    Returns (o (3, n) on the entry face, unit d (3, n), tmax (n,) = distance to the exit)."""
    rng = np.random.default_rng(seed)
    centre = m.bmin + 0.5 * m.bsize
    v = rng.normal(size=(3, n))
    o = centre[:, None] + SPHERE_RADIUS * v / np.linalg.norm(v, axis=0)
    target = m.bmin[:, None] + rng.uniform(0.0, 1.0, size=(3, n)) * m.bsize[:, None]
    d = target - o
    d /= np.linalg.norm(d, axis=0)
    rays = RayBatch(pixel=np.arange(n, dtype=np.int64), o=np.ascontiguousarray(o), d=np.ascontiguousarray(d),
                    tmax=np.full(n, np.inf), beta=np.ones((3, n)), rng=np.zeros(n, dtype=np.uint64),
                    depth=np.zeros(n, dtype=np.int64), pdf=np.full(n, np.inf))
    hit = clip_rays_to_volume(m, rays)
    # Aimed at interior points, every ray hits; a miss would only come from a degenerate draw.
    rays = rays.compact(hit)
    return np.ascontiguousarray(rays.o), np.ascontiguousarray(rays.d), rays.tmax


def time_tracker(fn: Tracker, m: Medium, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, states: np.ndarray,
                 repeats: int) -> tuple[list[float], np.ndarray]:
    """Wall times of ``repeats`` runs on fresh copies of the same streams, and the last result."""
    tmin = np.zeros(o.shape[1])
    times = []
    out = np.empty(0)
    for _ in range(repeats):
        s = states.copy()  # same random numbers every repetition: identical work
        t0 = time.perf_counter()
        out = fn(m, o, d, tmin, tmax, s)
        times.append(time.perf_counter() - t0)
    return times, out


def warm_up(m: Medium) -> None:
    """Compile (or load from numba's cache) both batch kernels outside the timings."""
    o, d, tmax = random_box_rays(m, 256, seed=12345)
    for fn in (delta_track_batch, ratio_track_batch):
        fn(m, o, d, np.zeros(o.shape[1]), tmax, stream_states(1, 0, o.shape[1]))


def bench_scene(name: str, n_rays: int, repeats: int, seed: int) -> dict[str, Any]:
    scene = builtin_scene(name)
    m = scene.medium()
    # One macrocell spanning the volume: the numba kernels then track with the global majorant.
    m_global = build_medium(scene.volume, scene.tf, macrocell=max(scene.volume.dims))
    warm_up(m)
    o, d, tmax = random_box_rays(m, n_rays, seed)
    states = stream_states(seed, 0, o.shape[1])
    n = o.shape[1]
    res: dict[str, Any] = {
        "rays": n,
        "medium": {"dims": list(m.density.shape), "majorant_cells": list(m.majorant.shape),
                   "global_majorant": float(m.majorant.max()), "mean_majorant": float(m.majorant.mean()),
                   "mean_ray_length": float(tmax.mean())},
    }
    for kind, fns in (("delta", (delta_track_numpy, delta_track_batch)),
                      ("ratio", (ratio_track_numpy, ratio_track_batch))):
        entry: dict[str, Any] = {}
        runs = (("numpy", fns[0], m), ("numba_global", fns[1], m_global), ("numba", fns[1], m))
        for backend, fn, medium in runs:
            times, out = time_tracker(fn, medium, o, d, tmax, states, repeats)
            best = min(times)
            entry[backend] = {"times_s": times, "best_s": best, "rays_per_s": n / best}
            if kind == "delta":
                entry[backend]["escape_fraction"] = float(np.isinf(out).mean())
            else:
                entry[backend]["mean_transmittance"] = float(out.mean())
        entry["speedup"] = entry["numba"]["rays_per_s"] / entry["numpy"]["rays_per_s"]
        entry["speedup_compile_only"] = entry["numba_global"]["rays_per_s"] / entry["numpy"]["rays_per_s"]
        res[kind] = entry
    return res


def print_table(results: dict[str, dict[str, Any]]) -> None:
    head = (f"{'scene':<7} {'kind':<6} {'numpy rays/s':>13} {'numba 1-cell':>13} {'numba rays/s':>13} "
            f"{'speedup':>8} {'(1-cell)':>8}   {'estimate: numpy / numba':<24}")
    print(head)
    print("-" * len(head))
    for name, r in results.items():
        for kind, key, label in (("delta", "escape_fraction", "escape"), ("ratio", "mean_transmittance", "Tr")):
            e = r[kind]
            check = f"{label} {e['numpy'][key]:.4f} / {e['numba'][key]:.4f}"
            print(f"{name:<7} {kind:<6} {e['numpy']['rays_per_s']:>13,.0f} {e['numba_global']['rays_per_s']:>13,.0f} "
                  f"{e['numba']['rays_per_s']:>13,.0f} {e['speedup']:>7.1f}x {e['speedup_compile_only']:>7.1f}x   "
                  f"{check:<24}")


def parse_scenes(values: list[str] | None) -> list[str]:
    if not values:
        return list(BUILTIN_SCENES)
    names = [s for v in values for s in v.split(",") if s]
    unknown = [s for s in names if s not in BUILTIN_SCENES]
    if unknown:
        raise SystemExit(f"unknown scene(s) {unknown}; builtin scenes: {', '.join(BUILTIN_SCENES)}")
    return names


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rays", type=int, default=1 << 18, help="rays per measurement (default 2**18)")
    ap.add_argument("--repeats", type=int, default=3, help="timed repetitions, best kept (default 3)")
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"JSON output (default {DEFAULT_OUT})")
    args = ap.parse_args(argv)
    if args.rays < 1 or args.repeats < 1:
        ap.error("--rays and --repeats must be at least 1")
    scenes = parse_scenes(args.scenes)
    info = machine_info()
    print(f"tracking benchmark: {args.rays} rays, best of {args.repeats}; {info['usable_cores']} usable cores, "
          f"numba threads {info['numba_threads']}", flush=True)
    results: dict[str, dict[str, Any]] = {}
    for name in scenes:
        print(f"  {name} ...", flush=True)
        with Contention() as c:
            results[name] = bench_scene(name, args.rays, args.repeats, args.seed)
        results[name]["other_cores"] = c.other_cores
    print()
    print_table(results)
    info = finish_info(info, results)
    doc = {"bench": "tracking", "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": info,
           "config": {"rays": args.rays, "repeats": args.repeats, "seed": args.seed}, "scenes": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
