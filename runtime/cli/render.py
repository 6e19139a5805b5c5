"""``pfn-render``: render a scene to EXR (layers L, L_d, L_i, L_e) + a tone-mapped PNG + a JSON report.

Examples::

    pfn-render --scene vortex --method pt --spp 64 --size 512x512 --out out/vortex.exr
    pfn-render --scene my_scene.json --method raymarch --g 0.5 --out out/marched.exr
    pfn-render --method field --bundle run/field.pfn --scene vortex --g 0.3 --spp 4 --size 512x512 --out img.exr
    pfn-render --method field --bundle run/field.pfn --out img.exr     # the scene the bundle was trained for
    pfn-render --method field --bundle run/field.pfn --scene vortex --orbit 120 --out orbit/frame.exr
    pfn-render --scene head --method pt --spp 4 --denoise oidn --out head.exr   # L denoised, L_noisy kept
    pfn-render --method pvrt --transfer vortex.pvrt --scene vortex --out relit.exr  # pfn-train pvrt vortex ...

Bad input exits with status 2 and one line on stderr: ``error: <input>: <problem>``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from photon_fields.runtime.cli.common import (
    OneLineArgumentParser,
    check_seed,
    guarded,
    make_parent,
    positive_int,
    prepare_output,
    refuse_to_replace,
)
from photon_fields.runtime.denoise.registry import DENOISER_NAMES, DENOISERS, Denoiser
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.renderers.registry import INPUTS, RENDERERS, one_of
from photon_fields.runtime.threads import set_threads


def parse_size(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise InputError("--size", f"expected WIDTHxHEIGHT such as 512x512, got {text!r}") from None
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise InputError("--size", f"width and height must be in [1, 16384], got {text!r}")
    return w, h


def build_parser() -> argparse.ArgumentParser:
    p = OneLineArgumentParser(prog="pfn-render", description=__doc__.split("\n")[0],
                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scene", default=None, help="builtin scene name (vortex, blobs, shell, head) or a scene JSON file "
                   "(default: with --method field the scene the bundle records, else vortex)")
    p.add_argument("--method", choices=list(RENDERERS), default="pt",
                   help="; ".join(f"{r.name}: {r.summary}" for r in RENDERERS.values()))
    p.add_argument("--spp", type=int, default=16, help="samples (passes) per pixel")
    p.add_argument("--size", default=None, help="WIDTHxHEIGHT (default: the scene camera's)")
    p.add_argument("--g", type=float, default=None, help="Henyey-Greenstein g in [-1, 1] (default: the scene's)")
    p.add_argument("--seed", type=int, default=0, help="random seed: same seed, same image")
    shared: dict[str, tuple[Any, list[str]]] = {}  # an option several renderers take is one flag
    for renderer in RENDERERS.values():
        for opt in renderer.options:
            shared.setdefault(opt.flag, (opt, []))[1].append(renderer.name)
    for opt, names in shared.values():
        if opt.type is None:
            p.add_argument(opt.flag, action="store_true", help=f"{', '.join(names)}: {opt.help}")
        else:
            p.add_argument(opt.flag, type=opt.type, default=opt.default, help=f"{', '.join(names)}: {opt.help}")
    p.add_argument("--map", default=None, help="photonmap: photon map (.npz) from `pfn-train trace`")
    p.add_argument("--bundle", default=None, help="field: photon-field bundle (NAME.pfn) from `pfn-train export`")
    p.add_argument("--transfer", default=None, help="pvrt: PVRT transfer (NAME.pvrt) from `pfn-train pvrt`; it must "
                   "match the scene's volume, transfer function and g (default --scene: the builtin it was made for)")
    p.add_argument("--precision", default="fp32",
                   help="field: MLP precision; fp32 (exact) is the only one (int8 was removed: runtime/field/field.py)")
    p.add_argument("--denoise", default=None, metavar="NAME",
                   help="denoise the image: " + "; ".join(f"{d.name}: {d.summary}" for d in DENOISERS.values())
                   + ". The EXR's L is then the denoised image and L_noisy the renderer's (L_e, L_d, L_i stay "
                   "the renderer's); the report records the denoiser and its time")
    p.add_argument("--orbit", type=int, default=None,
                   help="render N frames orbiting the volume to numbered files OUT_0000.exr ... (any --method)")
    p.add_argument("--orbit-degrees", type=float, default=360.0, help="--orbit: total orbit angle")
    p.add_argument("--force", action="store_true",
                   help="replace existing output files; photonmap / field: also use a map or bundle made for "
                        "another scene (a warning names what differs)")
    p.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")
    p.add_argument("--batch-size", type=int, default=1 << 18, help="work items per wavefront batch (memory bound)")
    p.add_argument("--exposure", type=float, default=None,
                   help="PNG exposure in stops (default: automatic; the JSON report records the one used)")
    p.add_argument("--exposure-from", default=None, metavar="REPORT.json",
                   help="PNG exposure recorded in an earlier render's JSON report (or an orbit's timings file), "
                        "so two renders are shown alike")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-resident", action="store_true",
                   help="render in this process even when a resident render server (pfn-resident start) is running; "
                        "without it, a running server of the same code and environment renders instead (the same "
                        "files and output, without the ~1 s of numba start-up; docs/resident.md)")
    p.add_argument("--out", default="render.exr",
                   help="output image, NAME.exr or NAME.png: the EXR (layers), the PNG (tone-mapped L) and a "
                        "NAME.json report are written side by side")
    return p


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Check every option, load the scene and the renderer's input, render (one image or an orbit), write
    EXR + PNG + JSON report. Options are checked before the scene is loaded: errors should name the option
    and come at once, not after minutes of rendering."""
    from photon_fields.runtime.scene.scene import load_scene

    renderer = RENDERERS[args.method]
    out = output_exr_path(args.out)
    spp = positive_int("--spp", args.spp, 1 << 16)
    positive_int("--batch-size", args.batch_size)
    options = renderer_options(args, renderer.name)
    size = parse_size(args.size) if args.size is not None else (None, None)
    if args.g is not None:
        from photon_fields.runtime.transport.phase import check_g

        check_g(args.g, "--g")
    check_seed(args.seed)
    exposure, exposure_mode = resolve_exposure_options(args)
    if args.precision != "fp32":
        from photon_fields.runtime.field.field import REMOVED_PRECISIONS

        raise InputError("--precision", REMOVED_PRECISIONS.get(args.precision,
                                                               f"fp32 is the only precision, got {args.precision!r}"))
    if renderer.input is not None:
        flag, what = INPUTS[renderer.input]
        if getattr(args, renderer.input) is None:
            raise InputError(flag, f"--method {renderer.name} needs {what}")
    if args.orbit is not None:
        positive_int("--orbit", args.orbit, 100_000)
        if not math.isfinite(args.orbit_degrees):
            raise InputError("--orbit-degrees", f"must be a finite angle, got {args.orbit_degrees}")
    denoiser = resolve_denoiser(args)
    check_outputs(args, out)
    set_threads(args.threads)
    # No --scene: a bundle rebuilds the scene it records (else the default, and a mismatch says so).
    scene_from = "--scene" if args.scene is not None else "default"
    if args.scene is None and renderer.input == "bundle":
        from photon_fields.runtime.field.bundle_reader import scene_for_bundle

        scene, scene_from = scene_for_bundle(args.bundle, force=args.force)
    elif args.scene is None and renderer.input == "transfer":
        scene, scene_from = scene_for_transfer(args.transfer)
    else:
        from photon_fields.runtime.scene.scene import DEFAULT_SCENE

        scene = load_scene(args.scene if args.scene is not None else DEFAULT_SCENE)
    scene = scene.with_overrides(g=args.g, width=size[0], height=size[1])
    inputs, warnings, field = load_inputs(args, renderer.input, scene, scene_from)
    for w in warnings:
        print(f"warning: {w}", file=sys.stderr)
    make_parent(out)
    render = renderer.render_function()
    if not args.quiet:
        from photon_fields.runtime.compile_notice import announce_compiles

        announce_compiles(lambda message: print(f"pfn-render: {message}", file=sys.stderr, flush=True))

    def render_frame(view: Any, progress: bool, seed: int = args.seed) -> Any:
        return render(view, spp=spp, seed=seed, batch_size=args.batch_size, progress=progress, **inputs,
                      **options)

    if args.orbit is not None:
        if denoiser is None:
            return run_orbit(args, scene, lambda view: render_frame(view, False), out, spp, exposure)
        # A temporal denoiser averages over frames: each needs its own samples (runtime/renderers/orbit.py).
        seeds = itertools.count(args.seed)
        return run_orbit(args, scene, lambda view: render_frame(view, False, next(seeds)), out, spp, exposure,
                         denoiser.sequence_denoiser(scene))

    t0 = time.perf_counter()
    result = render_frame(scene, not args.quiet)
    wall = time.perf_counter() - t0
    layers, denoised = denoise_layers(result.layers, denoiser, args.threads)
    from photon_fields.runtime.eval.machine import cpu_record

    report = {"scene": scene.name, "method": args.method, "spp": spp, "seed": args.seed, "g": scene.g,
              "size": [scene.camera.width, scene.camera.height], "options": options, "wall_s": wall,
              "timings_ms": result.timings_ms, "stats": result.stats, "scene_description": scene.to_dict(),
              "scene_from": scene_from, "warnings": warnings, "cpu": cpu_record()}
    if field is not None:
        report["field"] = field.describe()
    if "transfer" in inputs:
        mf = inputs["transfer"].manifest
        keys = ("scene_name", "basis", "grid", "exitance_order", "cpca", "photons")
        report["transfer"] = {"path": str(args.transfer), **{k: mf[k] for k in keys}}
    if denoised is not None:
        report["denoise"] = denoised
    from photon_fields.runtime.io.atomic import atomic_write_text
    from photon_fields.runtime.io.images import resolve_exposure, write_image_set

    meta = {"photon_fields.method": args.method, "photon_fields.scene": scene.name,
            "photon_fields.spp": str(spp), "photon_fields.seed": str(args.seed), "photon_fields.g": repr(scene.g)}
    if denoised is not None:
        meta["photon_fields.denoiser"] = denoised["name"]
    exposure = resolve_exposure(layers["L"], exposure)
    report["exposure"] = {"stops": exposure, "mode": exposure_mode}
    written = write_image_set(out, layers, metadata=meta, exposure=exposure)
    json_path = out.with_suffix(".json")
    try:
        atomic_write_text(json_path, json.dumps(report, indent=2) + "\n")
    except OSError as exc:  # e.g. a full disk: one line, not a traceback
        raise InputError(str(json_path), f"cannot write the JSON report: {exc.strerror or exc}") from None
    written.append(json_path)
    info = {"wall_s": wall, "written": [str(p) for p in written], "timings_ms": result.timings_ms}
    if denoised is not None:
        info["denoise"] = f"{denoised['name']} in {denoised['ms']:.0f} ms"
    return info


