"""A/B of the tracking kernels against an earlier commit, in one process: did a change cost the hot loop anything?

On a shared machine, timings of two separate runs differ by more than the few percent a kernel change may cost
(other jobs come and go). This script extracts ``--base`` (``git archive``) into a temporary folder, renames its
package to ``pf_base`` (every ``photon_fields`` import rewritten), and in *one* process alternates the base's
``delta_track_batch`` / ``ratio_track_batch`` and the working tree's on the same builtin-scene media, rays and
random streams, ``--alternations`` times each. Both see the same load drift; the minimum (and the first quartile)
of each side is compared. The two sides' results must be bit-identical (checked; a change to the scalar path that
alters samples is not what this measures).

``--stages`` times the frame's walks instead, as the renderers call them: ``sample_first_interactions`` (the
forced camera estimator) and ``direct_light_batch`` (NEE at those first interactions, the renderers' default light
sampling) at a ``--size`` square camera of each builtin scene, on all numba threads; medians and first quartiles
of the alternated calls. Whether the two sides' outputs are identical is reported, not required (a change that
rounds differently is still timed).

Usage::

    NUMBA_NUM_THREADS=1 .venv/bin/python bench/ab_tracking.py --base main --alternations 30
    .venv/bin/python bench/ab_tracking.py --base main --stages --scenes head,shell,blobs,vortex --alternations 15

Output: one line per scene and tracker (or stage), ``new/base`` ratios of the minimum (median) and the first
quartile.
"""

from __future__ import annotations

import argparse
import importlib
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))


def extract_base(commit: str, into: Path) -> None:
    """``commit``'s tree as package ``pf_base`` under ``into`` (imports rewritten)."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", commit], check=True, capture_output=True).stdout
    pkg = into / "pf_base"
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(pkg, filter="data")
    for py in pkg.rglob("*.py"):
        text = py.read_text(encoding="utf-8")
        new = re.sub(r"\bphoton_fields\b", "pf_base", text)
        if new != text:
            py.write_text(new, encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default="main", help="commit to compare against (default main)")
    ap.add_argument("--alternations", type=int, default=30)
    ap.add_argument("--rays", type=int, default=1 << 15)
    ap.add_argument("--scenes", default="vortex,head")
    ap.add_argument("--stages", action="store_true", help="time the 512^2 frame's first interactions and NEE instead")
    ap.add_argument("--size", type=int, default=512, help="--stages: the camera's width and height")
    args = ap.parse_args(argv)
    if args.stages:
        return ab_stages(args)
    from bench_tracking import random_box_rays

    from photon_fields.runtime.scene.scene import builtin_scene
    from photon_fields.runtime.transport import tracking as new_tracking
    from photon_fields.runtime.transport.rng import stream_states

    with tempfile.TemporaryDirectory() as tmp:
        extract_base(args.base, Path(tmp))
        sys.path.insert(0, tmp)
        base_scene = importlib.import_module("pf_base.runtime.scene.scene")
        base_tracking = importlib.import_module("pf_base.runtime.transport.tracking")
        for name in args.scenes.split(","):
            m_new, m_base = builtin_scene(name).medium(), base_scene.builtin_scene(name).medium()
            o, d, tmax = random_box_rays(m_new, args.rays, 0)
            states = stream_states(0, 0, o.shape[1])
            tmin = np.zeros(o.shape[1])
            for kind in ("delta_track_batch", "ratio_track_batch"):
                f_base, f_new = getattr(base_tracking, kind), getattr(new_tracking, kind)
                same = np.array_equal(f_base(m_base, o, d, tmin, tmax, states.copy()),
                                      f_new(m_new, o, d, tmin, tmax, states.copy()))
                times: dict[str, list[float]] = {"base": [], "new": []}
                for _ in range(args.alternations):
                    for side, f, m in (("base", f_base, m_base), ("new", f_new, m_new)):
                        s = states.copy()
                        t0 = time.perf_counter()
                        f(m, o, d, tmin, tmax, s)
                        times[side].append(time.perf_counter() - t0)
                b, n = (np.array(times[k]) for k in ("base", "new"))
                print(f"{name:7s} {kind:18s} base min {b.min() * 1e3:7.2f} ms | new min {n.min() * 1e3:7.2f} ms | "
                      f"new/base min {n.min() / b.min():.3f}, first quartile "
                      f"{np.percentile(n, 25) / np.percentile(b, 25):.3f} | results identical: {same}", flush=True)
    return 0


def ab_stages(args: argparse.Namespace) -> int:
    """``--stages``: the frame's first interactions and their NEE, base against the working tree (module docstring)."""
    sides = {"base": "pf_base", "new": "photon_fields"}
    with tempfile.TemporaryDirectory() as tmp:
        extract_base(args.base, Path(tmp))
        sys.path.insert(0, tmp)
        for name in args.scenes.split(","):
            calls, outputs = {}, {}
            for side, pkg in sides.items():
                calls[side], outputs[side] = _stage_calls(pkg, name, args.size)
            for side in sides:  # the stages both sides have
                calls[side] = {k: v for k, v in calls[side].items() if k in calls["base"]}
            same = {k: np.array_equal(outputs["base"][k], outputs["new"][k]) for k in calls["base"]}
            times: dict[str, dict[str, list[float]]] = {side: {"first": [], "nee": []} for side in sides}
            for a in range(args.alternations):
                for side in (("base", "new") if a % 2 else ("new", "base")):
                    for stage, call in calls[side].items():
                        t0 = time.perf_counter()
                        call()
                        times[side][stage].append(time.perf_counter() - t0)
            for stage in calls["base"]:
                b, n = (np.array(times[k][stage]) for k in sides)
                print(f"{name:7s} {stage:5s} base median {np.median(b) * 1e3:7.2f} ms | new {np.median(n) * 1e3:7.2f} "
                      f"ms | new/base median {np.median(n) / np.median(b):.3f}, first quartile "
                      f"{np.percentile(n, 25) / np.percentile(b, 25):.3f} | outputs identical: {same[stage]}",
                      flush=True)
    return 0


