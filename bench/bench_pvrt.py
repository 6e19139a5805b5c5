"""PVRT (Zhang, Dong, Ma 2013; runtime/pvrt): precomputation cost, frame time after a light change, and the
error against the path tracer under a few light directions.

Per builtin scene (default vortex, at ``--resolution``^3 voxels, its directional light only):

1. precompute a transfer (``--grid``, ``--order``, ``--paths`` per basis light): trace and CPCA seconds, the
   process's peak RSS growth (``ru_maxrss``), the file's size;
2. frame time after a light change at each of ``--sizes`` (1 spp; the light direction changes before every frame,
   so every frame re-projects the lighting, re-evaluates the radiance volume and re-marches the light volume):
   median and best of ``--repeats`` frames after a warm-up, with the stages' split (of the median frame), for
   ``render_pvrt`` (the whole march: what a frame after a camera change costs too) and for ``Relighting`` (the
   view kept: the camera samples marched once, their cost reported as "keep", and summed under each new light),
   and the largest relative difference of the two frames' L_d and L_i (the float32 of the kept samples);
3. for each light direction (the scene's and ``--dirs`` more, turned about the vertical axis): PVRT against two
   path-traced images (``--ref-spp`` each, seeds 1 and 2; cached in ``--work``) at ``--ref-size``: mean ratios of
   L_d, L_i and L, and the relative L2 of L against the first reference beside the references' own (the L2
   between the two / sqrt 2: what the reference's noise alone gives).

Output: a table and JSON (default ``bench/results/pvrt.json``) with the machine record (CPU model, load).
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from common import Contention, finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.eval.metrics import relative_l2  # noqa: E402
from photon_fields.runtime.pvrt.transfer import precompute_transfer, save_transfer  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.pvrt import Relighting, render_pvrt  # noqa: E402
from photon_fields.runtime.scene.lights import DirectionalLight  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "pvrt.json"
DEFAULT_WORK = HERE / "results" / "pvrt"


def turned(scene: Scene, degrees: float) -> Scene:
    """``scene`` with its directional lights (only) turned by ``degrees`` about the vertical (y) axis. The medium
    ignores the lights, so the copy shares it, as the viewer's scene after a light edit does
    (``runtime/viewer/session.py``): a light change rebuilds no majorant grid."""
    a = math.radians(degrees)
    r = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    lights = tuple(DirectionalLight(r @ lt.direction, lt.color, lt.power) for lt in scene.lights
                   if isinstance(lt, DirectionalLight))
    out = replace(scene, lights=lights, _cache={})
    if "medium" in scene._cache:
        out._cache["medium"] = scene._cache["medium"]
    return out


def reference(scene: Scene, spp: int, seed: int, work: Path, tag: str) -> dict[str, np.ndarray]:
    """Path-traced layers (cached as .npz in ``work``)."""
    cam = scene.camera
    path = work / f"ref_{scene.name}_{tag}_{cam.width}x{cam.height}_{spp}_{seed}.npz"
    if not path.exists():
        t0 = time.perf_counter()
        path.parent.mkdir(parents=True, exist_ok=True)
        layers = render_path_traced(scene, spp=spp, seed=seed, progress=False).layers
        np.savez(path, **{k: layers[k] for k in ("L", "L_d", "L_i")})
        print(f"  reference {tag} {spp} spp seed {seed}: {time.perf_counter() - t0:.0f} s", flush=True)
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["vortex"], help="builtin scenes with a directional light")
    ap.add_argument("--resolution", type=int, default=48, help="voxels along each side of the builtin volume")
    ap.add_argument("--grid", type=int, default=24, help="transfer cells along the longest side")
    ap.add_argument("--order", type=int, default=1, help="DSF order (1: 42 basis lights)")
    ap.add_argument("--paths", type=int, default=8000, help="photon paths per basis light")
    ap.add_argument("--sizes", type=int, nargs="*", default=[256, 512], help="frame sizes timed (square)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ref-size", type=int, default=96)
    ap.add_argument("--ref-spp", type=int, default=64)
    ap.add_argument("--dirs", type=int, default=2, help="light directions besides the scene's (turned 120 deg)")
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    info = machine_info()
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes):
        base = turned(builtin_scene(name, args.resolution), 0.0)
        if not base.lights:
            raise SystemExit(f"scene {name} has no directional light")
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        with Contention() as c_pre:
            t0 = time.perf_counter()
            transfer = precompute_transfer(base, order=args.order, grid=args.grid, paths=args.paths, seed=0,
                                           progress=False)
            pre_s = time.perf_counter() - t0
        peak_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
        with tempfile.TemporaryDirectory() as tmp:
            size_mb = save_transfer(transfer, Path(tmp) / "t.pvrt").stat().st_size / 1e6
        pre = {"seconds": pre_s, **(transfer.seconds or {}), "peak_rss_growth_mb": peak_mb, "file_mb": size_mb,
               "grid": transfer.manifest["grid"], "basis_lights": transfer.basis.size,
               "cpca_relative_error": transfer.manifest["cpca"]["relative_error"], "other_cores": c_pre.other_cores}
        print(f"\n{name} {args.resolution}^3: precompute {pre_s:.1f} s (trace {pre.get('trace', 0):.1f}, CPCA "
              f"{pre.get('cpca', 0):.1f}), peak RSS +{peak_mb:.0f} MB, file {size_mb:.1f} MB, grid {pre['grid']}, "
              f"{pre['basis_lights']} basis lights, CPCA error {pre['cpca_relative_error']:.3f}", flush=True)
        frames: dict[str, Any] = {}
        for size in args.sizes:
            scene = base.with_overrides(width=size, height=size)
            render_pvrt(turned(scene, 7.0), transfer=transfer, progress=False)  # warm-up (compiles)
            t0 = time.perf_counter()
            relit = Relighting(scene, transfer)
            keep_ms = (time.perf_counter() - t0) * 1e3
            relit.render(turned(scene, 7.0).lights)  # warm-up
            times: dict[str, list[float]] = {"march": [], "relit": []}
            stages: dict[str, list[dict[str, float]]] = {"march": [], "relit": []}
            diff = 0.0
            with Contention() as c:
                for r in range(args.repeats):
                    lit = turned(scene, 15.0 * (r + 1))  # a light change before every frame
                    layers = {}
                    for kind in ("march", "relit"):
                        t0 = time.perf_counter()
                        res = (render_pvrt(lit, transfer=transfer, progress=False) if kind == "march"
                               else relit.render(lit.lights))
                        times[kind].append((time.perf_counter() - t0) * 1e3)
                        stages[kind].append(res.timings_ms)
                        layers[kind] = res.layers
                    diff = max(diff, *(float(np.abs(layers["relit"][k] - layers["march"][k]).max()
                                             / max(float(np.abs(layers["march"][k]).max()), 1e-30))
                                       for k in ("L_d", "L_i")))
            row: dict[str, Any] = {"keep_ms": keep_ms, "kept_samples": relit.samples, "relit_max_rel_diff": diff,
                                   "other_cores": c.other_cores}
            for kind, prefix in (("march", ""), ("relit", "relit_")):
                mid = int(np.argsort(times[kind])[len(times[kind]) // 2])
                best = int(np.argmin(times[kind]))
                row.update({f"{prefix}median_ms": float(np.median(times[kind])), f"{prefix}ms": times[kind],
                            f"{prefix}stages_ms": stages[kind][mid], f"{prefix}best_stages_ms": stages[kind][best]})
                split = ", ".join(f"{k} {v:.0f}" for k, v in sorted(stages[kind][mid].items(), key=lambda kv: -kv[1])
                                  if k != "total")
                what = "march" if kind == "march" else "relit (kept samples)"
                print(f"  frame {size}x{size} after a light change, {what}: {np.median(times[kind]):.0f} ms, best "
                      f"{min(times[kind]):.0f} ({split})", flush=True)
            print(f"  kept {relit.samples} camera samples in {keep_ms:.0f} ms; relit vs march: max rel. diff "
                  f"{diff:.1e}", flush=True)
            frames[f"{size}x{size}"] = row
        accuracy = []
        print(f"  {'light':>8s} {'L_d ratio':>9s} {'L_i ratio':>9s} {'L ratio':>8s} {'rel. L2 L':>9s} "
              f"{'ref noise':>9s}")
        for i in range(args.dirs + 1):
            deg = 120.0 * i
            scene = turned(base, deg).with_overrides(width=args.ref_size, height=args.ref_size)
            refs = [reference(scene, args.ref_spp, seed, args.work, f"{args.resolution}_{deg:.0f}") for seed in (1, 2)]
            got = render_pvrt(scene, transfer=transfer, progress=False).layers
            row = {"turn_degrees": deg, "direction": [float(x) for x in scene.lights[0].direction],
                   **{f"{k}_ratio": float(got[k].mean() / refs[0][k].mean()) for k in ("L_d", "L_i", "L")},
                   "rel_l2_L": float(relative_l2(got["L"], refs[0]["L"])),
                   "rel_l2_L_i": float(relative_l2(got["L_i"], refs[0]["L_i"])),
                   "ref_noise_rel_l2_L": float(relative_l2(refs[1]["L"], refs[0]["L"]) / math.sqrt(2)),
                   "ref_noise_rel_l2_L_i": float(relative_l2(refs[1]["L_i"], refs[0]["L_i"]) / math.sqrt(2))}
            accuracy.append(row)
            print(f"  {deg:7.0f}d {row['L_d_ratio']:9.3f} {row['L_i_ratio']:9.3f} {row['L_ratio']:8.3f} "
                  f"{row['rel_l2_L']:9.3f} {row['ref_noise_rel_l2_L']:9.3f}", flush=True)
        results[name] = {"precompute": pre, "frames": frames, "accuracy": accuracy}
    info = finish_info(info, {})
    write_report(args.out, "pvrt", info, {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                 results=results)


if __name__ == "__main__":
    main()
