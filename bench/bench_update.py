"""Updates: a warm-started ``pfn-train update`` against a cold ``pfn-train all`` after an edit (issue 16).

For each scene (default: vortex) a base run is made as ``pfn-train all`` makes it (default preset, ``--photons``,
``--seed``; kept in ``--work`` and reused; or ``--bases DIR`` names existing run folders ``DIR/<scene>``, only
read). Then for each edit (:data:`EDITS`: one feature's opacity x0.5, the
density scale x1.5, an albedo colour change, the first light moved by 10 / 45 / 90 degrees about the vertical
axis, the first light's power x1.5 or its colour changed) the edited scene is trained twice, each timed end to end
(trace, training, export):

- ``update``: :func:`photon_fields.train.fit.update.update_run` from the base run (``--budget``,
  ``--max-steps``, ``--update-photons``, each by default the CLI's; retrace with the base map's seed, warm start,
  early stop); its time split by stage (``UpdateResult.time_split``) and the load average around it are recorded;
  for a power or colour edit (:data:`RESCALE_EDITS`) where the runtime takes it as a rescale of L_i (one light:
  ``photon_fields.runtime.scene.light_rescale``), no training: the base bundle loaded for the edited scene, its
  L_i times the factor, the load's time as the update's (``stop`` "rescale"); ``mean_over_cold_field`` is the
  issue's measure there (L_i within 1 % of a retrained field's mean);
- ``cold``: trace + fit + export with the default preset from scratch (what ``pfn-train all`` does).

Both fields' L_i is scored as :mod:`bench_fidelity` scores it (its ``compare``: image mean ratio, relative L2,
SSIM) at the scene's g and camera, against the photon map's L_i of the edited scene (the map both were trained
on: the update's retrace and the cold trace use the same seed, so it is the same map; rendered with the kernel in
g and the cold fit's final radius, as the cold field's targets; the update retraces the same paths' first
records when it keeps fewer photons) and, with ``--ref-spp`` > 0, against the path tracer's. The
goal: the update in <= 15 s on 2 cores with an error <= 1.2x the cold field's.

Output: a table on stdout and JSON (default ``bench/results/update.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_fidelity import compare, reference_li  # noqa: E402
from common import finish_info, load_average, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.models_spec import DEFAULT_PHOTONS, PHASE_WINDOW  # noqa: E402
from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.photons.photon_map import PhotonMap  # noqa: E402
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene, scene_from_dict  # noqa: E402
from photon_fields.runtime.wavefront.first_interaction import render_first_interaction  # noqa: E402
from photon_fields.train.eval.field_images import TorchFieldEstimator  # noqa: E402
from photon_fields.train.export.bundle import export_bundle, write_run_domain  # noqa: E402
from photon_fields.train.fit.checkpoint import finished_run, load_checkpoint  # noqa: E402
from photon_fields.train.fit.early_stop import DEFAULT_MIN_IMPROVEMENT, DEFAULT_PATIENCE  # noqa: E402
from photon_fields.train.fit.loop import fit  # noqa: E402
from photon_fields.train.fit.presets import UPDATE_BUDGET_S, UPDATE_LR_SHARE, UPDATE_MAX_STEPS  # noqa: E402
from photon_fields.train.fit.settings import FitSettings  # noqa: E402
from photon_fields.train.fit.update import update_run  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "update.json"
DEFAULT_WORK = HERE / "results" / "update"


def _rotate_y(v: list[float], degrees: float) -> list[float]:
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    return [c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]]


def _points(spec: dict[str, Any]) -> list[dict[str, Any]]:
    return spec["transfer_function"]["points"]


def opacity_feature(spec: dict[str, Any]) -> None:
    """The densest feature (control points at s >= 0.6) at half its opacity."""
    for p in _points(spec):
        if p["s"] >= 0.6:
            p["opacity"] *= 0.5


def density_scale(spec: dict[str, Any]) -> None:
    spec["transfer_function"]["density_scale"] *= 1.5


def albedo_colour(spec: dict[str, Any]) -> None:
    """Red and blue albedo swapped at every control point."""
    for p in _points(spec):
        p["albedo"] = [p["albedo"][2], p["albedo"][1], p["albedo"][0]]


def light_moved(degrees: float) -> Callable[[dict[str, Any]], None]:
    def edit(spec: dict[str, Any]) -> None:
        light = spec["lights"][0]
        key = "direction" if "direction" in light else "position"
        light[key] = _rotate_y(light[key], degrees)
    return edit


def light_power(spec: dict[str, Any]) -> None:
    """The first light's power x1.5."""
    spec["lights"][0]["power"] *= 1.5