def _stage_calls(pkg: str, name: str, size: int) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Package ``pkg``'s first-interaction and NEE calls on scene ``name`` at a size x size camera (warmed up), and
    their outputs."""
    fim = importlib.import_module(f"{pkg}.runtime.wavefront.first_interaction")
    nee = importlib.import_module(f"{pkg}.runtime.transport.direct_light")
    scene = importlib.import_module(f"{pkg}.runtime.scene.scene").builtin_scene(name).with_overrides(width=size,
                                                                                                    height=size)
    m, (kind, vec, rgb) = scene.medium(), scene.packed_lights()
    # A base from before environment maps (2026-11-24 and earlier) has no NEE of this signature: first only.
    env = scene.packed_environment_map() if hasattr(scene, "packed_environment_map") else None
    n = size * size
    scratch, status, transmit = fim.FirstInteractions.empty(n), np.empty(n, np.uint8), np.empty(n)

    def first() -> np.ndarray:
        return fim.sample_first_interactions(scene, m, 0, n, 1, scratch, status, transmit)

    found = fim.compact_first_interactions(scratch, first())

    batch = getattr(nee.direct_light_batch, "py_func", nee.direct_light_batch)  # compiled in bases before 2026-11-30
    one_light = (True,) if batch.__code__.co_argcount > 10 else ()  # a base before it: all lights

    def direct() -> np.ndarray:
        return nee.direct_light_batch(m, kind, vec, rgb, env, scene.g, found.x, found.d, found.rng.copy(), False,
                                      *one_light)

    if env is None:
        return {"first": first}, {"first": found.x.copy()}
    return {"first": first, "nee": direct}, {"first": found.x.copy(), "nee": direct()}


if __name__ == "__main__":
    sys.exit(main())
