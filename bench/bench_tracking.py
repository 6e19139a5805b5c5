"""Delta / ratio tracking throughput: the pure-numpy wavefront baseline against the numba kernels.

The product rule is "pure numpy wavefront code is the baseline; hot loops may be compiled with numba if
a benchmark shows it pays". This is that benchmark for the innermost loop of every renderer.

For each builtin scene's medium, ``--rays`` random rays cross the volume box: origins uniformly on a
sphere around the box, aimed at uniform points inside it, clipped to the box with
:func:`runtime.wavefront.rays.clip_rays_to_volume` (so every ray spans [0, box exit]). Both back ends track the
same rays with the same random streams (``photon_fields.runtime.transport.rng.stream_states``):

- numpy: :mod:`runtime.transport.tracking_numpy_baseline` (global majorant, vectorized over the active rays);
- numba: :mod:`runtime.transport.tracking` (``delta_track_batch`` / ``ratio_track_batch``: majorant-grid DDA,
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
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from common import Contention, finish_info, machine_info, parse_scenes, write_report

from photon_fields.runtime.scene.scene import builtin_scene
from photon_fields.runtime.transport.medium import Medium, build_medium
from photon_fields.runtime.transport.rng import stream_states
from photon_fields.runtime.transport.tracking import delta_track_batch, ratio_track_batch
from photon_fields.runtime.transport.tracking_numpy_baseline import delta_track_numpy, ratio_track_numpy
from photon_fields.runtime.wavefront.rays import RayBatch, clip_rays_to_volume

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "tracking.json"
SPHERE_RADIUS = 1.5  # the box's longest side is 1, so its half-diagonal is at most ~0.87

Tracker = Callable[[Medium, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]


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
    write_report(args.out, "tracking", info, {"rays": args.rays, "repeats": args.repeats, "seed": args.seed},
                 scenes=results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