def light_colour(spec: dict[str, Any]) -> None:
    """The first light's colour made bluish."""
    spec["lights"][0]["color"] = [0.7, 0.9, 1.0]


def last_light_power(spec: dict[str, Any]) -> None:
    """The last light's power x2 and its colour made warmer (with several lights: one light's edit among them)."""
    spec["lights"][-1]["power"] *= 2.0
    spec["lights"][-1]["color"] = [1.0, 0.8, 0.6]


EDITS: dict[str, Callable[[dict[str, Any]], None]] = {
    "opacity": opacity_feature, "density": density_scale, "albedo": albedo_colour,
    "light10": light_moved(10), "light45": light_moved(45), "light90": light_moved(90),
    "power": light_power, "colour": light_colour, "last": last_light_power,
}
#: Edits a field may follow by a rescale of its L_i (``photon_fields.runtime.scene.light_rescale``): with one light
#: always, with several when the base field keeps the lights apart (``--lights apart``, the default since
#: 2026-11-26); otherwise the bench falls back to ``update_run``.
RESCALE_EDITS = ("power", "colour", "last")


def rescaled(base: Path, new: Scene) -> tuple[np.ndarray | None, float]:
    """The RGB factor the base run's bundle takes for ``new`` (None: not a rescale) and the load's seconds: the
    runtime's own check, as ``pfn-render`` and ``pfn-view`` load a bundle for an edited scene."""
    t0 = time.perf_counter()
    try:
        field = PhotonField.load(base / "field.pfn", expected_fingerprint=new.fingerprint(),
                                 expected_parts=new.fingerprint_parts(), expected_lights=new.light_identities())
    except InputError:
        return None, time.perf_counter() - t0
    return field.light_scale, time.perf_counter() - t0


def edited(scene: Scene, edit: str) -> Scene:
    spec = copy.deepcopy(scene.spec())
    EDITS[edit](spec)
    spec["name"] = f"{scene.name}-{edit}"
    return scene_from_dict(spec)


def cold_run(scene: Scene, run: Path, photons: int, seed: int, reuse: bool) -> tuple[PhotonMap, dict[str, Any]]:
    """``pfn-train all`` in-process (trace, fit, export into ``run``), timed; reused when ``reuse`` and finished."""
    settings = FitSettings.from_preset("cpu", seed=seed)
    if reuse and finished_run(run, settings) is not None and (run / "map.npz").is_file() \
            and (run / "timing.txt").is_file():
        return PhotonMap.load(run / "map.npz"), {"wall_s": float((run / "timing.txt").read_text()), "reused": True}
    t0 = time.perf_counter()
    pmap = trace_photons(scene, photons, seed=seed, progress=False)
    run.mkdir(parents=True, exist_ok=True)
    pmap.save(run / "map.npz")
    write_run_domain(run, scene, None)
    result = fit(scene, pmap, run, settings, progress=False)
    export_bundle(run, run / "field.pfn", force=True)
    wall = time.perf_counter() - t0
    (run / "timing.txt").write_text(f"{wall}\n")
    return pmap, {"wall_s": wall, "reused": False, "steps": result.log["totals"]["steps_done"],
                  "val_rel_l1": result.log["totals"]["final_validation"]["val_rel_l1"]}


