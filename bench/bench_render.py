"""Render timings, the paper's Table 2 on this machine: neural renderer (Alg. 2) against the path tracer.

For each scene (default: all builtin), at ``--size`` (default 512x512) and 1 spp, best of ``--repeats``
after a warm-up render (numba compilation, onnxruntime session start-up), in one run:

- neural L_d: first interactions + NEE only (``render_neural(estimator=None)``);
- neural L_i: first interactions + field only (``direct=False``), split into hash encoding (position,
  direction), MLP inference and decoding, and the fraction of in-box rays removed by compaction;
- neural L: both, the product's frame;
- path tracer L_d: max 1 scattering vertex (single scattering with NEE);
- path tracer L (max path length 16, NEE + MIS, Russian roulette): also the time of its L_i, which a path
  tracer cannot compute without tracing the whole paths;
- speedups path tracer / neural for L_d, L_i and L. Issue goals: L_i >= 15x, L >= 5x, neural 512x512
  1 spp frame <= 0.25 s on 2 cores. The paper (GPU) reports L_i 10.2x and L 4.6x.

``--hd`` adds one 1280x720 row for the first scene. Bundles: ``--bundle SCENE=PATH`` or, by default,
``bench/results/render/<scene>.pfn``, exported from the training sweep's ``cpu`` run
(``bench/results/training/<scene>/cpu``) when present, else traced (1M photons) and trained with the
``cpu`` preset first (~2-3 min per scene; the result is kept for the next run).

Output: a table on stdout and JSON (default ``bench/results/render.json``).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from common import finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.eval.timing import time_renderers  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "render.json"
BUNDLES = HERE / "results" / "render"
TRAINING = HERE / "results" / "training"


def scenes_with_fields(args: argparse.Namespace) -> Iterator[tuple[str, Scene, Any]]:
    """Per scene of ``args.scenes`` (all builtins by default): its name, the scene at ``args.size`` squared and
    its field's estimator (``args.bundle`` entries SCENE=PATH, else :func:`bundle_for`)."""
    given = dict(b.split("=", 1) for b in args.bundle)
    for name in parse_scenes(args.scenes):
        base = builtin_scene(name)
        field = PhotonField.load(bundle_for(name, base, given), expected_fingerprint=base.fingerprint())
        yield name, base.with_overrides(width=args.size, height=args.size), field.estimator()


def bundle_for(name: str, scene: Scene, given: dict[str, str]) -> Path:
    """The scene's bundle: given, cached, exported from the sweep's cpu run, or trained now."""
    if name in given:
        return Path(given[name])
    path = BUNDLES / f"{name}.pfn"
    if path.exists():
        return path
    from photon_fields.train.export.bundle import export_bundle, write_run_domain

    run = TRAINING / name / "cpu"
    if not (run / "checkpoint.pt").exists():
        run = BUNDLES / f"{name}_run"
        print(f"{name}: no trained field yet, tracing 1M photons and training the cpu preset into {run}")
        train_field(scene, run)
    write_run_domain(run, scene)
    export_bundle(run, path, scene=scene, force=True)
    return path


def train_field(scene: Scene, run: Path, photons: int = 1_000_000, preset: str = "cpu") -> tuple[int, float, float]:
    """Trace ``photons`` records (seed 0) and fit ``preset`` into the run folder ``run``, quietly: the benches' own
    fields. Returns the records traced and the tracing and fitting seconds."""
    from photon_fields.train.fit.loop import fit
    from photon_fields.train.fit.settings import FitSettings
    from photon_fields.train.photons.tracing import trace_photons

    t0 = time.perf_counter()
    traced = trace_photons(scene, photons, seed=0, progress=False)
    trace_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    fit(scene, traced, run, FitSettings.from_preset(preset), progress=False)
    return len(traced), trace_s, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=None, help="builtin scenes (default: all)")
    ap.add_argument("--size", default="512x512")
    ap.add_argument("--hd", action=argparse.BooleanOptionalAction, default=True, help="add one 1280x720 row")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--max-depth", type=int, default=16)
    ap.add_argument("--precision", choices=("fp32", "int8"), default="fp32")
    ap.add_argument("--bundle", action="append", default=[], metavar="SCENE=PATH")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    args = ap.parse_args()
    given = dict(b.split("=", 1) for b in args.bundle)
    w, h = (int(v) for v in args.size.lower().split("x"))
    info = machine_info()
    results: dict[str, Any] = {}
    names = parse_scenes(args.scenes)
    for name in names:
        scene = builtin_scene(name)
        field = PhotonField.load(bundle_for(name, scene, given), precision=args.precision,
                                 expected_fingerprint=scene.fingerprint())
        rows = {f"{w}x{h}": time_renderers(scene, field, (w, h), args.repeats, args.max_depth)}
        if args.hd and name == names[0]:
            rows["1280x720"] = time_renderers(scene, field, (1280, 720), max(1, args.repeats - 1), args.max_depth)
        results[name] = rows
    print(f"\n{'scene':7s} {'size':9s} | {'neural L_d':>10s} {'L_i':>7s} {'L':>7s} | {'PT L_d':>7s} {'L':>7s} | "
          f"{'x L_d':>6s} {'x L_i':>6s} {'x L':>6s} | {'enc ms':>7s} {'mlp ms':>7s} {'compact':>7s}")
    for name, rows in results.items():
        for size, r in rows.items():
            n, p, s, f = r["neural"], r["path_tracer"], r["speedup"], r["neural"]["field_split_s_per_render"]
            enc = (f.get("encode_position_s", 0) + f.get("encode_direction_s", 0)) * 1e3
            print(f"{name:7s} {size:9s} | {n['L_d_s']:10.3f} {n['L_i_s']:7.3f} {n['L_s']:7.3f} | {p['L_d_s']:7.3f} "
                  f"{p['L_s']:7.3f} | {s['L_d']:6.1f} {s['L_i']:6.1f} {s['L']:6.1f} | {enc:7.1f} "
                  f"{f.get('inference_s', 0) * 1e3:7.1f} {n['compaction_removed']:7.1%}")
    info = finish_info(info, {f"{s}/{k}": r for s, rows in results.items() for k, r in rows.items()})
    write_report(Path(args.out), "render", info, {"size": [w, h], "repeats": args.repeats, "max_depth": args.max_depth,
                                                   "precision": args.precision}, results=results)


if __name__ == "__main__":
    main()
