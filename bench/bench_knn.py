"""K-nearest-photon radiance estimate: the numba grid (photon_fields.runtime.photons.knn) against scipy's cKDTree.

The photon-map training targets (paper Eq. 5) need, per query point, the K = 1024 nearest photons within
r_max and the HG-weighted sum of their powers. This benchmark times that whole estimate:

- grid: :func:`runtime.photons.knn_radiance.knn_radiance` (uniform-grid ring search fused with the estimate; ``prange``
  over query blocks, so it uses all numba threads). It gathers directions/weights into grid order on
  every call, and that copy is timed; ``grid_presorted`` is :func:`runtime.photons.knn_radiance.indexed_radiance` on a
  :class:`runtime.photons.photon_grid.PhotonIndex` built once (what a training loop over a fixed map would use);
- kdtree_w1 / kdtree_wall: ``cKDTree.query(k=K, distance_upper_bound=r, workers=1 / -1)`` followed by a
  vectorized numpy evaluation of the same estimate. Queries go through in chunks of ``--chunk`` so
  the (chunk, K) neighbour arrays stay small (a (2^16, 1024) float64 array alone would be 512 MiB).
  The kd-tree runs on the first ``--kd-queries`` queries only (default 2^13; the queries are in random
  order, so these are a fair sample): at 1-3 thousand queries/s, 3 x 2 runs over all 2^16 queries at
  four radii would take ~10 minutes on 2 cores. Its queries/s are rates, comparable as such.

Grid and tree construction are timed separately (``build_s``) and are not part of queries/s. numba is
compiled (or loaded from its cache) on a small batch before any timing; every measurement is the best
of ``--repeats`` runs. As a guard against benchmarking a broken kernel, the grid and kd-tree estimates
are compared on the kd-tree's queries (max relative difference over queries with a non-zero estimate,
and the number of ``found`` mismatches, which must be 0).

Data: ``--photons`` photons from a mixture of 16 isotropic Gaussians (centres uniform in
[-0.3, 0.3]^3, standard deviations log-uniform in [0.04, 0.15], mixture weights Dirichlet(1)), kept
inside [-0.5, 0.5]^3 by rejection; unit travel directions uniform on the sphere; RGB powers uniform in
[0.5, 1.5] / n. Queries are photons picked at random and jittered by N(0, 0.01^2) per axis ("near
the photons", like camera-path vertices in the medium), with uniform view directions; g = 0.3.

Parameters (command line)
-------------------------
--photons N   photon count (default 2**20)
--queries Q   query count (default 2**16)
--k K         neighbours (default 1024)
--radii LIST  r_max values, comma-separated (default 0.01,0.02,0.05,0.1; the box's longest side is 1)
--repeats R   timed repetitions, best kept (default 3)
--kd-queries Q  queries for the kd-tree baselines (default 2**13; 0: all)
--chunk C     kd-tree queries per chunk (default 2048)
--seed S      data seed (default 0)
--out PATH    JSON output (default bench/results/knn.json next to this script)

Output: a table on stdout and a JSON file with the machine, the configuration and, per radius and
back end, the wall times, the best time, queries/s and the mean ``found``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

# bench/ is on sys.path when this file is run as a script, so the sibling module imports directly.
from common import machine_info, write_report
from scipy.spatial import cKDTree

from photon_fields.runtime.photons.knn_radiance import indexed_radiance, knn_radiance
from photon_fields.runtime.photons.photon_grid import build_photon_grid, build_photon_index
from photon_fields.runtime.transport.phase import INV_4PI

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "knn.json"
G = 0.3
N_CLUSTERS = 16
QUERY_JITTER = 0.01

Estimate = tuple[np.ndarray, np.ndarray, np.ndarray]


def clustered_photons(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` positions from the Gaussian mixture of the module docstring, inside [-0.5, 0.5]^3."""
    centres = rng.uniform(-0.3, 0.3, (N_CLUSTERS, 3))
    sigmas = np.exp(rng.uniform(np.log(0.04), np.log(0.15), N_CLUSTERS))
    mix = rng.dirichlet(np.ones(N_CLUSTERS))
    parts: list[np.ndarray] = []
    have = 0
    while have < n:  # rejection keeps the mixture's shape inside the box (clipping would pile up on faces)
        label = rng.choice(N_CLUSTERS, size=n, p=mix)
        p = centres[label] + rng.normal(size=(n, 3)) * sigmas[label, None]
        p = p[(np.abs(p) <= 0.5).all(axis=1)]
        parts.append(p)
        have += p.shape[0]
    return np.concatenate(parts)[:n]


