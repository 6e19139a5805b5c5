"""Fidelity: how close the field's and the photon map's indirect light come to the path tracer's.

For each scene (default: every builtin, the CT-like ``head`` phantom included) and each training
configuration (:data:`CONFIGS`; default: the product's defaults and the paper-like settings they replaced),
one photon map is traced and one field fitted (``--work`` keeps both, so a second run only renders), and at
every g of ``--gs`` (default: the phases G, the midpoints between them and +-0.35, +-0.6) three L_i images of the same
view are compared, all at ``--size`` with the same first interactions:

- the path tracer's L_i at ``--ref-spp`` (the truth; cached per scene, size, spp and g),
- the field's L_i (the torch field behind the renderer's estimator: the exported bundle computes the
  same function, tests/runtime/field/test_bundle.py), at ``--spp``,
- the photon map's L_i with the training K and final radius (g in G only: the map has no other g).

Per image: ``mean`` = mean(L_i) / mean(reference L_i) (the bias a scientist sees as a wrong density),
``rel_l2`` and ``ssim`` against the reference (detail). Summaries per configuration: the worst mean
error over scenes, in G and outside G, and the ratio of the mean rel. L2 outside G to inside G.

``--converged`` adds, per scene and configuration, the neural renderer's full L, plain and with the final gather
(``final_gather_after=0``: one real bounce before the field), (two renders at
``--converged-neural-spp``, default 256, with different seeds: their mean, its noise, and the error left without
the noise of either image; the photon map's L likewise when the scene's g is in G) against the mean of two
independent path-traced L at ``--converged-spp`` (default 2048 each; half their difference is the reference's own
noise), next to the path tracer at 1 and 4 spp, denoised by Intel Open Image Denoise
(``photon_fields.runtime.denoise.oidn``) when the ``oidn`` extra is installed (``pip install 'photon-fields[oidn]'``;
skipped if not).

``--seeds`` fits one field per seed (each from its own map) and reports, per g, the field's mean over the seeds
with their spread: one seed's mean moves by a few percent (docs/training.md), so a claim of 1-3 % needs
several. The summary's worst mean error is then that of the seed mean (the systematic error), next to the
worst single seed; the photon map and ``--converged`` are evaluated for the first seed only.

``--orbits DEG ...`` (default: 0 180) scores every field from each of these views, the scene's camera orbited about
its target (0: the scene's own; references cached apart): a field's error can depend on the side it is seen from
(``probe_field_directions.py``: head's unlit side was 10-18 % dark), which one camera alone does not show. The
fields are the same for every view (a fit does not depend on the camera); each view gets its own entry and
summary (``results["scene/config"]`` for the scene's own camera, ``"scene/config@180"`` for the other side) and
the worst over the views is printed last. ``--converged`` uses the first view only. ``--gathered-map`` also
scores the photon map one real bounce away (``render_photon_mapped(..., final_gather_after=0)``): what targets
gathered before the map would teach the field (docs/training.md, "Where the kernel estimate stops").

Output: tables on stdout and JSON (default ``bench/results/fidelity.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from common import finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.models_spec import (  # noqa: E402
    DEFAULT_MAP_PHASES,
    DEFAULT_PHASES,
    DEFAULT_PHOTONS,
    PAPER_PHASES,
    PHASE_WINDOW,
)
from photon_fields.models_spec.photon_map import RECORD_FLOOR  # noqa: E402
from photon_fields.runtime.denoise.oidn import denoise_oidn, oidn_available  # noqa: E402
from photon_fields.runtime.eval.metrics import relative_l2, ssim  # noqa: E402
from photon_fields.runtime.photons.phase_window import window_range  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped  # noqa: E402
from photon_fields.runtime.scene.camera import orbit_camera  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402
from photon_fields.runtime.wavefront.first_interaction import render_first_interaction  # noqa: E402
from photon_fields.train.eval.field_images import TorchFieldEstimator  # noqa: E402
from photon_fields.train.fit.checkpoint import finished_run, load_checkpoint  # noqa: E402
from photon_fields.train.fit.loop import fit  # noqa: E402
from photon_fields.train.fit.settings import FitSettings  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "fidelity.json"
DEFAULT_WORK = HERE / "results" / "fidelity"
BETWEEN = (-0.6, -0.35, 0.35, 0.6)
#: The phase bins of the default map before 2026-11-25 (windows whole over [-0.75, 0.75]).
NARROW_BINS = tuple(round(-0.9 + 0.05 * i, 6) for i in range(37))


@dataclass(frozen=True)
class Config:
    """One way to train a field: the map it learns from, the preset and the fit's overrides of it."""

    photons: int
    """Photon records in the training map."""
    phases: tuple[float, ...] = DEFAULT_PHASES
    """The phase set G (or the narrow phase bins) the map is traced for."""
    preset: str = "cpu-phases"
    """The training preset (:data:`photon_fields.train.fit.presets.PRESETS`)."""
    overrides: dict[str, Any] = field(default_factory=dict)
    """:class:`photon_fields.train.fit.settings.FitSettings` fields that differ from the preset's."""
    g_window: float | None = None
    """The map's kernel in g (a PHASE_BINS map): its photon-map column is then the training target at every g."""
    record_floor: float = RECORD_FLOOR
    """Photon tracing's record floor (:mod:`photon_fields.runtime.photons.photon_path`)."""
    about: str = ""


