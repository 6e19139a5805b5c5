"""A frame-time goal stated against an issue's day, measured against that day's code in the same run.

Issue 14 asks for "vortex neural 1 spp rel. L2 <= 0.35 at <= 1.5x today's frame time": a ratio to the renderer of
the day the issue was filed (commit 5ace6b4, 2026-11-24), on whatever machine the bench runs on, since this
machine's speed drifts between sessions. This bench extracts ``--base`` (``git archive``, the package renamed
``pf_base`` as ``ab_tracking.py`` does), trains the base's own field for the scene with the base's own trainer
(``pfn-train all``, cached in ``--work``), and in one process alternates the base's neural 1-spp frame (its
default camera estimator) with the working tree's for each of ``--cameras`` (``common.alternated_median_ms``,
``--rounds`` rounds). Errors: rel. L2 of L against the working tree's path tracer at ``--ref-spp`` (cached),
mean over the rounds' seeds. Prints and writes (JSON with the machine record) each configuration's ms, ms over
the base's, rel. L2, and whether it meets ``--max-error`` within ``--max-ratio`` of the base's frame.

    .venv/bin/python bench/bench_issue_baseline.py --bundle /tmp/hb/vortex/field.pfn   # ~3 min with the caches
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np  # noqa: E402
from ab_tracking import extract_base  # noqa: E402
from bench_equal_error import reference  # noqa: E402
from common import alternated_median_ms, finish_info, machine_info, write_report  # noqa: E402

from photon_fields.runtime.eval.metrics import relative_l2  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.renderers.neural import render_neural  # noqa: E402
from photon_fields.runtime.scene.scene import builtin_scene  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_WORK = HERE / "results" / "issue_baseline"
#: The code of the day issue 14 was filed (its table: vortex 25 ms at rel. L2 0.70).
ISSUE_14_DAY = "5ace6b4"


def base_package(commit: str, work: Path) -> Path:
    """The folder holding ``pf_base`` for ``commit`` (extracted once into ``work``; numba's cache stays with it)."""
    root = work / f"base_{commit}"
    if not (root / "pf_base").exists():
        extract_base(commit, root)
    return root


def base_bundle(root: Path, scene: str, work: Path, commit: str) -> Path:
    """The base's field for ``scene``, trained by the base's own ``pfn-train all`` when not cached."""
    run = work / f"run_{commit}_{scene}"
    bundle = run / "field.pfn"
    if not bundle.exists():
        print(f"training the base's {scene} field with {commit}'s pfn-train into {run}", flush=True)
        code = (f"import sys; sys.path.insert(0, {str(root)!r}); "
                "from pf_base.train.cli.train import main; sys.exit(main())")
        subprocess.run([sys.executable, "-c", code, "all", scene, "--out", str(run), "--quiet", "--force"],
                       check=True)
    return bundle


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default=ISSUE_14_DAY, help="the issue day's commit (default: issue 14's, %(default)s)")
    ap.add_argument("--scene", default="vortex")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--bundle", required=True, help="the working tree's field for the scene")
    ap.add_argument("--cameras", nargs="+", default=["forced", "auto"], help="the working tree's camera estimators")
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--max-error", type=float, default=0.35)
    ap.add_argument("--max-ratio", type=float, default=1.5)
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK)
    ap.add_argument("--out", type=Path, default=HERE / "results" / "issue_baseline.json")
    args = ap.parse_args(argv)
    info = machine_info()
    args.work.mkdir(parents=True, exist_ok=True)
    root = base_package(args.base, args.work)
    bundle = base_bundle(root, args.scene, args.work, args.base)
    sys.path.insert(0, str(root))
    base_scene_mod = importlib.import_module("pf_base.runtime.scene.scene")
    base_field_mod = importlib.import_module("pf_base.runtime.field.field")
    base_neural = importlib.import_module("pf_base.runtime.renderers.neural")

    size = {"width": args.size, "height": args.size}
    b_scene = base_scene_mod.builtin_scene(args.scene).with_overrides(**size)
    b_est = base_field_mod.PhotonField.load(bundle, expected_fingerprint=b_scene.fingerprint()).estimator()
    scene = builtin_scene(args.scene).with_overrides(**size)
    est = PhotonField.load(args.bundle, expected_fingerprint=scene.fingerprint()).estimator()
    ref = reference(scene, args.ref_spp, args.work)

    renders: dict[str, Any] = {"base": lambda s: base_neural.render_neural(b_scene, b_est, spp=1, seed=s,
                                                                          progress=False)}
    for cam in args.cameras:
        renders[cam] = (lambda c: lambda s: render_neural(scene, est, spp=1, seed=s, progress=False, camera=c))(cam)
    images: dict[str, dict[int, np.ndarray]] = {name: {} for name in renders}
    used: dict[str, str] = {}

    def recorded(name: str) -> Any:
        """``renders[name]`` keeping its image (scored after the timing) and the camera estimator it used (auto
        probes in the warm-up call)."""
        def render(seed: int) -> None:
            result = renders[name](seed)
            images[name][seed] = result.layers["L"]
            used[name] = str(result.stats.get("camera_estimator", name))
        return render

    ms = alternated_median_ms({name: recorded(name) for name in renders}, args.rounds)
    errors = {name: float(np.mean([relative_l2(images[name][s], ref) for s in range(1, args.rounds + 1)]))
              for name in renders}  # the timed renders' seeds 1 .. rounds (seed 0 is the warm-up)
    print(f"{args.scene} {args.size}x{args.size}, 1 spp, base {args.base}; goal: rel. L2 <= {args.max_error} "
          f"at <= {args.max_ratio}x the base's frame")
    results = {}
    for name in renders:
        ratio = ms[name] / ms["base"]
        new = name != "base"
        meets = new and errors[name] <= args.max_error and ratio <= args.max_ratio
        label = f"{name} ({used[name]})" if new else name
        print(f"  {label:18s} {ms[name]:7.1f} ms  x{ratio:5.2f}  rel. L2 {errors[name]:.3f}"
              f"{'  meets' if meets else ''}")
        results[name] = {"ms": ms[name], "ratio_to_base": ratio, "rel_l2": errors[name],
                         "camera_estimator": used[name] if new else None, "meets_goal": bool(meets) if new else None}
    write_report(args.out, "issue_baseline", finish_info(info, {}), vars(args) | {"work": str(args.work),
                 "out": str(args.out)}, results=results)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
