"""Training configurations: wall time (trace + fit) against image quality; the data behind the cpu preset.

For each scene (default: vortex, blobs) one 1M-photon training map (seed 0) and one reference map at
g = -0.35 / 0.35 (seed 1, same photons per phase) are traced and cached in ``--work`` (default
``bench/results/training/<scene>/``). Each configuration is a preset plus overrides (:data:`CONFIGS`);
it is trained into ``<work>/<scene>/<config>/`` (checkpoint, log.json, loss.png) and judged by
:func:`train.eval.field_images.evaluate_field`: relative L2 and SSIM of the field's L_i against the photon-map
renderer's L_i on two held-out views, for g in G = {-0.75, 0, 0.75} and for g = +-0.35 (not in G).

Reported per configuration: trace seconds (the map's), fit wall seconds, their sum, final training loss,
validation loss / relative L1 (held-out points, from the fit log), the image errors, and whether it is on
the Pareto front of (trace + fit seconds, relative L2 in G). Independent-map scores (g in G against a
second map, seed 1) are the like-for-like partner of the outside-G scores (:mod:`train.eval.field_images`).
Staggered vs naive: the ``cpu-staggered`` row against ``cpu`` (same everything but the schedule), plus
the wall time at which the naive run first reached the staggered run's final validation loss.

``paper`` (Sec. 3.4/3.5 exactly: ~1 s per step here, ~1 h) is not in the default list: pass it with
``--configs``; ``--reuse`` (default on) evaluates an existing finished run instead of training again, so
a long run can be made once (``pfn-train fit ... --preset paper --out <work>/<scene>/paper``) and scored
by every later sweep.

Output: a table on stdout and JSON (default ``bench/results/training.json``). Figures vary with load: the
report records the foreign load during each fit.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # see train.cli.train: torch and numba pools share 2 cores

from common import Contention, finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.models_spec.hashgrid import HashGridConfig  # noqa: E402
from photon_fields.runtime.photons.photon_map import PhotonMap  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402
from photon_fields.train.eval.field_images import OUTSIDE_G, evaluate_field, reference_maps  # noqa: E402
from photon_fields.train.fit.checkpoint import finished_run, load_checkpoint  # noqa: E402
from photon_fields.train.fit.loop import fit  # noqa: E402
from photon_fields.train.fit.presets import PRESETS, Preset  # noqa: E402
from photon_fields.train.fit.settings import FitSettings  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "training.json"
DEFAULT_WORK = HERE / "results" / "training"

# Architectures beyond the shipped presets, registered for the sweep only.
SWEEP_PRESETS: dict[str, Preset] = {
    # v0 of the cpu preset: 8 x 2 position features (2^15 rows), 4 x 2 direction levels, 2 hidden layers.
    "sweep-small": Preset(HashGridConfig(3, 8, 2, 15, 16, 1.5), HashGridConfig(2, 4, 2, 12, 4, 2.0), 64, 2,
                          steps=800, batch=1 << 12, lr=1e-2, schedule="naive", sampling="support"),
    # Finer and wider position grid (12 levels x 4 features, 2^18 rows), 4 hidden layers as the paper.
    "sweep-large": Preset(HashGridConfig(3, 12, 4, 18, 16, 1.5), HashGridConfig(2, 8, 2, 15, 4, 1.6), 64, 4,
                          steps=800, batch=1 << 12, lr=1e-2, schedule="naive", sampling="support"),
}

# name -> (preset, FitSettings overrides)
CONFIGS: dict[str, tuple[str, dict[str, Any]]] = {
    "cpu": ("cpu", {}),
    "cpu-staggered": ("cpu", {"schedule_kind": "staggered"}),
    "cpu-box": ("cpu", {"sampling": "box"}),
    "cpu-400": ("cpu", {"steps": 400}),
    "cpu-1600": ("cpu", {"steps": 1600}),
    "cpu-b14": ("cpu", {"batch": 1 << 14, "steps": 400}),
    "cpu-k256": ("cpu", {"k": 256}),
    "small": ("sweep-small", {}),
    "large": ("sweep-large", {}),
    "tiny": ("tiny", {}),
    "paper": ("paper", {}),
}
DEFAULT_CONFIGS = ["cpu", "cpu-staggered", "cpu-box", "cpu-400", "cpu-1600", "cpu-b14", "cpu-k256", "small",
                   "large", "tiny"]


def cached_map(path: Path, make: Any) -> PhotonMap:
    if path.exists():
        return PhotonMap.load(path)
    pmap = make()
    pmap.save(path)
    return pmap


def settings_for(config: str) -> FitSettings:
    preset, overrides = CONFIGS[config]
    return FitSettings.from_preset(preset, **overrides)


def time_to_reach(log: dict[str, Any], target: float) -> float | None:
    """Wall seconds at which a run's validation loss first dropped to ``target`` (None if never)."""
    wall = log["per_step"]["wall_s"]
    for v in log["validation"]:
        if v["val_loss"] <= target:
            return float(wall[min(v["step"], len(wall)) - 1])
    return None


