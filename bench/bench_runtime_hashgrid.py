"""Inference hash encoding speed: runtime.field.hashgrid.encode points/s (numba, no torch) against the numpy reference.

For each configuration (the paper's D=3 position and D=2 direction encodings, plus smaller tables and
narrower rows), ``runtime.field.hashgrid.encode`` encodes uniform random points (worst case for the caches:
consecutive points share no cells) at several batch sizes with 1 and 2 numba threads, into a
preallocated output (as the renderer does). The D=2 configs get ``direction_to_unit_square`` of uniform
random directions. Tables are random float32 in [-1, 1], 64-byte aligned (``runtime.field.hashgrid.aligned_table``,
what a loader should do). The numpy reference (``photon_fields.models_spec.hashgrid.encode_reference``, single
threaded) runs at the smallest batch only, and its output is compared with the kernel's (it must be
bit-identical). Two more sections explain the kernel's design:

- ``layouts``: the paper configs at ``--layout-batch`` points and 2 threads with each loop layout of
  ``runtime.field.hashgrid.encode_with_layout``: ``blocks`` (the default) at several block sizes, ``blocks`` with
  block 1 (points outside, levels inside) and ``levels`` (levels outside, ``prange`` over blocks inside);
- ``alignment``: the same default kernel on the same table placed 64-byte aligned and 16 bytes past a
  64-byte boundary (where numpy puts large arrays), at ``--layout-batch`` points and 2 threads;
- ``rays``: the paper configs on renderer-like *coherent* queries at ``--layout-batch`` points and 2
  threads: a pinhole camera's rays through a square pixel grid in raster order, 64 samples along each
  ray inside the box (positions), the ray's direction for each of its samples (directions). Also the
  combined rate of one field query's two encodings, ``1 / (1 / r_position + 1 / r_direction)``, for both
  random and ray-ordered inputs (the MLP comes on top).

Every figure is the best of at least ``--repeats`` calls and at least ``--min-time`` seconds of calls,
after a warm-up call (numba compile or cache load, first touch of the buffers). Run on an idle machine:
the kernel is bound by random memory reads, and another process on the 2 cores (or their shared cache
and memory bus) slows it more than anything else; ``other_cores`` records that per measurement.

Parameters (command line)
-------------------------
--batches LIST   batch sizes (default 16384,65536,262144)
--threads LIST   numba thread counts (default 1,2)
--configs LIST   configuration names (default: all of CONFIGS)
--layout-batch N batch of the layouts, alignment and rays sections (default 65536; 0 skips them)
--repeats R      minimum timed calls per figure (default 3)
--min-time S     minimum timed seconds per figure (default 0.25)
--seed S         data seed (default 0)
--out PATH       JSON output (default bench/results/runtime_hashgrid.json next to this script)

Output: a table on stdout and JSON with ``machine``, ``config`` and per configuration: the HashGridConfig,
table rows and MB, ``points_per_s`` per threads and batch (with every call's seconds and other_cores),
the reference's points/s and ``matches_reference``; then ``layouts``, ``alignment`` and ``rays``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numba
import numpy as np

# bench/ is on sys.path when this file is run as a script, so the sibling module imports directly.
from common import Contention, finish_info, machine_info, write_report

from photon_fields.models_spec.hashgrid import (
    PAPER_DIRECTION,
    PAPER_POSITION,
    HashGridConfig,
    direction_to_unit_square,
    encode_reference,
    total_table_rows,
)
from photon_fields.runtime.field.hashgrid import aligned_table, encode, encode_with_layout

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "runtime_hashgrid.json"
CONFIGS: dict[str, HashGridConfig] = {
    "paper_position_D3": PAPER_POSITION,
    "paper_direction_D2": PAPER_DIRECTION,
    "D3_T16": HashGridConfig(3, 16, 8, 16, 16, 2.0),  # 2 MB per fine level: about one core's L2
    "D3_T14": HashGridConfig(3, 16, 8, 14, 16, 2.0),  # 512 KB per fine level: cache-resident
    "D3_F2": HashGridConfig(3, 16, 2, 19, 16, 2.0),  # 8-byte rows: 2^19-row tables of 4 MB
    "D2_T14": HashGridConfig(2, 16, 8, 14, 16, 2.0),
}
LAYOUTS: list[tuple[str, int]] = [("blocks", 256), ("blocks", 1024), ("blocks", 4096), ("blocks", 1),
                                  ("levels", 1024), ("levels", 4096)]


def timed(fn: Callable[[], Any], repeats: int, min_time: float) -> list[float]:
    """Seconds of each call after one warm-up call: at least ``repeats`` calls and ``min_time`` seconds."""
    fn()
    times: list[float] = []
    while len(times) < repeats or sum(times) < min_time:
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def points(cfg: HashGridConfig, n: int, rng: np.random.Generator) -> np.ndarray:
    if cfg.dims == 2:
        d = rng.standard_normal((n, 3))
        return direction_to_unit_square(d / np.linalg.norm(d, axis=1, keepdims=True))
    return rng.random((n, cfg.dims), dtype=np.float32)


def ray_queries(n: int, samples: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Positions (n, 3) and unit directions (n, 3) of ``n // samples`` camera rays in raster order, ``samples``
    equally spaced points each inside the unit box (a renderer's ray-marching batch)."""
    rays = n // samples
    side = max(1, int(np.sqrt(rays)))
    iy, ix = np.divmod(np.arange(rays), side)
    d = np.stack([((ix + 0.5) / side - 0.5) * 0.8, ((iy + 0.5) / side - 0.5) * 0.8, np.ones(rays)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = 1.5 + (np.arange(samples) + 0.5) / samples  # the camera at z = -1.5 sees the box over t in ~[1.5, 2.5]
    p = np.array([0.5, 0.5, -1.5]) + d[:, None, :] * t[None, :, None]
    return np.clip(p.reshape(-1, 3), 0.0, 1.0).astype(np.float32), np.repeat(d, samples, axis=0)


def set_threads(t: int) -> int:
    t = min(t, numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(t)
    return t


def rate(n: int, times: list[float]) -> float:
    return round(n / min(times), 1)


def note_contention(seen: dict[str, dict[str, Any]], key: str, other_cores: float | None) -> None:
    if other_cores is not None:
        old = seen.get(key, {}).get("other_cores") or 0.0
        seen[key] = {"other_cores": max(old, other_cores)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--batches", default="16384,65536,262144")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--layout-batch", type=int, default=65536)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--min-time", type=float, default=0.25)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    try:
        batches = [int(b) for b in args.batches.split(",") if b]
        threads = [int(t) for t in args.threads.split(",") if t]
    except ValueError:
        ap.error("--batches and --threads take comma-separated ints")
    names = [c for c in args.configs.split(",") if c]
    unknown = [c for c in names if c not in CONFIGS]
    if unknown:
        ap.error(f"unknown config(s) {unknown}; known: {', '.join(CONFIGS)}")
    if not batches or min(batches) < 1 or not threads or min(threads) < 1 or args.repeats < 1:
        ap.error("--batches, --threads and --repeats must be >= 1")

    info = machine_info()
    rng = np.random.default_rng(args.seed)
    t_start = time.perf_counter()
    results: dict[str, dict[str, Any]] = {}
    contention: dict[str, dict[str, Any]] = {}  # for finish_info: the worst other_cores per config / section
    print(f"{'config':20s} {'MB':>6s} {'thr':>3s} " + " ".join(f"{f'2^{b.bit_length() - 1}':>9s}" for b in batches)
          + "  (M points/s, best)")
    for name in names:
        cfg = CONFIGS[name]
        table = aligned_table(rng.random((total_table_rows(cfg), cfg.features), dtype=np.float32) * np.float32(2)
                              - np.float32(1))
        xs = {b: points(cfg, b, rng) for b in batches}
        outs = {b: np.empty((b, cfg.output_dims), np.float32) for b in batches}
        res: dict[str, Any] = {"hashgrid_config": cfg.to_dict(), "table_rows": int(table.shape[0]),
                               "table_mb": round(table.nbytes / 2**20, 1), "points_per_s": {}}
        for t in threads:
            t = set_threads(t)
            row: dict[str, Any] = {}
            for b in batches:
                with Contention() as busy:
                    times = timed(partial(encode, cfg, table, xs[b], out=outs[b]), args.repeats, args.min_time)
                row[str(b)] = {"points_per_s": rate(b, times), "times_s": [round(v, 5) for v in times],
                               "other_cores": busy.other_cores}
                note_contention(contention, name, busy.other_cores)
            res["points_per_s"][str(t)] = row
            print(f"{name:20s} {res['table_mb']:6.0f} {t:3d} "
                  + " ".join(f"{row[str(b)]['points_per_s'] / 1e6:9.2f}" for b in batches), flush=True)
        # The reference: single-threaded numpy, smallest batch; also the exactness guard.
        b = min(batches)
        ref = encode_reference(cfg, table, xs[b])
        res["matches_reference"] = bool(np.array_equal(ref, encode(cfg, table, xs[b])))
        with Contention() as busy:
            times = timed(partial(encode_reference, cfg, table, xs[b]), 1, 0.0)
        res["reference"] = {"batch": b, "points_per_s": rate(b, times), "times_s": [round(v, 5) for v in times],
                            "other_cores": busy.other_cores}
        print(f"{'':20s} {'':6s} {'':3s} numpy reference at {b}: {res['reference']['points_per_s'] / 1e6:.3f} "
              f"M/s; bit-identical: {res['matches_reference']}", flush=True)
        results[name] = res

    layouts: dict[str, Any] = {}
    alignment: dict[str, Any] = {}
    rays: dict[str, Any] = {}
    n = args.layout_batch
    if n > 0:
        t = set_threads(max(threads))
        print(f"\nlayouts, table alignment and ray-ordered queries at {n} points, {t} threads (M points/s, best)")
        for name in [c for c in ("paper_position_D3", "paper_direction_D2") if c in names] or names[:1]:
            cfg = CONFIGS[name]
            table = aligned_table(rng.random((total_table_rows(cfg), cfg.features), dtype=np.float32))
            x = points(cfg, n, rng)
            out = np.empty((n, cfg.output_dims), np.float32)
            want = encode(cfg, table, x)
            entry: dict[str, Any] = {}
            for layout, block in LAYOUTS:
                with Contention() as busy:
                    times = timed(partial(encode_with_layout, cfg, table, x, out, layout, block), args.repeats,
                                  args.min_time)
                key = "points_outside" if (layout, block) == ("blocks", 1) else f"{layout}_{block}"
                entry[key] = {"points_per_s": rate(n, times), "times_s": [round(v, 5) for v in times],
                              "other_cores": busy.other_cores, "matches": bool(np.array_equal(out, want))}
                note_contention(contention, f"layouts/{name}", busy.other_cores)
            layouts[name] = {"batch": n, "threads": t, **entry}
            print(f"{name:20s} " + "  ".join(f"{k} {v['points_per_s'] / 1e6:.2f}" for k, v in entry.items()),
                  flush=True)
            # numpy's placement of large arrays: 16 bytes past a cache line.
            buf = np.empty(table.nbytes + 64, np.uint8)
            start = (16 - buf.ctypes.data) % 64
            off16 = buf[start:start + table.nbytes].view(np.float32).reshape(table.shape)
            off16[...] = table
            entry = {}
            for key, tab in (("aligned_64", table), ("offset_16", off16)):
                with Contention() as busy:
                    times = timed(partial(encode, cfg, tab, x, out=out), args.repeats, args.min_time)
                entry[key] = {"points_per_s": rate(n, times), "times_s": [round(v, 5) for v in times],
                              "other_cores": busy.other_cores}
                note_contention(contention, f"alignment/{name}", busy.other_cores)
            alignment[name] = {"batch": n, "threads": t, **entry}
            print(f"{'':20s} table aligned to 64 B {entry['aligned_64']['points_per_s'] / 1e6:.2f}, 16 B past a line "
                  f"{entry['offset_16']['points_per_s'] / 1e6:.2f}", flush=True)
            # Renderer-like coherent queries.
            pos, dirs = ray_queries(n)
            xr = pos if cfg.dims == 3 else direction_to_unit_square(dirs)
            outr = np.empty((xr.shape[0], cfg.output_dims), np.float32)
            with Contention() as busy:
                times = timed(partial(encode, cfg, table, xr, out=outr), args.repeats, args.min_time)
            note_contention(contention, f"rays/{name}", busy.other_cores)
            rays[name] = {"batch": int(xr.shape[0]), "threads": t, "points_per_s": rate(xr.shape[0], times),
                          "random_points_per_s": alignment[name]["aligned_64"]["points_per_s"],
                          "times_s": [round(v, 5) for v in times], "other_cores": busy.other_cores}
            print(f"{'':20s} ray-ordered queries {rays[name]['points_per_s'] / 1e6:.2f}", flush=True)
        if "paper_position_D3" in rays and "paper_direction_D2" in rays:
            p3, p2 = rays["paper_position_D3"], rays["paper_direction_D2"]
            both = {k: round(1.0 / (1.0 / p3[k] + 1.0 / p2[k]), 1) for k in ("random_points_per_s", "points_per_s")}
            rays["field_query_encodings"] = {"random_queries_per_s": both["random_points_per_s"],
                                             "ray_queries_per_s": both["points_per_s"]}
            print(f"one field query's position + direction encodings: {both['random_points_per_s'] / 1e6:.2f} M/s "
                  f"(random), {both['points_per_s'] / 1e6:.2f} M/s (ray-ordered)")

    info = finish_info(info, contention)
    info["wall_s"] = round(time.perf_counter() - t_start, 1)
    write_report(args.out, "runtime_hashgrid", info,
                 {"batches": batches, "threads": threads, "configs": names, "layout_batch": n,
                  "repeats": args.repeats, "min_time": args.min_time, "seed": args.seed},
                 results=results, layouts=layouts, alignment=alignment, rays=rays)
    return 0


if __name__ == "__main__":
    sys.exit(main())