CONFIGS: dict[str, Config] = {
    "default": Config(DEFAULT_PHOTONS, DEFAULT_MAP_PHASES, "cpu", g_window=PHASE_WINDOW,
                      about="the product's defaults: 39 phase bins (any g of [-0.8, 0.8] from a kernel in g), K = 32, "
                            "spline features, the direction features times g (since 2026-11-27), anneal, three "
                            "quarters of the samples where cameras see the medium (half before 2026-11-27), "
                            "records with a floor of 0.1 (since 2026-11-27; floor0.0 is the map before)"),
    **{f"floor{q}": Config(DEFAULT_PHOTONS, DEFAULT_MAP_PHASES, "cpu", g_window=PHASE_WINDOW, record_floor=q,
                           about=f"the default with photons also recorded at null collisions, record floor {q}")
       for q in (0.0, 0.03, 0.1, 0.3)},
    "together": Config(DEFAULT_PHOTONS, DEFAULT_MAP_PHASES, "cpu", {"per_light": False}, g_window=PHASE_WINDOW,
                       about="the default with one output for all lights (before 2026-11-26; the same with one light)"),
    "support": Config(DEFAULT_PHOTONS, DEFAULT_MAP_PHASES, "cpu", {"sampling": "support"}, g_window=PHASE_WINDOW,
                      about="the default before 2026-11-25: every training sample uniform over the support"),
    "narrow-K64": Config(DEFAULT_PHOTONS, NARROW_BINS, "cpu", {"k": 64}, g_window=PHASE_WINDOW,
                         about="the default before 2026-11-25 10:00: 37 bins over [-0.9, 0.9] (g trained over "
                               "[-0.75, 0.75]) and K = 64"),
    **{f"K{k}-bins": Config(DEFAULT_PHOTONS, DEFAULT_MAP_PHASES, "cpu", {"k": k}, g_window=PHASE_WINDOW,
                            about=f"the default with K = {k} photons per target") for k in (16, 64)},
    "phases": Config(DEFAULT_PHOTONS, about="the defaults before the kernel in g: five phases, 1M photons each, "
                                            "the field trained at the phases (cpu-phases)"),
    "paper-like": Config(1_000_000, PAPER_PHASES, overrides={"loss": "log", "k": 1024},
                         about="the defaults before: the paper's three phases, 1M photons, K 1024, the loss on L'"),
    "G3-3M": Config(3_000_000, PAPER_PHASES, about="three phases with a million photons each, linear loss"),
    "log-loss": Config(DEFAULT_PHOTONS, overrides={"loss": "log"}, about="cpu-phases with the paper's loss"),
    **{f"K{k}": Config(DEFAULT_PHOTONS, overrides={"k": k}, about=f"cpu-phases with K = {k} photons per target")
       for k in (16, 32, 64, 128, 256, 1024)},
    **{f"K{k}-avg{int(a * 100)}": Config(DEFAULT_PHOTONS, overrides={"k": k, "average": a},
                                          about=f"K = {k}, the parameters averaged over the last {a:.0%} of the steps")
       for k in (32, 64, 256) for a in (0.3, 0.5)},
    "G9-K64-avg50": Config(DEFAULT_PHOTONS, tuple(np.linspace(-0.75, 0.75, 9).tolist()), overrides={"k": 64},
                           about="nine phases, 5M photons in all, K = 64, parameters averaged over the last half"),
    "tent-continuous": Config(DEFAULT_PHOTONS, preset="cpu-tent",
                              about="the cpu-tent preset: tent phase features, g drawn continuously over G's range"),
    "tent-mixed": Config(DEFAULT_PHOTONS, preset="cpu-tent", overrides={"g_sampling": "mixed"},
                         about="tent phase features, half the training g at the phases, half continuous"),
    "window-paper-anneal": Config(DEFAULT_PHOTONS, DEFAULT_MAP_PHASES, "cpu", {"lr_decay_start": 0.7,
                                                                              "lr_decay_every": 25},
                                  g_window=PHASE_WINDOW, about="the default with the paper's learning-rate anneal"),
    "phases-anneal": Config(DEFAULT_PHOTONS, overrides={"lr_decay_start": 0.5, "lr_decay_every": 10},
                            about="cpu-phases with the default's learning-rate anneal"),
    "G0-K64-avg50": Config(1_000_000, (0.0,), overrides={"k": 64},
                           about="one phase (g = 0), 1M photons: the field without any g to model"),
}