def run_config(scene: Scene, pmap: PhotonMap, ref_map: PhotonMap, config: str, work: Path, reuse: bool,
               size: int, spp: int, cache: dict[Any, Any]) -> dict[str, Any]:
    settings = settings_for(config)
    run = work / config
    log = finished_run(run, settings) if reuse else None
    other = None
    if log is None:
        with Contention() as c:
            result = fit(scene, pmap, run, settings, progress=sys.stderr.isatty())
        log, other = result.log, c.other_cores
    model, _ = load_checkpoint(run / "checkpoint.pt", expected_fingerprint=scene.fingerprint())
    gs = tuple(pmap.phases) + OUTSIDE_G
    radius = log["schedule"]["stages"][-1]["radius_percent"] / 100.0
    quality = evaluate_field(scene, model, [pmap, ref_map], gs, size=size, spp=spp, k=settings.k, radius=radius,
                             cache=cache, independent=ref_map)
    t = log["totals"]
    val = t.get("final_validation") or {}
    trace_s = float(pmap.metadata()["trace_seconds"])
    return {"preset": settings.preset, "settings": settings.to_dict(), "reused": other is None and reuse,
            "other_cores": other, "trace_s": trace_s, "fit_s": t["wall_s"], "total_s": trace_s + t["wall_s"],
            "targets_s_per_step": t["targets_s_per_step"], "train_s_per_step": t["train_s_per_step"],
            "final_loss": t["final_loss"], "val_loss": val.get("val_loss"), "val_rel_l1": val.get("val_rel_l1"),
            "parameters": log["parameters"], "quality": quality, "_log": log}


def pareto(rows: dict[str, dict[str, Any]]) -> list[str]:
    """Configurations not beaten in both trace + fit time and relative L2 (in G) by another one."""
    front = []
    for name, r in rows.items():
        t, e = r["total_s"], r["quality"]["rel_l2_in_G"]
        others = [(o["total_s"], o["quality"]["rel_l2_in_G"]) for o in rows.values()]
        if not any(ot <= t and oe <= e and (ot, oe) != (t, e) for ot, oe in others):
            front.append(name)
    return sorted(front, key=lambda n: rows[n]["total_s"])


def bench_scene(name: str, configs: list[str], args: argparse.Namespace) -> dict[str, Any]:
    scene = builtin_scene(name)
    work = Path(args.work) / name
    work.mkdir(parents=True, exist_ok=True)
    pmap = cached_map(work / "map_1M_s0.npz", lambda: trace_photons(scene, 1_000_000, seed=0, progress=False))
    # Independent noise at G and +-0.35, the training map's photons per phase (photon_fields.train.eval.field_images).
    ref_map = cached_map(work / "map_1M_indep_s1.npz",
                         lambda: reference_maps(scene, pmap, tuple(pmap.phases) + OUTSIDE_G))
    cache: dict[Any, Any] = {}
    rows: dict[str, dict[str, Any]] = {}
    for config in configs:
        t0 = time.perf_counter()
        rows[config] = run_config(scene, pmap, ref_map, config, work, args.reuse, args.size, args.spp, cache)
        q = rows[config]["quality"]
        print(f"{name:7s} {config:14s} trace+fit {rows[config]['total_s']:7.1f} s  val relL1 "
              f"{rows[config]['val_rel_l1'] or float('nan'):.3f}  L_i relL2 G {q['rel_l2_in_G']:.3f} "
              f"(+-0.35: {q['rel_l2_outside_G']:.3f})  SSIM G {q['ssim_in_G']:.3f} (+-0.35: {q['ssim_outside_G']:.3f})"
              f"  [{time.perf_counter() - t0:.0f} s]", flush=True)
    out: dict[str, Any] = {"photons": len(pmap), "configs": {}, "pareto": pareto(rows)}
    if "paper" in rows:
        e = rows["paper"]["quality"]["rel_l2_in_G"]
        for r in rows.values():
            r["rel_l2_vs_paper"] = r["quality"]["rel_l2_in_G"] / e if e > 0 else None
    if "cpu" in rows and "cpu-staggered" in rows:
        naive, stag = rows["cpu"], rows["cpu-staggered"]
        out["staggered_vs_naive"] = {
            "naive": {"fit_s": naive["fit_s"], "final_loss": naive["final_loss"], "val_loss": naive["val_loss"],
                      "rel_l2_in_G": naive["quality"]["rel_l2_in_G"]},
            "staggered": {"fit_s": stag["fit_s"], "final_loss": stag["final_loss"], "val_loss": stag["val_loss"],
                          "rel_l2_in_G": stag["quality"]["rel_l2_in_G"]},
            "naive_s_to_staggered_final_val": time_to_reach(naive["_log"], stag["val_loss"]),
        }
    for k, r in rows.items():
        r.pop("_log")
        out["configs"][k] = r
    return out


