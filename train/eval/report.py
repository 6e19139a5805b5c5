"""``pfn-eval``: the paper's evaluation (Sec. 4) on this machine, from scratch, into ``docs/results.md``.

One command traces, trains, exports and renders everything it reports; no number in the report is typed
by hand. Sections (paper figure / table in brackets):

1. Training [Fig. 7, Fig. 9, Table 1]: loss curves and wall time of the ``cpu`` preset with the naive and
   the staggered KNN schedule, at several photon counts, on the first scene.
2. Tracing speed [Table 3]: seconds per 1M / 3M photons (Alg. 1) for every scene.
3. Render timings [Table 2]: L_d, L_i, L of the neural renderer and of the path tracer (max path length
   16), 1 spp, with speedups (:mod:`photon_fields.runtime.eval.timing`), for every scene.
4. Image quality [Fig. 8]: L_d, L_i and L of the neural renderer, the photon-map renderer, the path
   tracer and the ray marcher; relative L2 and SSIM of the neural L_i against the photon-map L_i and of
   every L against the path-traced reference.
5. Noise against spp [Fig. 11]: relative L2 of L against a high-spp path-traced reference for the neural
   renderer at 1 / 4 / 8 spp and the path tracer at 1 / 4 / 8 / 16 spp, with wall times; checks the
   paper's claim that the neural renderer at 1 spp beats the path tracer at 4 spp.
6. Phase awareness [Fig. 10]: the field trained on the default G, evaluated at g in {-0.75, -0.35,
   0, 0.35, 0.75} against photon maps traced at each g (:mod:`photon_fields.train.eval.field_images`).

Every stage is seeded from ``--seed``; the seeds and settings are recorded in ``docs/results.json``.
``--quick`` shrinks everything (one scene, small maps and images, the ``tiny`` preset) to check the
command end to end in about a minute; its numbers mean nothing.

Outputs (``--out``, default ``docs``): ``results.md``, ``results.json`` and ``results/*.png``; the work
folder (``--work``, default ``eval_work``) keeps maps, runs and bundles, and EXRs of the section-4 images.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np  # noqa: E402

from photon_fields.models_spec import DEFAULT_MAP_PHASES, DEFAULT_PHASES  # noqa: E402
from photon_fields.runtime.cli.common import (  # noqa: E402
    OneLineArgumentParser,
    check_seed,
    guarded,
    positive_int,
    refuse_to_replace,
)
from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.runtime.scene.scene import BUILTIN_SCENES  # noqa: E402
from photon_fields.runtime.threads import set_threads

PHASE_SWEEP = (-0.75, -0.35, 0.0, 0.35, 0.75)


@dataclass(frozen=True)
class EvalPlan:
    """Sizes of everything the evaluation renders and trains (full or ``--quick``)."""

    scenes: tuple[str, ...]
    preset: str
    steps: int | None  # None: the preset's
    photon_counts: tuple[int, ...]  # section 1
    trace_counts: tuple[int, ...]  # section 2
    train_photons: int  # the field of sections 3-6
    timing_size: tuple[int, int]
    timing_repeats: int
    image_size: int
    image_spp: int
    reference_spp: int
    noise_size: int
    noise_reference_spp: int
    eval_size: int
    phases: tuple[float, ...]  # the maps' phase set: the one the preset trains from


FULL = EvalPlan(tuple(BUILTIN_SCENES), "cpu", None, (300_000, 1_000_000), (1_000_000, 3_000_000), 1_000_000,
                (512, 512), 3, 256, 4, 256, 128, 1024, 128, DEFAULT_MAP_PHASES)
QUICK = EvalPlan(("blobs",), "tiny", 30, (20_000,), (20_000,), 30_000, (48, 48), 1, 32, 2, 16, 32, 32, 32,
                 DEFAULT_PHASES)


def build_parser() -> argparse.ArgumentParser:
    p = OneLineArgumentParser(prog="pfn-eval", description=__doc__.split("\n")[0],
                              formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scenes", default=None, help="comma-separated builtin scenes (default: all; --quick: blobs)")
    p.add_argument("--quick", action="store_true", help="tiny settings: checks the command, numbers mean nothing")
    p.add_argument("--size", type=int, default=None,
                   help="side of the section-4 images in pixels (default: 256; --quick: 32)")
    p.add_argument("--spp", type=int, default=None,
                   help="samples per pixel of the section-4 neural / photon-map / ray-marched images (default 4)")
    p.add_argument("--seed", type=int, default=0, help="base seed of every stage")
    p.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")
    p.add_argument("--out", default="docs", help="report folder (results.md, results.json, results/*.png)")
    p.add_argument("--work", default="eval_work", help="maps, runs, bundles and EXRs (finished runs are reused)")
    p.add_argument("--force", action="store_true", help="replace an earlier report in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


# --------------------------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------------------------


def _plt():  # noqa: ANN202
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> str:
    from photon_fields.runtime.io.atomic import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    _plt().close(fig)
    return path.name


def _say(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def _md_table(header: list[str], rows: list[list[Any]]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.3g}" if abs(v) < 1000 else f"{v:,.0f}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


class Evaluation:
    """Holds the shared artefacts (maps, fields) between sections; each ``section_*`` returns markdown."""

    def __init__(self, plan: EvalPlan, out: Path, work: Path, seed: int, threads: int | None, progress: bool):
        self.plan, self.out, self.work, self.seed = plan, out, work, seed
        self.threads, self.progress = threads, progress
        self.figs = out / "results"
        self.data: dict[str, Any] = {"plan": plan.__dict__, "seed": seed}
        self._maps: dict[tuple[str, int], Any] = {}
        self._fields: dict[str, Any] = {}

    # -- artefacts ---------------------------------------------------------------------------------
    def scene(self, name: str, size: tuple[int, int] | None = None):  # noqa: ANN201
        from photon_fields.runtime.scene.scene import builtin_scene

        s = builtin_scene(name)
        return s.with_overrides(width=size[0], height=size[1]) if size else s

    def photon_map(self, name: str, photons: int):  # noqa: ANN201
        from photon_fields.runtime.photons.photon_map import PhotonMap
        from photon_fields.train.photons.tracing import trace_photons

        key = (name, photons)
        if key not in self._maps:
            path = self.work / name / f"map_{photons}_p{len(self.plan.phases)}_s{self.seed}.npz"
            if path.exists():
                self._maps[key] = PhotonMap.load(path, expected_fingerprint=self.scene(name).fingerprint())
            else:
                pmap = trace_photons(self.scene(name), photons, phases=self.plan.phases, seed=self.seed,
                                     progress=self.progress)
                pmap.save(path)
                self._maps[key] = pmap
        return self._maps[key]

    def run(self, name: str, photons: int, schedule: str) -> tuple[Path, dict[str, Any]]:
        """A fit of the plan's preset on the scene's map (kept in the work folder and reused)."""
        from photon_fields.train.export.bundle import write_run_domain
        from photon_fields.train.fit.checkpoint import finished_run
        from photon_fields.train.fit.loop import fit
        from photon_fields.train.fit.settings import FitSettings

        run = self.work / name / f"run_{photons}_{schedule}"
        settings = FitSettings.from_preset(self.plan.preset, steps=self.plan.steps, schedule_kind=schedule,
                                           seed=self.seed)
        log = finished_run(run, settings)
        if log is not None:
            return run, log
        scene = self.scene(name)
        run.mkdir(parents=True, exist_ok=True)
        write_run_domain(run, scene)
        return run, fit(scene, self.photon_map(name, photons), run, settings, progress=self.progress).log

    def field(self, name: str):  # noqa: ANN201
        """The scene's runtime field: the naive-schedule run at ``train_photons``, exported and loaded."""
        from photon_fields.runtime.field.field import PhotonField
        from photon_fields.train.export.bundle import export_bundle

        if name not in self._fields:
            run, _ = self.run(name, self.plan.train_photons, "naive")
            bundle = export_bundle(run, run / "field.pfn", scene=self.scene(name), force=True).path
            self._fields[name] = PhotonField.load(bundle, threads=self.threads,
                                                  expected_fingerprint=self.scene(name).fingerprint())
        return self._fields[name]

    # -- 1. training ---------------------------------------------------------------------------------
    def section_training(self) -> str:
        name = self.plan.scenes[0]
        plt = _plt()
        fig, (ax_step, ax_wall) = plt.subplots(1, 2, figsize=(11, 4))
        rows, data = [], {}
        for photons in self.plan.photon_counts:
            for schedule in ("naive", "staggered"):
                _say(f"1. training: {name}, {photons:,} photons, {schedule} schedule")
                _, log = self.run(name, photons, schedule)
                t = log["totals"]
                val = t.get("final_validation") or {}
                label = f"{photons / 1e6:g}M {schedule}"
                loss = np.asarray(log["per_step"]["loss"], dtype=float)
                k = max(1, len(loss) // 50)
                smooth = np.convolve(loss, np.ones(k) / k, mode="valid")
                ax_step.plot(np.arange(len(smooth)) + k - 1, smooth, label=label)
                wall = np.asarray(log["per_step"]["wall_s"])
                vs = [v["step"] for v in log["validation"]]
                ax_wall.plot([wall[s - 1] for s in vs], [v["val_loss"] for v in log["validation"]], "o-", label=label)
                radii = "/".join(f"{s['radius_percent']:.3g}" for s in log["schedule"]["stages"])
                rows.append([f"{photons:,}", schedule, radii, t["steps_done"], t["wall_s"],
                             t["targets_s_per_step"] * 1e3, t["train_s_per_step"] * 1e3, t["final_loss"],
                             val.get("val_loss", float("nan")), val.get("val_rel_l1", float("nan"))])
                data[label] = {"wall_s": t["wall_s"], "final_loss": t["final_loss"], "validation": val,
                               "first_validation": log["validation"][0] if log["validation"] else None,
                               "loss": log["settings"]["loss"], "schedule": log["schedule"]}
        for ax, xl in ((ax_step, "step"), (ax_wall, "wall time (s)")):
            ax.set_yscale("log")
            ax.set_xlabel(xl)
            ax.legend(fontsize=8)
        ax_step.set_ylabel("training loss (relative L2; running mean)")
        ax_wall.set_ylabel("validation loss (held-out points)")
        png = _save(fig, self.figs / "training.png")
        self.data["training"] = data
        return (f"## 1. Training (Fig. 7, Fig. 9, Table 1)\n\nScene `{name}`, preset `{self.plan.preset}`, "
                f"seed {self.seed}. Radii in % of the box's longest side (Table-1 units, `train.fit.schedule`).\n\n"
                + _md_table(["photons", "schedule", "radii %", "steps", "wall s", "targets ms/step",
                             "train ms/step", "final loss", "val loss", "val rel. L1"], rows)
                + f"\n\n![training curves](results/{png})\n")

    # -- 2. tracing ----------------------------------------------------------------------------------
    def section_tracing(self) -> str:
        from photon_fields.train.photons.tracing import trace_photons

        rows, data = [], {}
        for name in self.plan.scenes:
            scene = self.scene(name)
            trace_photons(scene, 1000, progress=False)  # compile / load the numba cache outside the timing
            for photons in self.plan.trace_counts:
                _say(f"2. tracing: {name}, {photons:,} photons")
                t0 = time.perf_counter()
                pmap = trace_photons(scene, photons, phases=self.plan.phases, seed=self.seed, progress=self.progress)
                dt = time.perf_counter() - t0
                if photons == self.plan.train_photons:
                    self._maps[(name, photons)] = pmap
                    pmap.save(self.work / name / f"map_{photons}_p{len(self.plan.phases)}_s{self.seed}.npz")
                rows.append([name, f"{photons:,}", dt, len(pmap) / dt / 1e6, pmap.emitted])
                data[f"{name}/{photons}"] = {"seconds": dt, "records": len(pmap), "emitted": pmap.emitted}
        self.data["tracing"] = data
        return (f"## 2. Photon tracing (Table 3)\n\nAlg. 1, {len(self.plan.phases)} phases, max 16 collisions, "
                f"{os.cpu_count()} cores.\n\n"
                + _md_table(["scene", "photons", "seconds", "M records/s", "paths"], rows) + "\n")

    # -- 3. render timings -------------------------------------------------------------------------
    def section_timings(self) -> str:
        from photon_fields.runtime.eval.timing import time_renderers

        rows, data = [], {}
        for name in self.plan.scenes:
            field = self.field(name)
            _say(f"3. render timings: {name} at {self.plan.timing_size[0]}x{self.plan.timing_size[1]}")
            r = time_renderers(self.scene(name), field, self.plan.timing_size, self.plan.timing_repeats)
            n, p, s = r["neural"], r["path_tracer"], r["speedup"]
            f = n["field_split_s_per_render"]
            rows.append([name, n["L_d_s"], n["L_i_s"], n["L_s"], p["L_d_s"], p["L_s"], s["L_d"], s["L_i"], s["L"],
                         (f.get("encode_position_s", 0) + f.get("encode_direction_s", 0)) * 1e3,
                         f.get("inference_s", 0) * 1e3, n["compaction_removed"], r["other_cores"]])
            data[name] = r
        self.data["timings"] = data
        w, h = self.plan.timing_size
        return (f"## 3. Render timings (Table 2)\n\n{w}x{h}, 1 spp, best of {self.plan.timing_repeats}; path "
                "tracer max path length 16 (its L_i costs its whole L). Seconds; speedup = path tracer / neural. "
                "Field time split: hash encoding and MLP inference (ms per frame). `compacted` = share of "
                "in-box rays without a first interaction. `load` = cores kept busy by other processes.\n\n"
                + _md_table(["scene", "neural L_d", "neural L_i", "neural L", "PT L_d", "PT L (= L_i)", "x L_d",
                             "x L_i", "x L", "encode ms", "MLP ms", "compacted", "load"], rows) + "\n")

    # -- 4. image quality ----------------------------------------------------------------------------
    def section_images(self) -> str:
        from photon_fields.runtime.eval.metrics import relative_l2, ssim
        from photon_fields.runtime.io.images import auto_exposure_stops, tonemap_srgb, write_image_set
        from photon_fields.runtime.renderers.neural import render_neural
        from photon_fields.runtime.renderers.path_tracer import render_path_traced
        from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped
        from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
        from photon_fields.train.eval.field_images import map_at_g

        plt = _plt()
        size, spp = self.plan.image_size, self.plan.image_spp
        md = [f"## 4. Image quality (Fig. 8)\n\n{size}x{size}; neural, photon map and ray marcher {spp} spp, "
              f"path tracer {self.plan.reference_spp} spp (the reference). Each row of a figure is tone-mapped "
              "with the path tracer's exposure for that layer.\n"]
        rows, data = [], {}
        for name in self.plan.scenes:
            _say(f"4. images: {name}")
            scene = self.scene(name, (size, size))
            pmap = self.photon_map(name, self.plan.train_photons)
            pmap = map_at_g(scene, pmap, scene.g, seed=self.seed + 1)
            neural = render_neural(scene, self.field(name).estimator(), spp=spp, seed=self.seed, progress=False)
            renders = {  # the photon map with the neural image's camera estimator (auto's choice): the same samples
                "neural": neural,
                "photon map": render_photon_mapped(scene, pmap, spp=spp, seed=self.seed, progress=False,
                                                   camera=str(neural.stats["camera_estimator"])),
                "ray marcher": render_ray_marched(scene, spp=spp, seed=self.seed, progress=False),
                "path tracer": render_path_traced(scene, spp=self.plan.reference_spp, seed=self.seed + 1,
                                                  progress=self.progress),
            }
            ref = renders["path tracer"].layers
            row_stops = {layer: auto_exposure_stops(ref[layer]) for layer in ("L_d", "L_i", "L")}
            for method, r in renders.items():  # one exposure for every PNG: the reference's L
                write_image_set(self.work / name / f"fig8_{method.replace(' ', '_')}.exr", r.layers,
                                exposure=row_stops["L"])
            fig, axes = plt.subplots(3, 4, figsize=(12, 9.4))
            for row, layer in enumerate(("L_d", "L_i", "L")):
                stops = row_stops[layer]
                for col, (method, r) in enumerate(renders.items()):
                    axes[row, col].imshow(tonemap_srgb(r.layers[layer], stops))
                    axes[row, col].set_title(f"{method}: {layer}", fontsize=9)
                    axes[row, col].axis("off")
            fig.suptitle(f"{name}, g = {scene.g:g}")
            fig.tight_layout()
            png = _save(fig, self.figs / f"images_{name}.png")
            nl, pl = renders["neural"].layers, renders["photon map"].layers
            scores = {"neural_L_i_vs_photon_map_L_i": {"rel_l2": relative_l2(nl["L_i"], pl["L_i"]),
                                                        "ssim": ssim(nl["L_i"], pl["L_i"])}}
            for method, r in renders.items():
                if method != "path tracer":
                    scores[f"{method}_L_vs_path_tracer"] = {"rel_l2": relative_l2(r.layers["L"], ref["L"]),
                                                            "ssim": ssim(r.layers["L"], ref["L"])}
            rows.append([name, scene.g, scores["neural_L_i_vs_photon_map_L_i"]["rel_l2"],
                         scores["neural_L_i_vs_photon_map_L_i"]["ssim"],
                         *(scores[f"{m}_L_vs_path_tracer"][k] for m in ("neural", "photon map", "ray marcher")
                           for k in ("rel_l2", "ssim"))])
            data[name] = {**scores, "exposure_stops": row_stops}
            md.append(f"![{name}](results/{png})\n")
        self.data["images"] = data
        md.insert(1, _md_table(["scene", "g", "neural L_i vs PM: rel. L2", "SSIM", "neural L: rel. L2", "SSIM",
                                "photon map L: rel. L2", "SSIM", "ray marcher L: rel. L2", "SSIM"], rows) + "\n")
        return "\n".join(md)

    # -- 5. noise against spp ----------------------------------------------------------------------------
    def section_noise(self) -> str:
        from photon_fields.runtime.eval.metrics import relative_l2
        from photon_fields.runtime.renderers.neural import render_neural
        from photon_fields.runtime.renderers.path_tracer import render_path_traced

        name = self.plan.scenes[0]
        _say(f"5. noise against spp: {name}")
        size = self.plan.noise_size
        scene = self.scene(name, (size, size))
        ref = render_path_traced(scene, spp=self.plan.noise_reference_spp, seed=self.seed + 100,
                                 progress=self.progress).layers["L"]
        est = self.field(name).estimator()
        curves: dict[str, list[tuple[int, float, float]]] = {"neural": [], "path tracer": []}
        for method, spps in (("neural", (1, 4, 8)), ("path tracer", (1, 4, 8, 16))):
            for spp in spps:
                t0 = time.perf_counter()
                if method == "neural":
                    img = render_neural(scene, est, spp=spp, seed=self.seed + spp, progress=False).layers["L"]
                else:
                    img = render_path_traced(scene, spp=spp, seed=self.seed + spp, progress=False).layers["L"]
                curves[method].append((spp, time.perf_counter() - t0, relative_l2(img, ref)))
        plt = _plt()
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 4))
        for method, pts in curves.items():
            a1.plot([p[0] for p in pts], [p[2] for p in pts], "o-", label=method)
            a2.plot([p[1] for p in pts], [p[2] for p in pts], "o-", label=method)
        for ax, xl in ((a1, "samples per pixel"), (a2, "wall time (s)")):
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel(xl)
            ax.set_ylabel("relative L2 of L vs reference")
            ax.legend()
        png = _save(fig, self.figs / "noise.png")
        n1 = curves["neural"][0][2]
        pt4 = next(e for s, _, e in curves["path tracer"] if s == 4)
        self.data["noise"] = {"curves": curves, "neural_1spp_beats_pt_4spp": bool(n1 < pt4)}
        rows = [[m, s, t, e] for m, pts in curves.items() for s, t, e in pts]
        verdict = "holds" if n1 < pt4 else "does not hold"
        return (f"## 5. Noise against spp (Fig. 11)\n\nScene `{name}`, {size}x{size}; reference: path tracer at "
                f"{self.plan.noise_reference_spp} spp. The neural renderer's error includes its bias (it "
                "converges to its own, slightly different, image).\n\n"
                + _md_table(["method", "spp", "seconds", "rel. L2 vs reference"], rows)
                + f"\n\nThe paper's claim \"neural at 1 spp beats the path tracer at 4 spp\" {verdict} here "
                f"(rel. L2 {n1:.3g} vs {pt4:.3g}).\n\n![noise](results/{png})\n")

    # -- 6. phase awareness ---------------------------------------------------------------------------
    def section_phases(self) -> str:
        from photon_fields.runtime.photons.photon_map import find_phase
        from photon_fields.train.eval.field_images import evaluate_field, reference_maps
        from photon_fields.train.fit.checkpoint import load_checkpoint

        name = self.plan.scenes[0]
        _say(f"6. phase awareness: {name}")
        scene = self.scene(name)
        pmap = self.photon_map(name, self.plan.train_photons)
        indep = reference_maps(scene, pmap, PHASE_SWEEP, seed=self.seed + 7, progress=self.progress)
        run, _ = self.run(name, self.plan.train_photons, "naive")
        model, _ = load_checkpoint(run / "checkpoint.pt")
        res = evaluate_field(scene, model, [indep], PHASE_SWEEP, size=self.plan.eval_size, spp=2, seed=self.seed)
        self.data["phases"] = res
        rows = [[g, "yes" if find_phase(pmap.phases, float(g)) is not None else "no", v["rel_l2"], v["ssim"]]
                for g, v in res["per_g"].items()]
        plt = _plt()
        fig, ax = plt.subplots(figsize=(5, 3.5))
        gs = [float(g) for g in res["per_g"]]
        ax.plot(gs, [v["rel_l2"] for v in res["per_g"].values()], "o-")
        for g in pmap.phases:
            ax.axvline(g, color="0.7", ls="--", lw=0.8)
        ax.set_xlabel("g (dashed: training phases G)")
        ax.set_ylabel("rel. L2, field L_i vs photon map L_i")
        png = _save(fig, self.figs / "phases.png")
        return (f"## 6. Phase awareness (Fig. 10)\n\nScene `{name}`: the field trained on G = "
                f"{list(pmap.phases)} against photon maps traced at each g (independent of the training map, "
                f"same photons per phase), {res['views']} held-out views, {res['size'][0]}x{res['size'][1]}.\n\n"
                + _md_table(["g", "in G", "rel. L2", "SSIM"], rows) + f"\n\n![phases](results/{png})\n")