def view_tag(orbit: float) -> str:
    """What the cached references' names add for a camera orbited by ``orbit`` degrees ("" for the scene's own)."""
    return f"_orbit{orbit:g}" if orbit else ""


def reference_li(scene: Scene, g: float, size: int, spp: int, work: Path, tag: str = "") -> np.ndarray:
    """The path tracer's L_i at g, cached in ``work`` (``tag``: :func:`view_tag` of the scene's camera)."""
    path = work / f"ref_{scene.name}_{size}_{spp}_{g:+.3f}{tag}.npy"
    if not path.exists():
        t0 = time.perf_counter()
        li = render_path_traced(scene.with_overrides(g=g, width=size, height=size), spp=spp, seed=1234,
                                progress=False).layers["L_i"]
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, li)
        print(f"  reference L_i {scene.name} g {g:+.2f}: {time.perf_counter() - t0:.1f} s", flush=True)
    return np.load(path)


def code_tag() -> str:
    """Short hash of the code a fitted field depends on beyond its settings (photon tracing, the estimate, the
    fit), so that a cached run is reused only by the code that trained it."""
    root = HERE.parent
    digest = hashlib.sha1()
    for folder in ("runtime/photons", "runtime/transport", "train/photons", "train/fit", "train/field"):
        for path in sorted((root / folder).glob("*.py")):
            digest.update(path.read_bytes())
    return digest.hexdigest()[:10]


def train(scene: Scene, name: str, config: Config, work: Path, seed: int) -> tuple[Any, Any, dict[str, Any]]:
    """The configuration's map and fitted field for ``scene`` (reused from ``work`` when finished with the same
    settings and code)."""
    run = work / scene.name / (f"{name}-{code_tag()}" + (f"-s{seed}" if seed else ""))
    settings = FitSettings.from_preset(config.preset, seed=seed, **config.overrides)
    t0 = time.perf_counter()
    pmap = trace_photons(scene, config.photons, phases=config.phases, seed=seed, progress=False,
                         record_floor=config.record_floor)
    trace_s = time.perf_counter() - t0
    log = finished_run(run, settings)
    if log is None:
        result = fit(scene, pmap, run, settings, progress=False)
        model, log = result.model, result.log
    else:
        model, _ = load_checkpoint(run / "checkpoint.pt", scene.fingerprint())
    return pmap, model, {"trace_s": trace_s, "fit_s": log["totals"]["wall_s"], "settings": settings.to_dict()}


