"""Probe: how much of a field's mean error at one g is the fit's own variability (issue 13's 3 % goal).

For fields fitted to one photon map (``--runs``: run folders or checkpoints of ``pfn-train fit --map MAP``, e.g.
two seeds and a longer fit), at every g of ``--gs``:

- ``image``: the field's mean L_i over the photon map's in the scene's view (the same first interactions, the map
  with the kernel in g at the fit's K and final radius): what ``bench_fidelity.py`` reports as field / path tracer,
  divided by the map's own share of it;
- ``seen``: the field's mean over its training targets at ``--points`` first collisions of lines from every
  direction (``visible_points``, the ``visible`` sampling's half), with the line's direction: the mean the fit
  itself is asked to match, over every view at once.

Its spread over g, per field, and whether two fields' patterns agree (systematic) or not (the fit's variability),
is the question. Output: a table on stdout and JSON (default ``bench/results/fit_variability.json``).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import finish_info, machine_info, write_report  # noqa: E402

from photon_fields.models_spec import PHASE_WINDOW  # noqa: E402
from photon_fields.models_spec.encoding import direction_input, normalize_position  # noqa: E402
from photon_fields.runtime.photons.photon_map import PhotonMap  # noqa: E402
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped  # noqa: E402
from photon_fields.runtime.scene.scene import builtin_scene  # noqa: E402
from photon_fields.runtime.wavefront.first_interaction import render_first_interaction  # noqa: E402
from photon_fields.train.eval.field_images import TorchFieldEstimator  # noqa: E402
from photon_fields.train.fit.checkpoint import load_checkpoint  # noqa: E402
from photon_fields.train.fit.settings import FitSettings  # noqa: E402
from photon_fields.train.fit.targets import TargetSampler  # noqa: E402
from photon_fields.train.fit.visible_points import visible_points  # noqa: E402

HERE = Path(__file__).resolve().parent


def seen_ratio(model: torch.nn.Module, sampler: TargetSampler, x: np.ndarray, d: np.ndarray, g: float,
               radius: float, rng: np.random.Generator) -> float:
    """sum of the field's L over sum of its targets at (x, d, g), the photons chosen as the fit chooses them (g's
    own kernel from the binned index, or with phases ``TargetSampler.sources``)."""
    gg = np.full(x.shape[0], g)
    ph = np.zeros(x.shape[0], dtype=np.int64) if sampler.g_sampling == "window" else sampler.sources(rng, gg)
    q, _ = sampler.estimate(x, d, gg, ph, radius)
    m = sampler.medium
    with torch.no_grad():
        L = model.radiance(torch.from_numpy(normalize_position(x, m.bmin, m.bsize)),
                           torch.from_numpy(direction_input(d)),
                           torch.from_numpy(gg.astype(np.float32).reshape(-1, 1))).double().numpy()
    return float(L.sum() / q.sum())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="shell")
    ap.add_argument("--map", type=Path, required=True, help="the photon map the fields were fitted to")
    ap.add_argument("--runs", type=Path, nargs="+", required=True, help="run folders (checkpoint.pt, log.json)")
    ap.add_argument("--gs", type=float, nargs="*", default=[round(-0.75 + 0.05 * i, 2) for i in range(31)])
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--points", type=int, default=8192)
    ap.add_argument("--out", type=Path, default=HERE / "results" / "fit_variability.json")
    args = ap.parse_args(argv)
    info = machine_info()
    scene = builtin_scene(args.scene)
    m = scene.medium()
    pmap = PhotonMap.load(args.map)
    settings = FitSettings.from_preset("cpu")
    radius = settings.resolve_schedule(len(pmap)).radii_percent[-1] / 100.0
    sampler = TargetSampler(pmap, m, k=settings.k, psi=settings.psi, seed=99, sampling="visible", g_sampling="window")
    x, d = visible_points(m, np.random.default_rng(5), args.points)
    maps = {}
    rows: dict[str, list[dict[str, float]]] = {}
    for run in args.runs:
        model, _ = load_checkpoint(run / "checkpoint.pt", scene.fingerprint())
        estimator = TorchFieldEstimator(model, m)
        rng = np.random.default_rng(6)
        rows[str(run)] = []
        for g in args.gs:
            view = scene.with_overrides(g=g, width=args.size, height=args.size)
            if g not in maps:
                maps[g] = float(render_photon_mapped(view, pmap, k=settings.k, radius=radius, spp=args.spp, seed=7,
                                                     progress=False, g_window=PHASE_WINDOW, camera="forced",
                                                     final_gather_after=None).layers["L_i"].mean())
            li = render_first_interaction(view, estimator, spp=args.spp, seed=7, progress=False).layers["L_i"]
            row = {"g": g, "image": float(li.mean()) / maps[g],
                   "seen": seen_ratio(model, sampler, x, d, g, radius, rng)}
            rows[str(run)].append(row)
            print(f"{run.name:>16} g {g:+.2f}: image {row['image']:.4f}  seen {row['seen']:.4f}", flush=True)
    summary = {run: {key: {"min": min(r[key] for r in rs), "max": max(r[key] for r in rs),
                           "sd": float(np.std([r[key] for r in rs]))} for key in ("image", "seen")}
               for run, rs in rows.items()}
    for run, s in summary.items():
        print(f"{Path(run).name}: image {s['image']['min']:.3f}-{s['image']['max']:.3f} (sd {s['image']['sd']:.4f}), "
              f"seen {s['seen']['min']:.3f}-{s['seen']['max']:.3f} (sd {s['seen']['sd']:.4f})")
    write_report(args.out, "probe_fit_variability", finish_info(info, {}),
                 {k: str(v) for k, v in vars(args).items()}, rows=rows, summary=summary)


if __name__ == "__main__":
    main()