def print_table(results: dict[str, Any]) -> None:
    print(f"\n{'scene':7s} {'config':14s} {'trace s':>8s} {'fit s':>7s} {'total':>7s} {'val L1':>7s} "
          f"{'relL2 G':>8s} {'SSIM G':>7s} {'G indep':>8s} {'relL2 out':>9s} {'SSIM out':>8s} {'vs paper':>8s}  pareto")
    for name, res in results.items():
        for k, r in res["configs"].items():
            q = r["quality"]
            vp = r.get("rel_l2_vs_paper")
            print(f"{name:7s} {k:14s} {r['trace_s']:8.1f} {r['fit_s']:7.1f} {r['total_s']:7.1f} "
                  f"{r['val_rel_l1'] or float('nan'):7.3f} {q['rel_l2_in_G']:8.3f} {q['ssim_in_G']:7.3f} "
                  f"{q.get('rel_l2_in_G_independent') or float('nan'):8.3f} "
                  f"{q['rel_l2_outside_G']:9.3f} {q['ssim_outside_G']:8.3f} "
                  f"{(f'{vp:.2f}x' if vp else '-'):>8s}  {'*' if k in res['pareto'] else ''}")
        if "staggered_vs_naive" in res:
            s = res["staggered_vs_naive"]
            reach = s["naive_s_to_staggered_final_val"]
            print(f"  staggered vs naive: naive {s['naive']['fit_s']:.0f} s, val loss {s['naive']['val_loss']:.4g}; "
                  f"staggered {s['staggered']['fit_s']:.0f} s, val loss {s['staggered']['val_loss']:.4g}; naive "
                  f"reached the staggered final val loss after {reach or float('nan'):.0f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["vortex", "blobs"],
                    help="builtin scenes (comma or space separated)")
    ap.add_argument("--configs", default=",".join(DEFAULT_CONFIGS),
                    help=f"comma-separated, from: {', '.join(CONFIGS)}")
    ap.add_argument("--reuse", action=argparse.BooleanOptionalAction, default=True,
                    help="score an existing finished run with the same settings instead of training again")
    ap.add_argument("--size", type=int, default=128, help="held-out view size (pixels, square)")
    ap.add_argument("--spp", type=int, default=2, help="samples per pixel of the evaluation renders")
    ap.add_argument("--work", default=str(DEFAULT_WORK), help="maps and run folders")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    args = ap.parse_args()
    configs = [c for c in args.configs.split(",") if c]
    unknown = [c for c in configs if c not in CONFIGS]
    if unknown:
        raise SystemExit(f"unknown config(s) {unknown}; available: {', '.join(CONFIGS)}")
    PRESETS.update(SWEEP_PRESETS)
    info = machine_info()
    results = {name: bench_scene(name, configs, args) for name in parse_scenes(args.scenes)}
    print_table(results)
    info = finish_info(info, {f"{s}/{c}": r for s, res in results.items() for c, r in res["configs"].items()})
    write_report(Path(args.out), "training", info, {"configs": {c: CONFIGS[c] for c in configs}, "size": args.size,
                                                     "spp": args.spp, "sweep_presets": list(SWEEP_PRESETS)},
                 results=results)


if __name__ == "__main__":
    main()