def resolve_denoiser(args: argparse.Namespace) -> Denoiser | None:
    """``--denoise``: the registry entry (:mod:`photon_fields.runtime.denoise.registry`) or None, checked before
    any work: a known name, one that denoises what is rendered (a single image, or an ``--orbit`` sequence),
    and that can run here (an optional package installed)."""
    if args.denoise is None:
        return None
    denoiser = DENOISERS[one_of(DENOISER_NAMES)("--denoise", args.denoise)]
    what = f"--denoise {denoiser.name}"
    if args.orbit is not None and not denoiser.sequences:
        raise InputError(what, "denoises single images, not --orbit sequences")
    if args.orbit is None and not denoiser.stills:
        raise InputError(what, "denoises frame sequences: use it with --orbit N")
    denoiser.check_available(what)
    return denoiser


def denoise_layers(layers: dict[str, Any], denoiser: Denoiser | None,
                   threads: int | None) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """The layers to write: with a denoiser, L denoised (first, so viewers show it) and the renderer's L kept as
    L_noisy (L_e, L_d, L_i unchanged: they add up to L_noisy); and what the report records of it (None
    without one)."""
    if denoiser is None:
        return layers, None
    import numpy as np  # the CLI module imports no numpy at start-up

    what = f"--denoise {denoiser.name}"
    t0 = time.perf_counter()
    # An unbiased estimator with a control variate (the "marched" camera estimator) leaves a pixel of a few samples
    # slightly negative now and then; a denoiser takes radiance >= 0, and clamping them costs far less than the
    # noise it removes.
    clean = denoiser.denoise_function()(np.maximum(layers["L"], 0.0), threads=threads, what=what)
    ms = (time.perf_counter() - t0) * 1e3
    out = {"L": clean, "L_noisy": layers["L"], **{k: v for k, v in layers.items() if k != "L"}}
    return out, {"name": denoiser.name, "ms": ms, "input": "L", "noisy_layer": "L_noisy",
                 "version": denoiser.version()}