def field_li(scene: Scene, run: Path, size: int, spp: int, trained_for: Scene | None = None,
             light_scale: np.ndarray | None = None) -> np.ndarray:
    """The L_i image of ``run``'s field in ``scene``'s view (``trained_for``: the scene the run was trained for, when
    that is not ``scene``; ``light_scale``: its rescale for ``scene``, RGB or one per light)."""
    model, _ = load_checkpoint(run / "checkpoint.pt", (trained_for or scene).fingerprint())
    view = scene.with_overrides(width=size, height=size)
    return render_first_interaction(view, TorchFieldEstimator(model, scene.medium(), light_scale=light_scale),
                                    spp=spp, seed=7, progress=False).layers["L_i"]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["vortex"], help="builtin scenes")
    ap.add_argument("--edits", nargs="*", default=list(EDITS), help=f"of {list(EDITS)}")
    ap.add_argument("--photons", type=int, default=DEFAULT_PHOTONS, help="photons of the base and cold maps")
    ap.add_argument("--budget", type=float, default=UPDATE_BUDGET_S, help="the update's --budget, seconds")
    ap.add_argument("--max-steps", type=int, default=UPDATE_MAX_STEPS, help="the update's --max-steps")
    ap.add_argument("--patience", type=int, default=DEFAULT_PATIENCE,
                    help="validations without an improvement before the update stops (PlateauStop)")
    ap.add_argument("--min-improvement", type=float, default=DEFAULT_MIN_IMPROVEMENT,
                    help="the relative improvement of the validation error that counts (PlateauStop)")
    ap.add_argument("--lr-share", type=float, default=UPDATE_LR_SHARE,
                    help="the update's learning rate as a share of the preset's (UPDATE_LR_SHARE)")
    ap.add_argument("--update-photons", type=int, default=None,
                    help="the update's --photons (default: the CLI's, the base map's count capped at UPDATE_PHOTONS)")
    ap.add_argument("--bases", type=Path, default=None,
                    help="folder of finished base runs <scene>/ (default preset, --seed, --photons), only read")
    ap.add_argument("--size", type=int, default=64, help="L_i image size")
    ap.add_argument("--spp", type=int, default=16, help="field and photon-map samples per pixel")
    ap.add_argument("--ref-spp", type=int, default=0, help="path-traced reference L_i spp (0: photon map only)")
    ap.add_argument("--no-reweight", action="store_true",
                    help="retrace for an albedo edit too (the update reweights RUN's map by default)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fresh", action="store_true", help="retrain cold runs even if --work holds them")
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    unknown = [e for e in args.edits if e not in EDITS]
    if unknown:
        raise SystemExit(f"unknown edit(s) {unknown}; available: {', '.join(EDITS)}")
    info = machine_info()
    results: dict[str, Any] = {}
    print(f"{'scene/edit':<18} {'update s':>8} {'retrace':>7} {'setup':>5} {'steps':>5} {'stop':>9} {'load':>4} "
          f"{'cold s':>7} {'upd/map L2':>10} {'cold/map L2':>11} {'ratio':>6} {'mean/cold':>9}"
          + ("  upd/PT L2 cold/PT L2" if args.ref_spp else ""), flush=True)
    for name in parse_scenes(args.scenes):
        scene = builtin_scene(name)
        base = args.work / name / "base"
        if args.bases is not None:
            base = args.bases / name
            log = finished_run(base, FitSettings.from_preset("cpu", seed=args.seed))
            if log is None or not (base / "map.npz").is_file() or abs(log["photons"] / args.photons - 1) > 0.01:
                raise SystemExit(f"{base}: not a finished base run (default preset, seed {args.seed}, "
                                 f"{args.photons} photons, map.npz)")
        else:
            cold_run(scene, base, args.photons, args.seed, reuse=True)
        for edit in args.edits:
            new = edited(scene, edit)
            folder = args.work / name / edit
            load_before = load_average()
            scale, load_s = rescaled(base, new) if edit in RESCALE_EDITS else (None, 0.0)
            t0 = time.perf_counter()
            res = None
            if scale is None:
                res = update_run(base, new, folder / "update", budget_s=args.budget, max_steps=args.max_steps,
                                 photons=args.update_photons, force=True, progress=False, patience=args.patience,
                                 min_improvement=args.min_improvement, lr_share=args.lr_share,
                                 reweight=not args.no_reweight)
            update_s = load_s + time.perf_counter() - t0
            load_after = load_average()
            pmap, cold = cold_run(new, folder / "cold", args.photons, args.seed, reuse=not args.fresh)
            view = new.with_overrides(width=args.size, height=args.size)
            cold_settings = FitSettings.from_preset("cpu", seed=args.seed)
            radius = cold_settings.resolve_schedule(len(pmap)).final_radius
            ref_map = render_photon_mapped(view, pmap, k=cold_settings.k, radius=radius, spp=args.spp, seed=7,
                                           progress=False, g_window=PHASE_WINDOW, camera="forced",
                                           final_gather_after=None).layers["L_i"]
            # A rescale renders the base field for the edited scene (its camera interactions) times the factor.
            upd_li = field_li(new, res.out, args.size, args.spp) if res is not None else \
                field_li(new, base, args.size, args.spp, trained_for=scene, light_scale=scale)
            cold_li = field_li(new, folder / "cold", args.size, args.spp)
            if res is not None:
                stop = res.fit.log["stop"]
                update: dict[str, Any] = {
                    "wall_s": update_s, "trace_s": res.trace_s, "export_s": res.bundle.seconds,
                    "photons": res.fit.log["photons"], "map_from": res.map_from, "time_split": res.time_split,
                    "steps": stop["steps"],
                    "stop": stop["reason"], "kept_step": stop["kept_step"], "validation": res.fit.log["validation"]}
                split = res.time_split
            else:
                stop = {"steps": 0, "reason": "rescale"}
                update = {"wall_s": update_s, "rescale": scale.tolist(), "steps": 0, "stop": "rescale"}
                split = {"trace_s": 0.0, "setup_s": load_s}
            update.update({"load_before": load_before, "load_after": load_after, "vs_map": compare(upd_li, ref_map),
                           "mean_over_cold_field": float(upd_li.mean() / max(cold_li.mean(), 1e-30))})
            entry: dict[str, Any] = {"update": update, "cold": {**cold, "vs_map": compare(cold_li, ref_map)}}
            entry["ratio_vs_map"] = entry["update"]["vs_map"]["rel_l2"] / entry["cold"]["vs_map"]["rel_l2"]
            load = max(x[0] for x in (load_before, load_after) if x) if load_before else float("nan")
            line = (f"{name + '/' + edit:<18} {update_s:8.1f} {split['trace_s']:7.1f} {split['setup_s']:5.1f} "
                    f"{stop['steps']:5d} {stop['reason']:>9} {load:4.1f} {cold['wall_s']:7.1f} "
                    f"{entry['update']['vs_map']['rel_l2']:10.3f} "
                    f"{entry['cold']['vs_map']['rel_l2']:11.3f} {entry['ratio_vs_map']:6.2f} "
                    f"{update['mean_over_cold_field']:9.3f}")
            if args.ref_spp:
                ref = reference_li(new, new.g, args.size, args.ref_spp, args.work)
                entry["update"]["vs_path_tracer"] = compare(upd_li, ref)
                entry["cold"]["vs_path_tracer"] = compare(cold_li, ref)
                entry["photon_map_vs_path_tracer"] = compare(ref_map, ref)
                line += (f"  {entry['update']['vs_path_tracer']['rel_l2']:9.3f} "
                         f"{entry['cold']['vs_path_tracer']['rel_l2']:10.3f}")
            results[f"{name}/{edit}"] = entry
            print(line, flush=True)
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    write_report(args.out, "update", finish_info(info, results), config, results=results)


if __name__ == "__main__":
    main()
