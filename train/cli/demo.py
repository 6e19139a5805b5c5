"""``pfn-demo``: the product's showcase, end to end on one scene (what ``make demo`` runs).

1. trace a multi-phase photon map (Alg. 1), 2. fit a photon field with the ``cpu`` preset (Sec. 3.5),
3. export the bundle (``field.pfn``), 4. load it in the torch-free runtime and render the neural image
(Alg. 2), 5. render the photon-map image (same samples, Eq. 5 in place of the field; when the scene's g
is not in the training set G, from an extra map traced at that g) and a path-traced reference, plus the
path tracer at the neural frame's wall time (equal-time comparison), 6. write a side-by-side figure and
a short summary of timings and errors.

Outputs in ``--out`` (default ``demo_out/``): ``run/`` (map, checkpoint, loss curve, bundle), EXR + PNG of
each render, ``comparison.png`` (L and L_i of the three renderers, the neural image's error against the
reference as a heat map), ``summary.txt`` and ``summary.json``.

Metrics (:mod:`photon_fields.runtime.eval.metrics`): relative L2 and SSIM of L against the path-traced reference for the
neural and photon-map images, and of the neural L_i against the photon-map L_i (the field's own error).
The reference is a finite-spp path tracing and carries its own noise; ``summary.json`` records its spp.

Every stage takes the one ``--seed``: the same command gives the same map, field and images.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np  # noqa: E402

from photon_fields.models_spec import DEFAULT_PHOTONS  # noqa: E402
from photon_fields.runtime.cli.common import (  # noqa: E402
    OneLineArgumentParser,
    check_seed,
    guarded,
    positive_int,
    refuse_to_replace,
)
from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.runtime.threads import set_threads


def build_parser() -> argparse.ArgumentParser:
    p = OneLineArgumentParser(prog="pfn-demo", description=__doc__.split("\n")[0],
                              formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scene", default="vortex", help="builtin scene name or scene JSON file")
    p.add_argument("--photons", default=f"{DEFAULT_PHOTONS // 1_000_000}M",
                   help="photon records to trace (default: a million per phase)")
    p.add_argument("--preset", default="cpu", help="training preset (cpu, paper, tiny)")
    p.add_argument("--steps", type=int, default=None, help="training steps (default: the preset's)")
    p.add_argument("--size", default="384x384", help="image size WIDTHxHEIGHT")
    p.add_argument("--spp", type=int, default=8, help="samples per pixel of the neural and photon-map images")
    p.add_argument("--reference-spp", type=int, default=128, help="samples per pixel of the path-traced reference")
    p.add_argument("--seed", type=int, default=0, help="one seed for tracing, training and rendering")
    p.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--out", default="demo_out", help="output folder")
    p.add_argument("--force", action="store_true", help="replace an earlier demo's outputs in --out")
    return p


def comparison_figure(path: Path, images: dict[str, dict[str, np.ndarray]], reference: str,
                      title: str) -> dict[str, float]:
    """Rows L and L_i, one column per renderer, tone-mapped with the reference's exposure per row; a last
    column with the neural L's error against the reference (relative to the reference's mean luminance).
    Returns each row's exposure (stops) by layer."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from photon_fields.runtime.io.atomic import atomic_path
    from photon_fields.runtime.io.images import auto_exposure_stops, tonemap_srgb

    names = list(images)
    fig, axes = plt.subplots(2, len(names) + 1, figsize=(3.2 * (len(names) + 1), 6.8))
    row_stops: dict[str, float] = {}
    for row, layer in enumerate(("L", "L_i")):
        stops = row_stops[layer] = auto_exposure_stops(images[reference][layer])
        for col, name in enumerate(names):
            ax = axes[row, col]
            ax.imshow(tonemap_srgb(images[name][layer], stops))
            ax.set_title(f"{name}: {layer}", fontsize=9)
            ax.axis("off")
        ax = axes[row, -1]
        ref = images[reference][layer].mean(axis=2)
        err = np.abs(images["neural"][layer].mean(axis=2) - ref) / max(float(ref.mean()), 1e-12)
        im = ax.imshow(err, cmap="magma", vmin=0.0, vmax=max(float(np.percentile(err, 99)), 1e-6))
        ax.set_title(f"|neural - {reference}| {layer} / mean", fontsize=9)
        ax.axis("off")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    plt.close(fig)
    return row_stops


