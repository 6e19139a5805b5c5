"""Photon tracing speed (paper Table 3) and photon-map convergence to the path tracer.

1. Tracing: for each builtin scene at ``--resolution`` (default 128^3, the paper's VORTICES size), the
   wall time of :func:`photon_fields.train.photons.tracing.trace_photons` for each of ``--photons`` (default 1M), best
   of ``--repeats``, with records/s and emitted paths. A tiny trace runs first so numba compilation is
   not timed. Goal (issue 3): 1M photons in at most 10 s on 2 cores.
2. Convergence (``--convergence``, default on): on a small optically thin scene, the relative L2 error
   and mean ratio of the photon-map renderer's L_i against a high-spp path-traced L_i, at 100k, 1M and
   4M photons.

Output: a table on stdout and JSON (default ``bench/results/photons.json``).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

from common import Contention, finish_info, machine_info, parse_scenes, write_report

from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped
from photon_fields.runtime.scene.scene import Scene, builtin_scene
from photon_fields.train.cli.train import parse_count
from photon_fields.train.photons.tracing import trace_photons

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "photons.json"


def bench_tracing(name: str, resolution: int, counts: list[int], repeats: int) -> dict[str, Any]:
    scene = builtin_scene(name, resolution)
    scene.medium()
    trace_photons(scene, 1000, progress=False)  # compile / load the numba cache outside the timing
    out: dict[str, Any] = {"resolution": resolution, "runs": {}}
    for n in counts:
        best = None
        with Contention() as c:
            for _ in range(repeats):
                t = time.perf_counter()
                pmap = trace_photons(scene, n, progress=False, seed=1)
                dt = time.perf_counter() - t
                if best is None or dt < best[0]:
                    best = (dt, pmap)
        dt, pmap = best
        out["runs"][str(n)] = {"seconds": dt, "records": len(pmap), "emitted_paths": pmap.emitted,
                               "records_per_s": len(pmap) / dt, "records_per_path": len(pmap) / pmap.emitted,
                               "other_cores": c.other_cores}
    return out


def convergence_scene() -> Scene:
    import numpy as np

    from photon_fields.runtime.scene.camera import Camera
    from photon_fields.runtime.scene.lights import DirectionalLight
    from photon_fields.runtime.scene.transfer import TransferFunction
    from photon_fields.runtime.scene.volume import make_volume

    n = 32
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    field = 0.55 + 0.45 * np.sin(2 * np.pi * X) * np.cos(3 * np.pi * Y) * np.sin(np.pi * Z + 0.3)
    tf = TransferFunction(np.array([0.0, 1.0]), np.full((2, 3), 0.95), np.array([0.0, 1.0]), 8.0, "thin")
    cam = Camera([0.3, 0.4, 2.4], [0, 0, 0], [0, 1, 0], 30.0, 24, 24)
    return Scene(make_volume(field, window=(0.0, 1.0)), tf, (DirectionalLight([-0.5, -1.0, -0.3], [1, 1, 1], 3.0),),
                 cam, 0.0, "thin")


def bench_convergence(counts: list[int], ref_spp: int) -> dict[str, Any]:
    scene = convergence_scene()
    ref = render_path_traced(scene, spp=ref_spp, seed=1, progress=False).layers["L_i"]
    out: dict[str, Any] = {"reference_spp": ref_spp, "radius": 0.05, "k": 1024, "runs": {}}
    for n in counts:
        pmap = trace_photons(scene, n, seed=2, progress=False)
        li = render_photon_mapped(scene, pmap, spp=64, seed=1, progress=False).layers["L_i"]
        rel = math.sqrt(float(((li - ref) ** 2).sum() / (ref**2).sum()))
        out["runs"][str(n)] = {"rel_l2": rel, "mean_ratio": float(li.mean() / ref.mean())}
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", nargs="*", default=None)
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--photons", default="1M", help="comma-separated counts, e.g. 1M,3M")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--no-convergence", action="store_true")
    p.add_argument("--reference-spp", type=int, default=4096)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = p.parse_args(argv)
    counts = [parse_count(c) for c in args.photons.split(",")]
    info = machine_info()
    tracing = {}
    print(f"{'scene':8s} {'photons':>9s} {'seconds':>8s} {'M rec/s':>8s} {'rec/path':>9s}")
    for name in parse_scenes(args.scenes):
        tracing[name] = bench_tracing(name, args.resolution, counts, args.repeats)
        for n, r in tracing[name]["runs"].items():
            print(f"{name:8s} {int(n):9,d} {r['seconds']:8.2f} {r['records_per_s'] / 1e6:8.3f} "
                  f"{r['records_per_path']:9.3f}")
            tracing[name]["other_cores"] = r["other_cores"]
    result: dict[str, Any] = {"tracing": tracing}
    if not args.no_convergence:
        conv = bench_convergence([100_000, 1_000_000, 4_000_000], args.reference_spp)
        result["convergence"] = conv
        print("photon-map L_i vs path-traced L_i (thin smooth scene, K=1024, r=0.05):")
        for n, r in conv["runs"].items():
            print(f"  {int(n):9,d} photons: rel L2 {r['rel_l2']:.4f}, mean ratio {r['mean_ratio']:.4f}")
    write_report(args.out, "photons", finish_info(info, tracing),
                 {"resolution": args.resolution, "photons": counts, "repeats": args.repeats}, **result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
