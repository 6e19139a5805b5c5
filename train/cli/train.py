"""``pfn-train``: photon tracing and photon-field fitting.

Examples::

    pfn-train trace vortex --photons 1M --out maps/vortex.npz
    pfn-train trace my_scene.json --photons 3M --phases -0.75 0 0.75 --seed 7 --out maps/mine.npz
    pfn-train fit my_scene.json --map maps/mine.npz --out runs/mine/ --preset cpu-phases   # a map of a few phases
    pfn-train fit vortex --map maps/vortex.npz --out runs/vortex/            # preset cpu
    pfn-train fit vortex --map maps/vortex.npz --out runs/paper/ --preset paper
    pfn-train all blobs --photons 1M --out runs/blobs/                       # trace + fit + export
    pfn-train export runs/vortex/ --out fields/vortex.pfn                    # the bundle for pfn-render
    pfn-train update runs/vortex/ --scene vortex_edited.json --out runs/vortex_edited/   # warm-started, <= 15 s
    pfn-train pvrt vortex --out vortex.pvrt                                  # PVRT transfer for relighting

``fit`` writes ``checkpoint.pt``, ``log.json``, ``loss.png`` and ``domain.json`` (the world box, for the
export) into the ``--out`` folder (see :mod:`photon_fields.train.fit.loop`). Options left out come from the preset
(``--preset``: cpu, cpu-phases, paper, tiny). A map traced with the default phases (narrow bins) trains any g
with the default preset; a map of a few phases needs ``--preset cpu-phases`` (or ``--g-sampling discrete``).
``export`` writes the runtime's bundle (:mod:`train.export.bundle`); ``all`` ends with it (``OUT/field.pfn``,
replaced if present). ``update`` makes the run folder of an edited scene (transfer function or lights; same
volume) from an earlier run's field in seconds: retrace with the same seed, warm-started training until the
validation error stops improving or ``--budget`` runs out, export (:mod:`photon_fields.train.fit.update`).
``pvrt`` precomputes a PVRT transfer (Zhang et al. 2013; :mod:`photon_fields.runtime.pvrt`) for
``pfn-render --method pvrt --transfer NAME.pvrt``: the precomputation itself lives in the runtime (no torch), the
subcommand in :mod:`photon_fields.train.cli.pvrt_command`. ``--progress-file`` (every long job) is
:mod:`photon_fields.train.cli.progress_option`.

Bad input exits with status 2 and one line on stderr: ``error: <input>: <problem>``.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from photon_fields.models_spec import DEFAULT_MAP_PHASES, DEFAULT_PHOTONS
from photon_fields.models_spec.photon_map import RECORD_FLOOR
from photon_fields.runtime.cli.common import (
    OneLineArgumentParser,
    check_seed,
    guarded,
    parse_count,
    prepare_output,
    process_started,
    refuse_to_replace,
)
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.progress import ProgressFile
from photon_fields.runtime.threads import set_threads
from photon_fields.train.cli.progress_option import (
    add_job_options,
    open_progress,
    record_failure,
    stage_callback,
)
from photon_fields.train.cli.pvrt_command import add_pvrt_parser, cmd_pvrt


def build_parser() -> argparse.ArgumentParser:
    p = OneLineArgumentParser(prog="pfn-train", description="Photon Field Networks: photon tracing and training.")
    sub = p.add_subparsers(dest="command", required=True)
    t = sub.add_parser("trace", help="multi-phase photon tracing (Alg. 1) into a photon map",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _add_trace_options(t)
    t.add_argument("--seed", type=int, default=0, help="random seed: same seed, same map")
    t.add_argument("--out", required=True, help="output photon map (.npz)")
    add_job_options(t, replaces="an existing photon map")

    f = sub.add_parser("fit", help="fit a photon field to a photon map (Sec. 3.5)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    f.add_argument("scene", help="builtin scene name or scene JSON file the map was traced for")
    f.add_argument("--map", required=True, help="photon map (.npz) from pfn-train trace")
    _add_fit_options(f)

    a = sub.add_parser("all", help="trace a photon map (saved as OUT/map.npz), then fit a field to it",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _add_trace_options(a)
    a.add_argument("--tables-dtype", choices=["float32", "float16"], default="float32",
                   help="hash-table precision in the exported bundle")
    _add_fit_options(a)

    e = sub.add_parser("export", help="export a run's checkpoint as a field bundle (NAME.pfn) for the runtime",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    e.add_argument("run", help="run folder of pfn-train fit (checkpoint.pt, domain.json)")
    e.add_argument("--out", default=None, help="bundle directory to write, NAME.pfn (default: RUN/field.pfn)")
    e.add_argument("--scene", default=None, help="the scene trained for (needed only when the run folder has no "
                                                 "domain.json)")
    e.add_argument("--tables-dtype", choices=["float32", "float16"], default="float32",
                   help="hash-table precision (float16: half the size, L' within ~1e-3)")
    e.add_argument("--force", action="store_true", help="replace an existing bundle")
    _add_update_parser(sub)
    add_pvrt_parser(sub)
    return p


def _add_update_parser(sub: argparse._SubParsersAction) -> None:
    from photon_fields.train.fit.presets import UPDATE_BUDGET_S, UPDATE_MAX_STEPS, UPDATE_PHOTONS

    u = sub.add_parser("update", help="an edited scene's run folder from an earlier run's field: retrace, "
                                      "warm-started training, export (seconds)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    u.add_argument("run", help="run folder of pfn-train all (or fit, or update) of the same volume; only read")
    u.add_argument("--scene", required=True, help="the edited scene (builtin name or scene JSON file): same volume, "
                                                  "another transfer function or lights")
    u.add_argument("--out", required=True, help="the new run folder (map.npz, checkpoint.pt, log.json, loss.png, "
                                                "domain.json, field.pfn)")
    u.add_argument("--budget", type=float, default=UPDATE_BUDGET_S,
                   help="wall seconds from the command's start to the written bundle (start-up, retrace, training, "
                        "export)")
    u.add_argument("--max-steps", type=int, default=UPDATE_MAX_STEPS, help="at most this many training steps")
    u.add_argument("--photons", default=None, help="records in the new map (default: the earlier map's count, at most "
                                                   f"{UPDATE_PHOTONS // 1_000_000}M)")
    u.add_argument("--seed", type=int, default=None,
                   help="random seed of the retrace and the training (default: the earlier map's, which makes the "
                        "new map correlated with it)")
    u.add_argument("--tables-dtype", choices=["float32", "float16"], default="float32",
                   help="hash-table precision in the exported bundle")
    add_job_options(u, replaces="the results of an earlier run in --out")


def _add_trace_options(t: argparse.ArgumentParser) -> None:
    """The scene and photon-tracing options of ``trace`` and ``all``."""
    t.add_argument("scene", help="builtin scene name (vortex, blobs, shell, head) or a scene JSON file")
    t.add_argument("--photons", default=f"{DEFAULT_PHOTONS // 1_000_000}M",
                   help="records to store, e.g. 1M, 250k")
    t.add_argument("--phases", type=float, nargs="+", default=None,
                   help="the phase set G (default: 39 narrow bins over [-0.95, 0.95], from which the cpu preset "
                        "trains any g in [-0.8, 0.8]; a few phases, e.g. -0.75 0 0.75, need --preset cpu-phases)")
    t.add_argument("--max-bounces", type=int, default=16, help="max collisions per photon path")
    t.add_argument("--record-floor", type=float, default=RECORD_FLOOR,
                   help="also record photons at null collisions, each tentative collision with probability at least "
                        f"this (bounds every photon's weight; 0: real collisions only; default {RECORD_FLOOR})")


def _add_fit_options(f: argparse.ArgumentParser) -> None:
    from photon_fields.train.fit.presets import PRESETS

    f.add_argument("--out", required=True, help="run folder (checkpoint.pt, log.json, loss.png)")
    f.add_argument("--preset", default="cpu", choices=sorted(PRESETS), help="architecture and default settings")
    f.add_argument("--steps", type=int, default=None, help="training steps (default: the preset's)")
    f.add_argument("--batch", type=int, default=None, help="samples per step (default: the preset's)")
    f.add_argument("--lr", type=float, default=None, help="Adam learning rate (default: the preset's)")
    f.add_argument("--k", type=int, default=None, help="photons per radiance estimate (K) (default: the preset's)")
    f.add_argument("--schedule", choices=["staggered", "naive"], default=None,
                   help="KNN radius schedule: Table 1 by photon count, or its final radius throughout "
                        "(default: the preset's)")
    f.add_argument("--sampling", choices=["box", "support", "visible"], default=None,
                   help="training positions: uniform in the box (paper), in the medium's support, or half of them "
                        "where cameras around the volume see it (default: the preset's)")
    f.add_argument("--loss", choices=["linear", "log"], default=None,
                   help="training loss: relative L2 of the decoded radiance (unbiased under noisy targets) or of the "
                        "log-encoded output (the paper's) (default: the preset's)")
    f.add_argument("--g-sampling", choices=["discrete", "continuous", "mixed", "window"], default=None,
                   help="training g: the map's phases (the paper), continuous between them, half of each, or any g "
                        "from a kernel in g over a map traced in narrow phase bins (default: the preset's)")
    f.add_argument("--average", type=float, default=None,
                   help="share of the last steps whose parameters are averaged into the final field, 0: the last "
                        "step's (default: the preset's)")
    f.add_argument("--lights", choices=["apart", "together"], default="apart",
                   help="with several lights: one output per light, so that a light's power or colour can be edited "
                        "without retraining (apart), or one output for all (together, the paper's)")
    f.add_argument("--checkpoint-every", type=int, default=500, help="save checkpoint.pt every N steps")
    f.add_argument("--seed", type=int, default=0, help="random seed: same seed, same field")
    add_job_options(f, replaces="the results of an earlier run in --out")


def cmd_trace(args: argparse.Namespace) -> int:
    from photon_fields.runtime.photons.photon_map import check_record_floor
    from photon_fields.runtime.scene.scene import load_scene
    from photon_fields.train.photons.tracing import check_phases, trace_photons

    out = Path(args.out)
    photons = parse_count(args.photons)
    phases = check_phases(args.phases if args.phases is not None else DEFAULT_MAP_PHASES, "--phases")
    check_record_floor(args.record_floor, "--record-floor")
    check_seed(args.seed)
    set_threads(args.threads)
    scene = load_scene(args.scene)
    prepare_output(out, ".npz", force=args.force, what="a photon map")
    progress = open_progress(args, ("trace",))
    pmap = trace_photons(scene, photons, phases=phases, max_bounces=args.max_bounces, seed=args.seed,
                         progress=not args.quiet, on_progress=stage_callback(progress, "trace"),
                         record_floor=args.record_floor)
    pmap.save(out)
    if progress is not None:
        progress.finish("done", f"photon map {out}")
    meta = pmap.metadata()
    secs = meta["trace_seconds"]
    print(f"traced {meta['stored']:,} photons ({meta['emitted']:,} paths) in {secs:.2f} s "
          f"({meta['stored'] / max(secs, 1e-9) / 1e6:.2f} M/s) -> {out}")
    print(json.dumps({"per_phase": meta["per_phase"], "phases": meta["phases"]}))
    return 0


def _fit_settings(args: argparse.Namespace):  # noqa: ANN202  (photon_fields.train.fit.loop is imported lazily)
    from photon_fields.train.fit.settings import FitSettings

    settings = FitSettings.from_preset(args.preset, steps=args.steps, batch=args.batch, lr=args.lr, k=args.k,
                                       schedule_kind=args.schedule, sampling=args.sampling, loss=args.loss,
                                       average=args.average, g_sampling=args.g_sampling,
                                       seed=args.seed, per_light=args.lights == "apart",
                                       checkpoint_every=args.checkpoint_every)
    settings.validate()
    check_seed(args.seed)
    return settings


#: What ``fit`` writes into a run folder, and what ``all`` adds (the map it traced and the bundle).
FIT_OUTPUTS = ("checkpoint.pt", "log.json", "loss.png", "domain.json")
ALL_OUTPUTS = (*FIT_OUTPUTS, "map.npz", "field.pfn")


def _prepare_run_folder(out: Path, force: bool, outputs: Sequence[str]) -> None:
    """Refuse (before any work) a file where the run folder goes, and a folder holding an earlier run's
    results unless ``force``; then create it."""
    if out.exists() and not out.is_dir():
        raise InputError("--out", f"{str(out)!r} is a file; --out names a run folder")
    refuse_to_replace([out / name for name in outputs], force, f"an earlier run in {str(out)!r}")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError("--out", f"cannot create the folder {str(out)!r}: {exc.strerror or exc}") from None


def _set_all_threads(threads: int | None) -> None:
    set_threads(threads)  # numba: KNN targets, hash grid, optimizer
    if threads is not None:
        import torch

        torch.set_num_threads(threads)  # the MLP


def _run_fit(args: argparse.Namespace, scene, pmap, settings,  # noqa: ANN001
             progress: ProgressFile | None = None) -> int:
    from photon_fields.train.export.bundle import write_run_domain
    from photon_fields.train.fit.loop import fit
    from photon_fields.train.fit.targets import check_map_for_sampling

    out = Path(args.out)
    check_map_for_sampling(pmap, settings.g_sampling)  # refuse before anything is written into the run folder
    write_run_domain(out, scene, args.scene)  # the world box the export needs (checkpoints do not hold it)
    if settings.per_light and len(scene.lights) > 1 and pmap.light is None:
        print(f"note: {pmap.path or 'the photon map'} does not record which light each photon came from (traced "
              "before 2026-11-26): the field gets one output for all lights, and a light's power or colour edit "
              "will need an update; re-trace it to keep the lights apart", file=sys.stderr)
    result = fit(scene, pmap, out, settings, progress=not args.quiet, on_progress=stage_callback(progress, "fit"))
    t = result.log["totals"]
    val = t["final_validation"] or {}
    beside = t["targets_background_s"] / max(t["steps_done"], 1)
    print(f"fitted {t['steps_done']} steps x {settings.batch} samples in {t['wall_s']:.1f} s (targets "
          f"{t['targets_s_per_step'] * 1e3:.0f} ms/step waited"
          + (f", {beside * 1e3:.0f} computed beside the training" if beside else "")
          + f", training {t['train_s_per_step'] * 1e3:.0f} ms/step, "
          f"{t['samples_per_s']:,.0f} samples/s); final loss {t['final_loss']:.4g}, validation loss "
          f"{val.get('val_loss', float('nan')):.4g}, relative L1 {val.get('val_rel_l1', float('nan')):.3f}"
          + (f", {result.model.cfg.light_channels} lights apart" if result.model.cfg.light_channels > 1 else "")
          + " -> " + ", ".join(str(p) for p in result.files))
    return 0


def cmd_fit(args: argparse.Namespace) -> int:
    from photon_fields.runtime.scene.scene import load_scene
    from photon_fields.train.fit.loop import load_map_for

    settings = _fit_settings(args)
    _set_all_threads(args.threads)
    scene = load_scene(args.scene)
    pmap, note = load_map_for(scene, args.map)
    if note is not None:
        print(f"note: {note}", file=sys.stderr)
    out = Path(args.out)
    _prepare_run_folder(out, args.force, (*FIT_OUTPUTS, "field.pfn"))
    if (out / "field.pfn").exists():
        print(f"note: {out / 'field.pfn'} is the earlier fit's bundle; re-export it with "
              f"pfn-train export {out} --force", file=sys.stderr)
    progress = open_progress(args, ("fit",))
    _run_fit(args, scene, pmap, settings, progress)
    if progress is not None:
        progress.finish("done", f"run folder {out}")
    return 0


def cmd_all(args: argparse.Namespace) -> int:
    from photon_fields.runtime.photons.photon_map import check_record_floor
    from photon_fields.runtime.scene.scene import load_scene
    from photon_fields.train.photons.tracing import check_phases, trace_photons

    photons = parse_count(args.photons)
    phases = check_phases(args.phases if args.phases is not None else DEFAULT_MAP_PHASES, "--phases")
    check_record_floor(args.record_floor, "--record-floor")
    settings = _fit_settings(args)
    _set_all_threads(args.threads)
    scene = load_scene(args.scene)
    out = Path(args.out)
    _prepare_run_folder(out, args.force, ALL_OUTPUTS)
    progress = open_progress(args, ("trace", "fit", "export"))
    pmap = trace_photons(scene, photons, phases=phases, max_bounces=args.max_bounces, seed=args.seed,
                         progress=not args.quiet, on_progress=stage_callback(progress, "trace"),
                         record_floor=args.record_floor)
    map_path = pmap.save(out / "map.npz")
    secs = pmap.metadata()["trace_seconds"]
    print(f"traced {len(pmap):,} photons in {secs:.2f} s -> {map_path}")
    _run_fit(args, scene, pmap, settings, progress)
    from photon_fields.train.export.bundle import export_bundle

    if progress is not None:
        progress.update("export", 0, 1)
    res = export_bundle(out, out / "field.pfn", tables_dtype=args.tables_dtype, force=True)
    _print_export(res)
    if progress is not None:
        progress.finish("done", f"bundle {res.path}")
    return 0


def _print_export(res) -> None:  # noqa: ANN001  (photon_fields.train.export.bundle is imported lazily)
    mb = sum(res.files.values()) / 1e6
    check = f", verified (max |dL'| {res.verify_max_abs_diff:.2g})" if res.verify_max_abs_diff is not None else ""
    print(f"exported {res.path} ({mb:.1f} MB, tables {res.manifest['tables']['dtype']}{check}) in {res.seconds:.1f} s")


def cmd_export(args: argparse.Namespace) -> int:
    from photon_fields.train.export.bundle import export_bundle

    scene = None
    if args.scene is not None:
        from photon_fields.runtime.scene.scene import load_scene

        scene = load_scene(args.scene)
    res = export_bundle(args.run, args.out, scene=scene, tables_dtype=args.tables_dtype, force=args.force)
    _print_export(res)
    return 0


def cmd_update(args: argparse.Namespace) -> int:
    from photon_fields.runtime.scene.scene import load_scene
    from photon_fields.train.fit.update import update_run

    photons = parse_count(args.photons) if args.photons is not None else None
    if args.seed is not None:
        check_seed(args.seed)
    _set_all_threads(args.threads)
    scene = load_scene(args.scene)
    from photon_fields.runtime.scene.light_rescale import format_scale
    from photon_fields.train.fit.update import read_run

    try:
        scale = read_run(args.run).light_rescale(scene)
    except InputError:  # update_run refuses RUN below, after its own checks and in their order
        scale = None
    if scale is not None:
        print(f"note: {args.scene} differs from {args.run} only in its lights' power or colour: the run's field "
              f"renders it exactly, rescaled by {format_scale(scale)} per RGB channel (pfn-render and pfn-view do "
              "that when given its bundle); updating anyway", file=sys.stderr)
    progress = open_progress(args, ("trace", "fit", "export"))

    def bundle_written(bundle: Any) -> None:  # before the loss plot: a waiting viewer swaps the field in now
        if progress is not None:
            progress.finish("done", f"bundle {bundle.path}")

    res = update_run(args.run, scene, args.out, budget_s=args.budget, max_steps=args.max_steps, seed=args.seed,
                     photons=photons, force=args.force, scene_source=args.scene, tables_dtype=args.tables_dtype,
                     progress=not args.quiet, on_progress=None if progress is None else progress.update,
                     started=_COMMAND_CLOCK["started"], on_bundle=bundle_written)
    log = res.fit.log
    val = log["totals"]["final_validation"] or {}
    first = log["validation"][0]["val_rel_l1"]
    made = "traced" if res.map_from == "retraced" else "the albedo edit reweighted RUN's map"
    print(f"updated {args.run} -> {res.out}: {made} in {res.trace_s:.1f} s, {log['stop']['steps']} steps "
          f"(stopped: {log['stop']['reason']}), validation relative L1 {first:.3f} -> "
          f"{val.get('val_rel_l1', float('nan')):.3f}, {res.wall_s:.1f} s in all")
    _print_export(res.bundle)
    print(f"time: {update_time_line(res.time_split)}")
    if log["stop"]["reason"] == "budget" and log["stop"]["kept_step"] == 0:
        print(f"note: the budget ran out before training improved the field (retrace {res.trace_s:.1f} s): "
              f"{res.out / 'field.pfn'} is the earlier field; pass a larger --budget or fewer --photons",
              file=sys.stderr)
    return 0


def update_time_line(t: dict[str, float]) -> str:
    """Where an update's wall time went (:attr:`photon_fields.train.fit.update.UpdateResult.time_split`), in one
    line: what used the budget when it runs out."""
    steps = t["targets_s"] + t["train_s"]
    return (f"start-up {t.get('startup_s', 0.0):.1f} s, read RUN {t['read_run_s']:.1f} s, "
            f"retrace {t['trace_s']:.1f} s, save map {t['save_map_s']:.1f} s, "
            f"search structures {t['index_build_s']:.1f} s, validation targets {t['validation_targets_s']:.1f} s, "
            f"steps {steps:.1f} s (waiting for targets {t['targets_s']:.1f} s), validations {t['validate_s']:.1f} s, "
            f"log {t['outputs_s']:.1f} s, export {t['export_s']:.1f} s; the bundle after {t['bundle_s']:.1f} s (budget "
            f"{t['budget_s']:g} s), loss plot {t['plot_s']:.1f} s, {t['wall_s']:.1f} s in all")


@guarded
def _main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    command = {"trace": cmd_trace, "fit": cmd_fit, "all": cmd_all, "export": cmd_export,
               "update": cmd_update, "pvrt": cmd_pvrt}[args.command]
    try:
        return command(args)
    except BaseException as exc:
        record_failure(args, exc)
        raise


#: Where ``update --budget`` counts from: :func:`main` (the console script and ``python -m``, a process of its own)
#: sets the process's start, so that the budget bounds the command's wall time, imports included (the viewer's
#: background retrain runs it so); in-process calls of ``_main`` (tests, pfn-demo) count from the call.
_COMMAND_CLOCK: dict[str, float | None] = {"started": None}


def main(argv: Sequence[str] | None = None) -> int:
    _COMMAND_CLOCK["started"] = process_started()
    sys.exit(_main(argv))


if __name__ == "__main__":  # python -m photon_fields.train.cli.train (how pfn-view starts a background retrain)
    main()