def warm_up_renderers(scene: Any, estimator: Any, seed: int) -> None:
    """Untimed renders of an 8x8 view with the neural renderer's every camera estimator that ``auto`` may take
    (``camera_choice.AUTO_CHOICES``) and with the path tracer. numba compiles each kernel on first use (in a fresh
    clone, before its cache exists), and the equal-time comparison must time rendering, not compilation: a warm-up with
    ``auto`` alone renders so small a view forced, so the marched kernels compiled inside the timed render and
    the path tracer got the compile time as extra samples."""
    from photon_fields.runtime.renderers.neural import render_neural
    from photon_fields.runtime.renderers.path_tracer import render_path_traced
    from photon_fields.runtime.wavefront.camera_choice import AUTO_CHOICES

    tiny = scene.with_overrides(width=8, height=8)
    for camera in AUTO_CHOICES:
        render_neural(tiny, estimator, spp=1, seed=seed, progress=False, camera=camera)
    render_path_traced(tiny, spp=1, seed=seed, progress=False)


def run_demo(args: argparse.Namespace) -> dict[str, Any]:
    from photon_fields.runtime.cli.render import parse_size
    from photon_fields.train.cli.train import parse_count

    photons = parse_count(args.photons)
    width, height = parse_size(args.size)
    spp = positive_int("--spp", args.spp, 1 << 16)
    ref_spp = positive_int("--reference-spp", args.reference_spp, 1 << 16)
    check_seed(args.seed)
    from photon_fields.train.fit.presets import PRESETS
    from photon_fields.train.fit.settings import FitSettings

    if args.preset not in PRESETS:
        raise InputError("--preset", f"unknown preset {args.preset!r} (available: {', '.join(PRESETS)})")
    settings = FitSettings.from_preset(args.preset, steps=args.steps, seed=args.seed)
    settings.validate()
    set_threads(args.threads)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError("--out", f"{str(out)!r} is a file; --out names the demo's folder")
    refuse_to_replace(sorted(out.iterdir()) if out.is_dir() else [], args.force, f"an earlier demo in {str(out)!r}")

    from photon_fields.runtime.eval.machine import cpu_record
    from photon_fields.runtime.eval.metrics import relative_l2, ssim
    from photon_fields.runtime.field.field import PhotonField
    from photon_fields.runtime.io.images import auto_exposure_stops, write_image_set
    from photon_fields.runtime.renderers.neural import render_neural
    from photon_fields.runtime.renderers.path_tracer import render_path_traced
    from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped
    from photon_fields.runtime.scene.scene import load_scene
    from photon_fields.train.export.bundle import export_bundle, write_run_domain
    from photon_fields.train.fit.loop import fit
    from photon_fields.train.photons.tracing import trace_photons

    scene = load_scene(args.scene).with_overrides(width=width, height=height)
    run = out / "run"
    run.mkdir(parents=True, exist_ok=True)
    progress = not args.quiet
    times: dict[str, float] = {}

    def step(msg: str) -> None:
        print(f"[{sum(times.values()):6.1f} s] {msg}", flush=True)

    step(f"tracing {photons:,} photons in '{scene.name}' ...")
    t = time.perf_counter()
    pmap = trace_photons(scene, photons, seed=args.seed, progress=progress)
    pmap.save(run / "map.npz")
    times["trace"] = time.perf_counter() - t
    step(f"fitting the photon field (preset {settings.preset}, {settings.steps} steps) ...")
    t = time.perf_counter()
    write_run_domain(run, scene, str(args.scene))
    result = fit(scene, pmap, run, settings, progress=progress)
    times["fit"] = time.perf_counter() - t
    step("exporting the bundle ...")
    t = time.perf_counter()
    bundle = export_bundle(run, run / "field.pfn", scene=scene, force=True).path
    times["export"] = time.perf_counter() - t

    field = PhotonField.load(bundle, threads=args.threads, expected_fingerprint=scene.fingerprint())
    renders: dict[str, Any] = {}
    step("compiling the renderers (untimed in the comparison; cached for later runs) ...")
    t = time.perf_counter()
    warm_up_renderers(scene, field.estimator(), args.seed)
    times["warm_up"] = time.perf_counter() - t
    step(f"rendering: neural ({spp} spp) ...")
    t = time.perf_counter()
    renders["neural"] = render_neural(scene, field.estimator(), spp=spp, seed=args.seed, progress=progress)
    times["render_neural"] = time.perf_counter() - t
    step(f"rendering: photon map ({spp} spp) ...")
    t = time.perf_counter()
    from photon_fields.train.eval.field_images import map_at_g

    ref_map = map_at_g(scene, pmap, scene.g, seed=args.seed + 1, progress=progress)
    # the same samples as the neural image: its camera estimator (what auto chose for the field), not its own choice
    renders["photon map"] = render_photon_mapped(scene, ref_map, spp=spp, seed=args.seed, progress=progress,
                                                 camera=str(renders["neural"].stats["camera_estimator"]))
    times["render_photon_map"] = time.perf_counter() - t
    step(f"rendering: path-traced reference ({ref_spp} spp) ...")
    t = time.perf_counter()
    renders["path traced"] = render_path_traced(scene, spp=ref_spp, seed=args.seed + 1, progress=progress)
    times["render_path_traced"] = time.perf_counter() - t
    # Equal-time comparison: the path tracer with the spp it manages in the neural frame's time.
    per_spp = times["render_path_traced"] / ref_spp
    eq_spp = max(1, int(times["render_neural"] / per_spp))
    t = time.perf_counter()
    equal_time = render_path_traced(scene, spp=eq_spp, seed=args.seed + 2, progress=False)
    times["render_path_traced_equal_time"] = time.perf_counter() - t

    files = {"neural": "neural.exr", "photon map": "photonmap.exr", "path traced": "pathtraced.exr"}
    # One exposure for every PNG (the reference's L): equal radiance shows as equal pixel values.
    stops = auto_exposure_stops(renders["path traced"].layers["L"])
    written = [str(p) for name, r in renders.items()
               for p in write_image_set(out / files[name], r.layers, exposure=stops)]
    written += [str(p) for p in write_image_set(out / "pathtraced_equal_time.exr", equal_time.layers, exposure=stops)]
    ref = renders["path traced"].layers

    def score(img: dict[str, np.ndarray], against: dict[str, np.ndarray], layer: str = "L") -> dict[str, float]:
        return {"rel_l2": relative_l2(img[layer], against[layer]), "ssim": ssim(img[layer], against[layer])}

    metrics = {
        "neural_L_vs_reference": score(renders["neural"].layers, ref),
        "photon_map_L_vs_reference": score(renders["photon map"].layers, ref),
        "path_traced_equal_time_L_vs_reference": {"spp": eq_spp, **score(equal_time.layers, ref)},
        "neural_L_i_vs_photon_map_L_i": score(renders["neural"].layers, renders["photon map"].layers, "L_i"),
    }
    figure = out / "comparison.png"
    row_stops = comparison_figure(figure, {k: r.layers for k, r in renders.items()}, "path traced",
                      f"{scene.name} {width}x{height}, g = {scene.g:g}: neural {spp} spp "
                      f"({times['render_neural']:.2f} s), photon map {spp} spp, path traced {ref_spp} spp")
    summary = {"scene": scene.name, "size": [width, height], "seed": args.seed, "photons": len(pmap),
               "preset": settings.preset, "steps": settings.steps, "spp": spp, "reference_spp": ref_spp,
               "seconds": times, "total_s": sum(times.values()), "metrics": metrics,
               "neural_stages_ms": renders["neural"].timings_ms, "fit": result.log["totals"],
               "bundle": str(bundle), "files": [*written, str(figure), str(run / "loss.png")],
               "cpu": cpu_record(),
               "exposure_stops": {"png": stops, "comparison_rows": row_stops, "from": "the path-traced reference"}}
    text = summary_text(summary)
    from photon_fields.runtime.io.atomic import atomic_write_text

    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    atomic_write_text(out / "summary.txt", text)
    print(text, end="")
    return summary