def renderer_options(args: argparse.Namespace, method: str) -> dict[str, Any]:
    """Every renderer's options checked (a bad value is an error whichever method it is given with), and
    the keyword arguments of ``method``'s own."""
    chosen: dict[str, Any] = {}
    for renderer in RENDERERS.values():
        for opt in renderer.options:
            value = opt.value(getattr(args, opt.flag.lstrip("-").replace("-", "_")))
            if renderer.name == method:
                chosen[opt.keyword] = value
    return chosen


def load_inputs(args: argparse.Namespace, kind: str | None, scene: Any,
                scene_from: str) -> tuple[dict[str, Any], list[str], Any]:
    """The renderer's input (:data:`photon_fields.runtime.renderers.registry.INPUTS`) loaded and checked against
    the scene: its keyword arguments, the warnings of a forced mismatch, and the field (for the report)."""
    if kind == "map":
        from photon_fields.runtime.photons.estimate import map_for_scene
        from photon_fields.runtime.photons.photon_map import PhotonMap

        pmap = PhotonMap.load(args.map)
        if scene_from == "default" and not args.force and pmap.scene_fingerprint != scene.fingerprint():
            raise InputError(args.map, f"no --scene given, so the default scene '{scene.name}' was used; the map "
                             f"was traced for {pmap.mismatch(scene.fingerprint_parts())}; pass --scene")
        pmap, warning, note = map_for_scene(pmap, scene, args.force)
        if note:
            print(f"note: {note}", file=sys.stderr)
        from photon_fields.runtime.photons.phase_window import answerable, map_window

        answerable(pmap.phases, scene.g, map_window(pmap.phases), "--g")
        return {"pmap": pmap, "force": args.force}, [warning] if warning else [], None
    if kind == "transfer":
        from photon_fields.runtime.pvrt.transfer import load_transfer

        # A transfer made for another volume, transfer function, g or box is refused, --force or not: relighting
        # it would render the photons of another medium (Transfer.check_scene).
        return {"transfer": load_transfer(args.transfer, scene)}, [], None
    if kind == "bundle":
        from photon_fields.runtime.field.field import PhotonField

        field = PhotonField.load(args.bundle, threads=args.threads, precision=args.precision,
                                 expected_fingerprint=scene.fingerprint(), force=args.force,
                                 expected_parts=scene.fingerprint_parts(),
                                 expected_lights=scene.light_identities())
        if field.light_note:
            print(f"note: {field.light_note}", file=sys.stderr)
        return {"estimator": field.estimator()}, [field.scene_warning] if field.scene_warning else [], field
    return {}, [], None