def unit_vectors(n: int, rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def kdtree_radiance(tree: cKDTree, directions: np.ndarray, weights: np.ndarray, queries: np.ndarray,
                    view_dirs: np.ndarray, k: int, r_max: float, workers: int, chunk: int,
                    query_time: list[float]) -> Estimate:
    """The same estimate as knn_radiance from cKDTree neighbours, in numpy, chunk by chunk. The time spent
    in ``tree.query`` alone is appended to ``query_time``."""
    t_query = 0.0
    q = queries.shape[0]
    est = np.zeros((q, 3))
    radius = np.full(q, r_max)
    found = np.zeros(q, dtype=np.int64)
    # Pad so that the "missing neighbour" index n gathers a zero-weight photon.
    dirs = np.concatenate([directions, np.zeros((1, 3))])
    wts = np.concatenate([weights, np.zeros((1, 3))])
    one_minus_g2 = 1.0 - G * G
    for a in range(0, q, chunk):
        b = min(q, a + chunk)
        t0 = time.perf_counter()
        dist, idx = tree.query(queries[a:b], k=k, distance_upper_bound=r_max, workers=workers)
        t_query += time.perf_counter() - t0
        dist = dist.reshape(b - a, k)
        idx = idx.reshape(b - a, k)
        cnt = np.isfinite(dist).sum(axis=1)
        r = np.where(cnt >= k, dist[:, -1], r_max)
        cos = -np.einsum("qkc,qc->qk", dirs[idx], view_dirs[a:b])
        denom = 1.0 + G * G - 2.0 * G * cos
        p = INV_4PI * one_minus_g2 / (denom * np.sqrt(denom))
        s = np.einsum("qk,qkc->qc", p, wts[idx])
        with np.errstate(divide="ignore", invalid="ignore"):
            e = s / (4.0 / 3.0 * np.pi * r**3)[:, None]
        est[a:b] = np.where(cnt[:, None] > 0, e, 0.0)
        radius[a:b] = r
        found[a:b] = cnt
    query_time.append(t_query)
    return est, radius, found


def best_of(fn: Callable[[], Estimate], repeats: int) -> tuple[list[float], Estimate]:
    times = []
    out: Estimate | None = None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    assert out is not None
    return times, out


def compare(ref: Estimate, other: Estimate) -> dict[str, float]:
    """Max relative difference of the estimates (where the reference is non-zero) and of the radii."""
    e0, r0, f0 = ref
    e1, r1, f1 = other
    nz = e0 != 0.0
    rel = float(np.max(np.abs(e1[nz] - e0[nz]) / np.abs(e0[nz]))) if nz.any() else 0.0
    return {"max_rel_diff_estimate": rel, "max_rel_diff_radius": float(np.max(np.abs(r1 - r0) / r0)),
            "found_mismatches": int(np.count_nonzero(f0 != f1))}


def run(args: argparse.Namespace) -> dict[str, Any]:
    rng = np.random.default_rng(args.seed)
    n, q, k = args.photons, args.queries, args.k
    positions = clustered_photons(n, rng)
    directions = unit_vectors(n, rng)
    weights = rng.uniform(0.5, 1.5, (n, 3)) / n
    queries = positions[rng.integers(0, n, q)] + rng.normal(size=(q, 3)) * QUERY_JITTER
    view_dirs = unit_vectors(q, rng)

    build_photon_grid(positions[:1000])  # compile / load numba's cache of the sort kernels
    t0 = time.perf_counter()
    grid = build_photon_grid(positions)
    t_grid = time.perf_counter() - t0
    t0 = time.perf_counter()
    pmap = build_photon_index(positions, directions, weights, cell_size=grid.cell_size)
    t_map = time.perf_counter() - t0
    t0 = time.perf_counter()
    tree = cKDTree(positions)
    t_tree = time.perf_counter() - t0
    indexed_radiance(pmap, queries[:256], view_dirs[:256], G, k, 0.05)  # compile / load numba's cache
    counts = np.diff(grid.cell_start)
    build = {"grid_s": t_grid, "photon_map_s": t_map, "kdtree_s": t_tree, "cell_size": grid.cell_size,
             "dims": grid.dims.tolist(), "mean_photons_per_occupied_cell": float(counts[counts > 0].mean()),
             "photon_weighted_occupancy": float(counts.astype(np.float64) @ counts / max(n, 1))}

    results: dict[str, Any] = {}
    qk = q if args.kd_queries == 0 else min(q, args.kd_queries)
    kd_queries, kd_view = queries[:qk], view_dirs[:qk]
    for r in args.radii:
        print(f"  r_max = {r} ...", flush=True)
        query_times: dict[str, list[float]] = {"kdtree_w1": [], "kdtree_wall": []}
        runs: dict[str, tuple[int, Callable[[], Estimate]]] = {
            "grid": (q, lambda r=r: knn_radiance(grid, directions, weights, queries, view_dirs, G, k, r)),
            "grid_presorted": (q, lambda r=r: indexed_radiance(pmap, queries, view_dirs, G, k, r)),
            "kdtree_w1": (qk, lambda r=r, qt=query_times["kdtree_w1"]: kdtree_radiance(
                tree, directions, weights, kd_queries, kd_view, k, r, 1, args.chunk, qt)),
            "kdtree_wall": (qk, lambda r=r, qt=query_times["kdtree_wall"]: kdtree_radiance(
                tree, directions, weights, kd_queries, kd_view, k, r, -1, args.chunk, qt)),
        }
        entry: dict[str, Any] = {}
        outs: dict[str, Estimate] = {}
        for name, (nq, fn) in runs.items():
            times, outs[name] = best_of(fn, args.repeats)
            best = min(times)
            entry[name] = {"queries": nq, "times_s": times, "best_s": best, "queries_per_s": nq / best}
            if name in query_times:  # the kd-tree search alone, without the numpy estimate
                entry[name]["query_only_best_s"] = min(query_times[name])
                entry[name]["query_only_queries_per_s"] = nq / min(query_times[name])
        entry["mean_found"] = float(outs["grid"][2].mean())
        entry["fraction_with_k"] = float((outs["grid"][2] == k).mean())
        e, rad, found = outs["grid"]
        entry["check_grid_vs_kdtree"] = compare(outs["kdtree_w1"], (e[:qk], rad[:qk], found[:qk]))
        results[str(r)] = entry
    return {"build": build, "kd_queries": qk, "radii": results}


def print_table(res: dict[str, Any], q: int) -> None:
    b = res["build"]
    print(f"build: grid {b['grid_s']:.2f} s (cell {b['cell_size']:.4g}, dims {b['dims']}, photon-weighted "
          f"occupancy {b['photon_weighted_occupancy']:.1f}), photon map {b['photon_map_s']:.2f} s, "
          f"cKDTree {b['kdtree_s']:.2f} s")
    head = (f"{'r_max':>6} {'found':>6} {'=K':>5} {'grid q/s':>10} {'presorted':>10} {'kd w=1':>9} "
            f"{'kd w=all':>9} {'vs w=1':>7} {'vs all':>7} {'kd query only w=1/all':>22}   "
            f"{'check (rel diff, found)':<24}")
    print(head)
    print("-" * len(head))
    for r, e in res["radii"].items():
        g, gp, k1, ka = (e[x]["queries_per_s"] for x in ("grid", "grid_presorted", "kdtree_w1", "kdtree_wall"))
        c = e["check_grid_vs_kdtree"]
        q1, qa = (e[x]["query_only_queries_per_s"] for x in ("kdtree_w1", "kdtree_wall"))
        print(f"{r:>6} {e['mean_found']:>6.0f} {e['fraction_with_k']:>5.2f} {g:>10,.0f} {gp:>10,.0f} {k1:>9,.0f} "
              f"{ka:>9,.0f} {g / k1:>6.1f}x {g / ka:>6.1f}x {q1:>10,.0f}/{qa:<11,.0f}   "
              f"{c['max_rel_diff_estimate']:.1e}, {c['found_mismatches']} mismatches")
    print(f"({q} queries for the grid, {res['kd_queries']} for the kd-tree; 'found': mean photons used; "
          "'=K': fraction of queries with K photons within r_max; 'vs': grid / kd-tree queries/s; 'kd query only': "
          "cKDTree.query without the numpy estimate)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photons", type=int, default=1 << 20, help="photon count (default 2**20)")
    ap.add_argument("--queries", type=int, default=1 << 16, help="query count (default 2**16)")
    ap.add_argument("--k", type=int, default=1024, help="neighbours (default 1024)")
    ap.add_argument("--radii", type=lambda s: [float(v) for v in s.split(",") if v], default=[0.01, 0.02, 0.05, 0.1],
                    help="r_max values, comma-separated (default 0.01,0.02,0.05,0.1)")
    ap.add_argument("--repeats", type=int, default=3, help="timed repetitions, best kept (default 3)")
    ap.add_argument("--kd-queries", type=int, default=1 << 13,
                    help="queries for the kd-tree baselines (default 2**13; 0: all)")
    ap.add_argument("--chunk", type=int, default=2048, help="kd-tree queries per chunk (default 2048)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"JSON output (default {DEFAULT_OUT})")
    args = ap.parse_args(argv)
    if min(args.photons, args.queries, args.k, args.repeats, args.chunk) < 1 or args.kd_queries < 0 or not args.radii:
        ap.error("--photons, --queries, --k, --repeats and --chunk must be at least 1, --radii non-empty")
    if min(args.radii) <= 0.0:
        ap.error("--radii must be positive")
    info = machine_info()
    print(f"knn benchmark: {args.photons} clustered photons, {args.queries} queries, K = {args.k}, best of "
          f"{args.repeats}; {info['usable_cores']} usable cores, numba threads {info['numba_threads']}", flush=True)
    res = run(args)
    print()
    print_table(res, args.queries)
    write_report(args.out, "knn", info,
                 {"photons": args.photons, "queries": args.queries, "k": args.k, "radii": args.radii,
                  "repeats": args.repeats, "kd_queries": args.kd_queries, "chunk": args.chunk, "seed": args.seed,
                  "g": G, "query_jitter": QUERY_JITTER, "clusters": N_CLUSTERS}, **res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