def summary_text(s: dict[str, Any]) -> str:
    t, m = s["seconds"], s["metrics"]
    lines = [
        f"photon-fields demo: {s['scene']} at {s['size'][0]}x{s['size'][1]}, seed {s['seed']}",
        f"  trace {s['photons']:,} photons   {t['trace']:7.1f} s",
        f"  fit ({s['preset']}, {s['steps']} steps) {t['fit']:7.1f} s   (loss curve: run/loss.png)",
        f"  export bundle          {t['export']:7.1f} s   ({s['bundle']})",
        f"  renderers' warm-up     {t['warm_up']:7.1f} s   (numba compiles on a first run; not in the comparison)",
        f"  neural render, {s['spp']} spp   {t['render_neural']:7.2f} s",
        f"  photon map, {s['spp']} spp      {t['render_photon_map']:7.2f} s",
        f"  path traced, {s['reference_spp']} spp  {t['render_path_traced']:7.2f} s",
        "errors against the path-traced reference (relative L2 / SSIM):",
        *(f"  {label:32s} {m[key]['rel_l2']:.3f} / {m[key]['ssim']:.3f}" for label, key in (
            ("neural", "neural_L_vs_reference"), ("photon map", "photon_map_L_vs_reference"),
            (f"path traced, equal time ({m['path_traced_equal_time_L_vs_reference']['spp']} spp)",
             "path_traced_equal_time_L_vs_reference"))),
        f"field L_i vs photon-map L_i: {m['neural_L_i_vs_photon_map_L_i']['rel_l2']:.3f} / "
        f"{m['neural_L_i_vs_photon_map_L_i']['ssim']:.3f}",
        f"total {s['total_s']:.0f} s. Side by side: {Path(s['files'][-2])}",
    ]
    return "\n".join(lines) + "\n"


@guarded
def _main(argv: Sequence[str] | None = None) -> int:
    run_demo(build_parser().parse_args(argv))
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    sys.exit(_main(argv))