def scene_for_transfer(path: str) -> tuple[Any, str]:
    """No ``--scene`` with ``--method pvrt``: the builtin scene the transfer was precomputed for (its manifest's
    ``scene_name``; the fingerprints are checked when the transfer is loaded against it), else a one-line error
    asking for ``--scene``."""
    from photon_fields.runtime.pvrt.transfer import load_transfer
    from photon_fields.runtime.scene.scene import BUILTIN_SCENES, builtin_scene

    transfer = load_transfer(path)
    name = transfer.manifest["scene_name"]
    if name not in BUILTIN_SCENES:
        raise InputError("--scene", f"{path} was precomputed for scene {name!r}, not a builtin: pass its scene file "
                         "with --scene")
    return builtin_scene(name), "transfer"


def output_exr_path(text: str) -> Path:
    """``--out``: NAME.exr, or NAME.png (the EXR is written beside it); the EXR path either way."""
    out = Path(text)
    if out.suffix.lower() == ".png":
        return out.with_suffix(".exr")
    if out.suffix.lower() != ".exr":
        raise InputError("--out", f"must end in .exr or .png (both are written, with a .json report), got {text!r}")
    return out


def check_outputs(args: argparse.Namespace, out: Path) -> None:
    """Before any work: the files this render writes, refused if they exist unless ``--force``."""
    if args.orbit is None:
        prepare_output(out, ".exr", (".png", ".json"), force=args.force, what="an earlier render", create=False)
        return
    from photon_fields.runtime.renderers.orbit import orbit_frame_paths, orbit_noisy_png_path, orbit_timings_path

    frames = orbit_frame_paths(out, args.orbit)
    prepare_output(frames[0], ".exr", (".png",), force=args.force, what="an earlier orbit", create=False)
    noisy = [orbit_noisy_png_path(f) for f in frames] if args.denoise is not None else []
    refuse_to_replace([*frames, *(f.with_suffix(".png") for f in frames), *noisy, orbit_timings_path(out)],
                      args.force, "an earlier orbit")


