"""Flicker across a sequence of small edits: chained warm-started updates against cold retrains (issue 16).

A scientist tuning a transfer function makes many small edits in a row. After each, the viewer swaps in a new
field; how much the image jumps between consecutive fields, beyond what the edit itself changes, is the flicker
the user sees. Issue 16's goal: lower with warm-started updates than with cold retrains.

Per scene (default: blobs), ``--steps`` edits (default 10) of the densest feature's opacity (control points at
s >= 0.6, as :func:`bench_update.opacity_feature`), each multiplying it by ``--factor`` (default 0.93: ten steps end
near the single x0.5 edit of ``bench_update.py``). Three sequences of fields and images, all at the scene's camera
and g, ``--size`` square, ``--spp`` samples with one fixed render seed (consecutive images share their random
streams, so the render's own noise changes little between them):

- ``update``: a chain of :func:`photon_fields.train.fit.update.update_run` calls, edit k warm-started from edit
  k - 1's run (the first from the base run), each at the CLI's default budget: what the viewer does;
- ``cold``: trace + fit + export from scratch for every edit, with the same seed (``bench_update.cold_run``);
- ``map``: the cold runs' photon maps rendered directly (kernel in g, the cold fit's final radius): the change the
  training targets themselves make, their correlated noise included (the same seed traces the same paths).

Flicker of a sequence = mean over k of mean |I_k - I_(k-1)| / mean I_k (issue 14's measure), for the neural
L_i images; with ``--ref-spp`` > 0 also for the path tracer's L_i (the change the edits really make, plus its
noise). Each field's relative L2 against its own edit's photon-map image (the cold map) shows whether the chain
drifts. Output: a table per scene and JSON (default ``bench/results/update_flicker.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import copy
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_fidelity import compare, reference_li  # noqa: E402
from bench_update import DEFAULT_WORK, cold_run, field_li  # noqa: E402
from common import finish_info, load_average, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.models_spec import DEFAULT_PHOTONS, PHASE_WINDOW  # noqa: E402
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene, scene_from_dict  # noqa: E402
from photon_fields.train.fit.presets import UPDATE_BUDGET_S  # noqa: E402
from photon_fields.train.fit.settings import FitSettings  # noqa: E402
from photon_fields.train.fit.update import update_run  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "update_flicker.json"
#: The feature whose opacity the edits scale: the densest one (bench_update.opacity_feature's).
FEATURE_S = 0.6


def opacity_step(scene: Scene, factor: float, k: int) -> Scene:
    """``scene`` with the densest feature's opacity times ``factor ** k``."""
    spec = copy.deepcopy(scene.spec())
    for p in spec["transfer_function"]["points"]:
        if p["s"] >= FEATURE_S:
            p["opacity"] *= factor ** k
    spec["name"] = f"{scene.name}-opacity{k:02d}"
    return scene_from_dict(spec)


def flicker(images: list[np.ndarray]) -> list[float]:
    """mean |I_k - I_(k-1)| / mean I_k for k = 1 .. len - 1."""
    pairs = zip(images[:-1], images[1:], strict=True)
    return [float(np.abs(b - a).mean() / max(float(b.mean()), 1e-30)) for a, b in pairs]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["blobs"], help="builtin scenes")
    ap.add_argument("--steps", type=int, default=10, help="edits in the sequence")
    ap.add_argument("--factor", type=float, default=0.93, help="opacity factor per edit")
    ap.add_argument("--photons", type=int, default=DEFAULT_PHOTONS, help="photons of the base and cold maps")
    ap.add_argument("--budget", type=float, default=UPDATE_BUDGET_S, help="each update's --budget, seconds")
    ap.add_argument("--size", type=int, default=96, help="L_i image size")
    ap.add_argument("--spp", type=int, default=32, help="field and photon-map samples per pixel")
    ap.add_argument("--ref-spp", type=int, default=0, help="path-traced L_i spp per edit (0: none)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK, help="runs, reused when finished (cold and base)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    if args.steps < 2 or not 0.0 < args.factor < 1.0:
        raise SystemExit("--steps must be >= 2 and --factor in (0, 1)")
    info = machine_info()
    results: dict[str, Any] = {}
    settings = FitSettings.from_preset("cpu", seed=args.seed)
    for name in parse_scenes(args.scenes):
        base_scene = builtin_scene(name)
        work = args.work / name
        scenes = [opacity_step(base_scene, args.factor, k) for k in range(args.steps + 1)]
        images: dict[str, list[np.ndarray]] = {"update": [], "cold": [], "map": []}
        if args.ref_spp:
            images["path tracer"] = []
        per_edit: list[dict[str, Any]] = []
        previous = work / "base"
        cold_run(base_scene, previous, args.photons, args.seed, reuse=True)
        for k, scene in enumerate(scenes):
            cold_folder = previous if k == 0 else work / f"flicker-cold-{k:02d}"
            pmap, cold = cold_run(scene, cold_folder, args.photons, args.seed, reuse=True)
            entry: dict[str, Any] = {"edit": k, "opacity_factor": args.factor ** k, "cold_s": cold["wall_s"]}
            if k == 0:
                run = previous
            else:
                load = load_average()
                t0 = time.perf_counter()
                res = update_run(previous, scene, work / f"flicker-update-{k:02d}", budget_s=args.budget,
                                 force=True, progress=False)
                entry["update"] = {"wall_s": time.perf_counter() - t0, "steps": res.fit.log["stop"]["steps"],
                                   "stop": res.fit.log["stop"]["reason"], "load_before": load}
                run = previous = res.out
            view = scene.with_overrides(width=args.size, height=args.size)
            radius = settings.resolve_schedule(len(pmap)).final_radius
            ref_map = render_photon_mapped(view, pmap, k=settings.k, radius=radius, spp=args.spp, seed=7,
                                           progress=False, g_window=PHASE_WINDOW, camera="forced",
                                           final_gather_after=None).layers["L_i"]
            upd, cold_li = field_li(scene, run, args.size, args.spp), field_li(scene, cold_folder, args.size, args.spp)
            images["update"].append(upd)
            images["cold"].append(cold_li)
            images["map"].append(ref_map)
            entry["update_vs_map"], entry["cold_vs_map"] = compare(upd, ref_map), compare(cold_li, ref_map)
            if args.ref_spp:
                images["path tracer"].append(reference_li(scene, scene.g, args.size, args.ref_spp, work))
            per_edit.append(entry)
            upd_note = "" if k == 0 else (f"update {entry['update']['wall_s']:5.1f} s, {entry['update']['steps']:3d} "
                                          f"steps ({entry['update']['stop']}), ")
            print(f"{name} edit {k:2d} (opacity x{args.factor ** k:.3f}): {upd_note}rel. L2 vs map: update "
                  f"{entry['update_vs_map']['rel_l2']:.3f}, cold {entry['cold_vs_map']['rel_l2']:.3f}", flush=True)
        seq = {kind: flicker(imgs) for kind, imgs in images.items()}
        summary = {kind: float(np.mean(v)) for kind, v in seq.items()}
        results[name] = {"edits": per_edit, "flicker_per_edit": seq, "flicker": summary,
                         "flicker_ratio_update_over_cold": summary["update"] / summary["cold"]}
        print(f"{name}: flicker (mean |I_k - I_k-1| / mean I_k) "
              + ", ".join(f"{kind} {value:.4f}" for kind, value in summary.items())
              + f"; update / cold {results[name]['flicker_ratio_update_over_cold']:.2f}", flush=True)
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    write_report(args.out, "update_flicker", finish_info(info, results), config, results=results)


if __name__ == "__main__":
    main()