def run_eval(args: argparse.Namespace) -> Path:
    from photon_fields.runtime.io.atomic import atomic_write_text

    check_seed(args.seed)
    plan = QUICK if args.quick else FULL
    if args.scenes is not None:
        names = tuple(s for s in args.scenes.split(",") if s)
        unknown = [s for s in names if s not in BUILTIN_SCENES]
        if unknown or not names:
            raise InputError("--scenes", f"unknown scene(s) {unknown or [args.scenes]}; builtin scenes: "
                             f"{', '.join(BUILTIN_SCENES)}")
        plan = EvalPlan(**{**plan.__dict__, "scenes": names})
    if args.size is not None:
        plan = EvalPlan(**{**plan.__dict__, "image_size": positive_int("--size", args.size, 8192)})
    if args.spp is not None:
        plan = EvalPlan(**{**plan.__dict__, "image_spp": positive_int("--spp", args.spp, 1 << 16)})
    set_threads(args.threads)
    out, work = Path(args.out), Path(args.work)
    # The report is replaced only with --force; maps and runs in --work are reused on purpose, not replaced.
    refuse_to_replace([out / "results.md", out / "results.json"], args.force, f"an earlier report in {str(out)!r}")
    for s in plan.scenes:
        (work / s).mkdir(parents=True, exist_ok=True)
    ev = Evaluation(plan, out, work, args.seed, args.threads, not args.quiet)
    t0 = time.perf_counter()
    parts = [ev.section_tracing(), ev.section_training(), ev.section_timings(), ev.section_images(),
             ev.section_noise(), ev.section_phases()]
    parts[0], parts[1] = parts[1], parts[0]  # traced first (maps reused), reported in the paper's order

    wall = time.perf_counter() - t0
    ev.data["wall_s"] = wall
    from photon_fields.runtime.eval.machine import cpu_record, cpu_summary

    ev.data["cpu"] = cpu_record()
    header = (f"# Evaluation on this machine\n\nGenerated by `pfn-eval{' --quick' if args.quick else ''}` "
              f"(seed {args.seed}) on {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores of {cpu_summary()}, "
              f"in {wall / 60:.1f} "
              f"min; every number and figure below comes from that run (raw data: `results.json`).\n")
    atomic_write_text(out / "results.json", json.dumps(ev.data, indent=1, default=_jsonable) + "\n")
    path = out / "results.md"
    atomic_write_text(path, header + "\n" + "\n".join(parts))
    return path


def _jsonable(v: Any) -> Any:
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return str(v)


@guarded
def _main(argv: Sequence[str] | None = None) -> int:
    path = run_eval(build_parser().parse_args(argv))
    print(f"wrote {path} (figures in {path.parent / 'results'})")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    sys.exit(_main(argv))
