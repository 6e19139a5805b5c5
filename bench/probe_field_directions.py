"""Probe: the field against its own photon map over every direction a camera could see a point from.

``bench_fidelity.py`` judges a field by a few cameras per scene (the scene's own and the other side, ``--orbits``),
so a field whose error depends on the view direction reads as bright or dark depending on where they stand, and one
seed's mean moves by a few percent. This
probe asks the field and its training target the same question at many points at once: N visible points (the
first collisions of rays entering the volume from every direction, with those rays' directions: three quarters of
the training samples are drawn so, ``train/fit/visible_points.py``) and, per g, the ratio of the field's mean L_i
to the photon map's (``PhotonMapEstimator`` at the fit's final radius and K: what the fit's targets estimate), over
all of them and binned by the cosine between the view ray and the scene's first light (its direction of travel
for a directional light, the direction from the volume's centre for a point light). The fields and maps are
``bench_fidelity.py``'s (the same configuration and seed give the same run, reused from ``--work``).

No path tracer is involved: this measures what the fit makes of its targets, not the targets' own bias (which
``bench_fidelity.py``'s photon-map column shows). Its noise is the map's at 100k points: ~0.2 % per ratio overall.

Output: a table on stdout and JSON (default ``bench/results/field_directions.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_fidelity import CONFIGS, final_radius, train  # noqa: E402
from common import finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.photons.estimate import PhotonMapEstimator  # noqa: E402
from photon_fields.runtime.scene.lights import DIRECTIONAL  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402
from photon_fields.train.eval.field_images import TorchFieldEstimator  # noqa: E402
from photon_fields.train.fit.visible_points import visible_points  # noqa: E402

HERE = Path(__file__).resolve().parent
#: Bins of the cosine between the view ray's travel direction and the first light's.
COS_EDGES = (-1.0, -0.5, 0.0, 0.3, 0.6, 0.8, 0.9, 0.95, 1.0)


def light_axis(scene: Scene) -> np.ndarray:
    """Unit direction the first light's light travels in (from the volume's centre for a point light)."""
    kind, vec, _ = scene.packed_lights()
    if kind[0] == DIRECTIONAL:
        axis = np.asarray(vec[0], dtype=np.float64)
    else:
        m = scene.medium()
        axis = (m.bmin + 0.5 * m.bsize) - np.asarray(vec[0], dtype=np.float64)
    return axis / np.linalg.norm(axis)


def ratios(field: np.ndarray, target: np.ndarray, cos: np.ndarray) -> dict[str, Any]:
    """Mean field / mean target overall and per cosine bin (field and target: (n,) luminance-like sums)."""
    bins = []
    for lo, hi in zip(COS_EDGES[:-1], COS_EDGES[1:], strict=True):
        sel = (cos > lo) & (cos <= hi) if lo > -1.0 else cos <= hi
        bins.append({"cos": [lo, hi], "points": int(sel.sum()),
                     "ratio": float(field[sel].mean() / max(target[sel].mean(), 1e-30)) if sel.any() else None})
    return {"ratio": float(field.mean() / max(target.mean(), 1e-30)), "bins": bins}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--config", default="default", choices=list(CONFIGS))
    ap.add_argument("--seeds", type=int, nargs="*", default=[0])
    ap.add_argument("--gs", type=float, nargs="*", default=[-0.75, -0.35, 0.0, 0.35, 0.75])
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--work", type=Path, default=HERE / "results" / "fidelity")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "field_directions.json")
    args = ap.parse_args(argv)
    info = machine_info()
    config = CONFIGS[args.config]
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes):
        scene = builtin_scene(name)
        m = scene.medium()
        x, d = visible_points(m, np.random.default_rng(12345), args.points)
        cos = d @ light_axis(scene)
        xt, dt = np.ascontiguousarray(x.T), np.ascontiguousarray(d.T)  # the estimators' (3, n) layout
        rows = []
        for seed in args.seeds:
            pmap, model, facts = train(scene, args.config, config, args.work, seed)
            s = facts["settings"]
            target = PhotonMapEstimator(pmap, m, k=s["k"], radius=final_radius(s), g_window=config.g_window)
            field = TorchFieldEstimator(model, m)
            for g in args.gs:
                q = target(xt, dt, g).sum(axis=0)
                f = field(xt, dt, g).sum(axis=0)
                row = {"seed": seed, "g": g, **ratios(f, q, cos)}
                rows.append(row)
                cells = " ".join(f"{b['ratio']:.3f}" if b["ratio"] is not None else "  -  " for b in row["bins"])
                print(f"{name} seed {seed} g {g:+.2f}: all {row['ratio']:.3f} | by cos to the light {cells}",
                      flush=True)
        results[name] = rows
    print("cosine bins: " + " ".join(f"({lo:+.2f},{hi:+.2f}]" for lo, hi in zip(COS_EDGES[:-1], COS_EDGES[1:],
                                                                                   strict=True)))
    write_report(args.out, "probe_field_directions", finish_info(info, {}),
                 {"config": args.config, "seeds": args.seeds, "gs": args.gs, "points": args.points,
                  "cos_edges": list(COS_EDGES)}, scenes=results)


if __name__ == "__main__":
    main()