def compare(img: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    return {"mean": float(img.mean() / max(ref.mean(), 1e-30)), "rel_l2": relative_l2(img, ref), "ssim": ssim(img, ref)}


def map_answers(pmap: Any, config: Config, g: float) -> bool:
    """Whether the configuration's photon map has a target at g (its phase, or a whole window around g)."""
    if config.g_window is None:
        return bool(np.any(np.isclose(pmap.phases, g)))
    lo, hi = window_range(pmap.phases, config.g_window)
    return lo - 1e-9 <= g <= hi + 1e-9


def score(scene: Scene, pmap: Any, model: Any, settings: dict[str, Any], config: Config, gs: list[float],
          args: argparse.Namespace, work: Path, orbit: float = 0.0, with_map: bool = True) -> list[dict[str, Any]]:
    """Field and (``with_map``) photon-map L_i against the reference at every g (in_G: g is one of the field's
    phases G), seen by ``scene``'s camera (orbited by ``orbit`` degrees: the references' cache tag); with
    ``--gathered-map`` the map's L_i after one real bounce too (``photon_map_gathered``)."""
    estimator = TorchFieldEstimator(model, scene.medium())
    radius = final_radius(settings)
    rows = []
    for g in gs:
        ref = reference_li(scene, g, args.size, args.ref_spp, work, view_tag(orbit))
        view = scene.with_overrides(g=g, width=args.size, height=args.size)
        li = render_first_interaction(view, estimator, spp=args.spp, seed=7, progress=False).layers["L_i"]
        row: dict[str, Any] = {"g": g, "in_G": bool(np.any(np.isclose(model.cfg.phases, g))),
                               "field": compare(li, ref)}
        if with_map and map_answers(pmap, config, g):
            pm = render_photon_mapped(view, pmap, k=settings["k"], radius=radius, spp=args.spp, seed=7,
                                      progress=False, g_window=config.g_window, final_gather_after=None,
                                      camera="forced").layers["L_i"]  # the field's first interactions
            row["photon_map"] = compare(pm, ref)
            if args.gathered_map:  # the map one real bounce away: what gathered training targets would learn
                pm = render_photon_mapped(view, pmap, k=settings["k"], radius=radius, spp=args.spp, seed=7,
                                          progress=False, g_window=config.g_window, final_gather_after=0,
                                          camera="forced")
                row["photon_map_gathered"] = compare(pm.layers["L_i"], ref)
        rows.append(row)
    return rows


def over_seeds(per_seed: list[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """The rows of several seeds' fields as one: per g the field's figures averaged over the seeds, with each
    seed's mean in ``field["seed_means"]`` (the photon map's, if any, from the first seed)."""
    rows = []
    for same_g in zip(*per_seed, strict=True):
        row = dict(same_g[0])
        row["field"] = {key: float(np.mean([r["field"][key] for r in same_g])) for key in same_g[0]["field"]}
        row["field"]["seed_means"] = [r["field"]["mean"] for r in same_g]
        rows.append(row)
    return rows


def summarize(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Worst mean error in and outside G (of the seed mean, and of the worst single seed), mean rel. L2 in and
    outside G and their ratio."""
    out: dict[str, float] = {}
    for label, sel in (("in_G", [r for r in rows if r["in_G"]]), ("outside_G", [r for r in rows if not r["in_G"]])):
        if sel:
            out[f"worst_mean_error_{label}"] = max(abs(r["field"]["mean"] - 1.0) for r in sel)
            if len(sel[0]["field"].get("seed_means", [])) > 1:
                out[f"worst_single_seed_error_{label}"] = max(abs(m - 1.0) for r in sel
                                                              for m in r["field"]["seed_means"])
            out[f"rel_l2_{label}"] = float(np.mean([r["field"]["rel_l2"] for r in sel]))
    if "rel_l2_in_G" in out and "rel_l2_outside_G" in out:
        out["rel_l2_outside_over_in"] = out["rel_l2_outside_G"] / out["rel_l2_in_G"]
    return out


def final_radius(settings: dict[str, Any]) -> float:
    """The fit's last KNN search radius (world units)."""
    return settings["schedule"]["stages"][-1]["radius_percent"] / 100.0 if settings.get("schedule") else 0.05


def converged_error(img: np.ndarray, noise: float, ref: np.ndarray, ref_noise: float) -> dict[str, float]:
    """``compare`` of a two-seed mean against the reference, with the image's own noise (half the rel. L2 between
    its two halves) and the error left once both images' noise is taken out, sqrt(e^2 - noise^2 - ref_noise^2):
    what more samples would not remove (bias, blur, the photons' frozen noise)."""
    c = compare(img, ref)
    return {**c, "noise_rel_l2": noise,
            "bias_rel_l2": float(np.sqrt(max(0.0, c["rel_l2"] ** 2 - noise**2 - ref_noise**2)))}


def converged(scene: Scene, pmap: Any, model: Any, settings: dict[str, Any], config: Config,
              args: argparse.Namespace, work: Path, orbit: float = 0.0) -> dict[str, Any]:
    """Neural and photon-mapped L (the field's training targets, as an image) at ``--converged-neural-spp`` and the
    path tracer at 1 / 4 spp (+ OIDN) against a high-spp path-traced L."""
    view = scene.with_overrides(width=args.size, height=args.size)
    halves = []
    tag = view_tag(orbit)
    for seed in (4321, 4322):
        path = work / f"refL_{scene.name}_{args.size}_{args.converged_spp}_{scene.g:+.3f}_{seed}{tag}.npy"
        if not path.exists():
            np.save(path, render_path_traced(view, spp=args.converged_spp, seed=seed, progress=False).layers["L"])
        halves.append(np.load(path))
    ref = 0.5 * (halves[0] + halves[1])
    # The reference's own noise: two independent halves differ by sqrt(2) sigma, their mean has sigma / sqrt(2).
    out: dict[str, Any] = {"reference": {"spp": 2 * args.converged_spp,
                                         "noise_rel_l2": relative_l2(halves[0], halves[1]) / 2.0}}
    estimator = TorchFieldEstimator(model, scene.medium())
    renders = {"neural": lambda seed: render_first_interaction(view, estimator, spp=args.converged_neural_spp,
                                                               seed=seed, progress=False).layers["L"],
               "neural_final_gather": lambda seed: render_first_interaction(
                   view, estimator, spp=args.converged_neural_spp, seed=seed, progress=False,
                   final_gather_after=0).layers["L"]}
    if map_answers(pmap, config, scene.g):
        renders["photon_map"] = lambda seed: render_photon_mapped(
            view, pmap, k=settings["k"], radius=final_radius(settings), spp=args.converged_neural_spp, seed=seed,
            progress=False, g_window=config.g_window, final_gather_after=None, camera="forced").layers["L"]
    for name, render in renders.items():
        t0 = time.perf_counter()
        a, b = render(7), render(8)
        out[name] = {"spp": 2 * args.converged_neural_spp, "wall_s": time.perf_counter() - t0,
                     **converged_error(0.5 * (a + b), relative_l2(a, b) / 2.0, ref, out["reference"]["noise_rel_l2"])}
    denoise = denoise_oidn if oidn_available() else None
    for spp in (1, 4):
        t0 = time.perf_counter()
        pt = render_path_traced(view, spp=spp, seed=99, progress=False).layers["L"]
        entry = {"spp": spp, "wall_s": time.perf_counter() - t0, **compare(pt, ref)}
        if denoise is not None:
            entry["oidn"] = compare(denoise(pt), ref)
        out[f"pt_{spp}spp"] = entry
    return out


def result_key(scene: str, config: str, orbit: float) -> str:
    """The results' key of a (scene, configuration) seen from the camera orbited by ``orbit`` degrees."""
    return f"{scene}/{config}" + (f"@{orbit:g}" if orbit else "")


def print_entry(entry: dict[str, Any]) -> None:
    """One view's table: per g the field's mean (seed spread), rel. L2 and SSIM, the map's mean and rel. L2;
    the summary; the converged figures if any."""
    print(f"  view: camera orbited {entry['orbit']:g} degrees" if entry["orbit"] else "  view: the scene's camera")
    for r in entry["rows"]:
        pm, gm = r.get("photon_map"), r.get("photon_map_gathered")
        seeds = r["field"]["seed_means"]
        spread = f" ({min(seeds):.3f}-{max(seeds):.3f})" if len(seeds) > 1 else ""
        print(f"  g {r['g']:+.2f}{' (G)' if r['in_G'] else '    '}  "
              f"field mean {r['field']['mean']:.3f}{spread} "
              f"rel L2 {r['field']['rel_l2']:.3f} SSIM {r['field']['ssim']:.3f}"
              + (f"   photon map mean {pm['mean']:.3f} rel L2 {pm['rel_l2']:.3f}" if pm else "")
              + (f"   gathered {gm['mean']:.3f} / {gm['rel_l2']:.3f}" if gm else ""))
    print("  " + ", ".join(f"{k} {v:.3f}" for k, v in entry["summary"].items()), flush=True)
    if "converged" in entry:
        c = entry["converged"]
        print("  converged L: " + ", ".join(
            f"{k} {c[k]['rel_l2']:.3f} (noise {c[k]['noise_rel_l2']:.3f}, "
            f"without noise {c[k]['bias_rel_l2']:.3f})"
            for k in ("neural", "neural_final_gather", "photon_map") if k in c))
        print("  converged L rel L2: " + ", ".join(
            f"{k} {v['rel_l2']:.3f}" + (f" (+OIDN {v['oidn']['rel_l2']:.3f})" if "oidn" in v else "")
            for k, v in c.items() if k.startswith("pt_"))
            + f"; reference noise {c['reference']['noise_rel_l2']:.3f}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--configs", nargs="*", default=["default", "phases"], help=f"of {list(CONFIGS)}")
    ap.add_argument("--gs", type=float, nargs="*", default=None, help="g values (default: G and +-0.35, +-0.6)")
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--spp", type=int, default=32, help="field and photon-map samples per pixel")
    ap.add_argument("--ref-spp", type=int, default=512, help="path-traced reference L_i samples per pixel")
    ap.add_argument("--converged", action="store_true", help="also the converged L against denoised path tracing")
    ap.add_argument("--gathered-map", action="store_true",
                    help="also the photon map's L_i one real bounce away (final gather): gathered targets' truth")
    ap.add_argument("--converged-spp", type=int, default=2048,
                    help="path-traced reference L: two independent renders at this spp, averaged")
    ap.add_argument("--converged-neural-spp", type=int, default=256,
                    help="neural and photon-mapped L: two renders at this spp with different seeds, averaged")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--seeds", type=int, nargs="*", default=None,
                    help="fit one field per seed and average the field's figures over them (default: --seed)")
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK)
    ap.add_argument("--orbits", type=float, nargs="+", default=[0.0, 180.0],
                    help="views: the scene's camera orbited by these many degrees about its target (0: its own, 180: "
                         "from the other side; a field's error can depend on the side it is seen from, "
                         "probe_field_directions.py)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    unknown = [c for c in args.configs if c not in CONFIGS]
    if unknown:
        raise SystemExit(f"unknown config(s) {unknown}; available: {', '.join(CONFIGS)}")
    info = machine_info()
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes):
        scene = builtin_scene(name)
        # The fields do not depend on the camera (nor does the cached run): only the view moves.
        views = {orbit: scene.with_overrides(camera=orbit_camera(scene.camera, orbit)) if orbit else scene
                 for orbit in args.orbits}
        for cname in args.configs:
            config = CONFIGS[cname]
            per_view: dict[float, list[list[dict[str, Any]]]] = {orbit: [] for orbit in views}
            first = None
            for seed in args.seeds or [args.seed]:
                pmap, model, facts = train(scene, cname, config, args.work, seed)
                nodes = model.cfg.phases
                midpoints = [(a + b) / 2 for a, b in zip(nodes[:-1], nodes[1:], strict=True)]
                gs = args.gs if args.gs is not None else sorted({round(g, 6) for g in (*nodes, *BETWEEN, *midpoints)})
                for orbit, view in views.items():
                    per_view[orbit].append(score(view, pmap, model, facts["settings"], config, gs, args, args.work,
                                                 orbit, with_map=first is None))
                first = first or (pmap, model, facts)
            pmap, model, facts = first
            print(f"{name} / {cname}: trace {facts['trace_s']:.1f} s, fit {facts['fit_s']:.0f} s")
            for orbit, per_seed in per_view.items():
                rows = over_seeds(per_seed)
                entry = {**facts, "seeds": args.seeds or [args.seed], "orbit": orbit, "rows": rows,
                         "summary": summarize(rows)}
                if args.converged and orbit == args.orbits[0]:
                    entry["converged"] = converged(views[orbit], pmap, model, facts["settings"], config, args,
                                                   args.work, orbit)
                results[result_key(name, cname, orbit)] = entry
                print_entry(entry)
            if len(views) > 1:
                summaries = [results[result_key(name, cname, o)]["summary"] for o in views]
                worst = {k: max(s[k] for s in summaries) for k in summaries[0] if k.startswith("worst_")}
                print("  worst over the views: " + ", ".join(f"{k} {v:.3f}" for k, v in worst.items()), flush=True)
    write_report(args.out, "fidelity", finish_info(info, {}),
                 {k: v for k, v in vars(args).items() if k not in ("work", "out")} | {"work": str(args.work)},
                 configs={k: {"photons": c.photons, "phases": list(c.phases), "preset": c.preset,
                              "overrides": c.overrides, "g_window": c.g_window, "about": c.about}
                          for k, c in CONFIGS.items()},
                 results=results)


if __name__ == "__main__":
    main()