def resolve_exposure_options(args: argparse.Namespace) -> tuple[float | None, str]:
    """``--exposure`` / ``--exposure-from``: the fixed exposure (None: automatic) and how it was chosen."""
    if args.exposure is not None and args.exposure_from is not None:
        raise InputError("--exposure-from", "give --exposure or --exposure-from, not both")
    if args.exposure is not None:
        if not math.isfinite(args.exposure):
            raise InputError("--exposure", f"must be a finite number of stops, got {args.exposure}")
        return args.exposure, "--exposure"
    if args.exposure_from is not None:
        return exposure_from_report(args.exposure_from), f"--exposure-from {args.exposure_from}"
    return None, "auto"


def exposure_from_report(path_text: str) -> float:
    """The PNG exposure (stops) recorded in a render's JSON report (``exposure``) or an orbit's timings file
    (``exposure_stops``)."""
    from photon_fields.runtime.errors import check_keys

    path = Path(path_text)
    what = f"--exposure-from {path_text}"
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(what, "file not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(what, f"not a JSON report of pfn-render: {exc}") from None
    if isinstance(doc, dict) and isinstance(doc.get("exposure"), dict):
        check_keys(doc["exposure"], ("stops", "mode"), f"{what} exposure", required=("stops",))
        stops = doc["exposure"]["stops"]
    elif isinstance(doc, dict) and "exposure_stops" in doc:
        stops = doc["exposure_stops"]
    else:
        raise InputError(what, "records no exposure (expected the JSON report of a pfn-render image or orbit)")
    if isinstance(stops, bool) or not isinstance(stops, (int, float)) or not math.isfinite(stops):
        raise InputError(what, f"exposure must be a finite number of stops, got {stops!r}")
    return float(stops)


def run_orbit(args: argparse.Namespace, scene: Any, render_frame: Any, out: Path, spp: int,
              exposure: float | None, denoiser: Any = None) -> dict[str, Any]:
    """``--orbit N``: N frames orbiting the volume, numbered files beside ``out``, a timings JSON; with a
    sequence ``denoiser`` (``--denoise wrls``) every frame's L denoised and its seed ``--seed`` + frame index."""
    from photon_fields.runtime.renderers.orbit import render_orbit

    summary = render_orbit(scene, render_frame, out, frames=args.orbit, spp=spp, degrees=args.orbit_degrees,
                           exposure=exposure, progress=not args.quiet, denoiser=denoiser,
                           record={"method": args.method, "seed": args.seed,
                                   "seeds": "seed + frame index" if denoiser is not None else "seed"})
    files = summary["files"]
    info = {"wall_s": float(sum(summary["frame_s"])), "timings_ms": summary["stage_ms_per_frame"],
            "written": [files[0], "...", files[-1], summary["timings_file"]] if len(files) > 2 else
            [*files, summary["timings_file"]],
            "orbit": f"{summary['frames']} frames, mean {summary['mean_s'] * 1e3:.0f} ms, median "
                     f"{summary['median_s'] * 1e3:.0f} ms, p95 {summary['p95_s'] * 1e3:.0f} ms per frame"}
    if denoiser is not None:
        d = summary["denoiser"]
        info["denoise"] = (f"{d['name']}, mean {d['mean_denoise_ms']:.0f} ms per frame (+ {d['mean_depth_ms']:.0f} ms "
                           "depth map)")
    return info


def format_timings(timings_ms: dict[str, float]) -> str:
    """Per-stage milliseconds in one line, largest first (the total last)."""
    items = sorted(((k, v) for k, v in timings_ms.items() if k != "total"), key=lambda kv: -kv[1])
    text = ", ".join(f"{k} {v:.0f}" for k, v in items)
    return f"stages (ms): {text}" + (f"; total {timings_ms['total']:.0f}" if "total" in timings_ms else "")


@guarded
def _main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    info = run(args)
    if "orbit" in info:
        print(f"orbit: {info['orbit']}")
    print(format_timings(info["timings_ms"]))
    if "denoise" in info:
        print(f"denoised: {info['denoise']}")
    print(f"rendered in {info['wall_s']:.2f} s -> " + ", ".join(info["written"]))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    sys.exit(_main(argv))
