"""Equal-error speedup: how much sooner the neural renderer reaches an image of a given error than the path tracer.

For each scene (default: every builtin) at ``--size`` (default 256x256), everything in one process after a
warm-up, against the path tracer at ``--ref-spp`` (default 512; cached in ``--work``):

- the path tracer at 1, 2, 4, ... spp: wall time (best of ``--repeats``) and rel. L2 (mean over the repeats'
  seeds): its error-time curve, up to ``--pt-max-spp``, or by default (``--pt-max-spp 0``) until it is at or below
  the least error of the neural renderer's plain rows (every camera estimator at ``--spps``, not denoised: the
  rows issue 14's 10x is about), so that their speedups are interpolated rather than extrapolated bounds; it stops
  at a quarter of ``--ref-spp`` (beyond, the reference's own noise is a large part of the curve's error) and says
  so, with the ``--ref-spp`` that would let it go on;
- the neural renderer with each camera estimator (``--cameras``, default all of them) at ``--spps``
  (default 1, 4, 32): wall time and rel. L2 the same way;
- "raymarch-field" (unless ``--no-raymarch-field``): the ray marcher with the field's L_i (``pfn-render --method
  raymarch-field``) at the same spp: noise-free single scattering from its light volume, biased by a few per cent;
- per neural point, the **equal-error speedup**: the path tracer's time to reach the neural image's rel. L2,
  interpolated log-log on its curve (extrapolated from the last two points when the neural image is better
  than the curve's end, marked ``>``), over the neural time;
- with the ``oidn`` extra installed (``pip install 'photon-fields[oidn]'``), the same for the path tracer and the
  neural renderer at ``--oidn-spps`` (default 1 and 4) denoised by Intel Open Image Denoise
  (``photon_fields.runtime.denoise.oidn``, what ``pfn-render --denoise oidn`` runs: colour only, HDR), the
  denoiser's time included; with ``--gather-oidn-spps``, the neural renderer also with the final gather from its
  first sample (``--final-gather-after 0``: a real bounce before the field, less of its bias) and OIDN.
- the temporal WRLS denoiser (``photon_fields.runtime.denoise.wrls``) on a static camera, as a progressive render
  shows it: 1-spp frames accumulated (the neural renderer per camera estimator, ``ProgressiveRender``, and the path
  tracer, seed per frame) and the running mean denoised after every frame; rel. L2 after ``--wrls-frames``
  frames (default 1, 4, 32), the time of all frames so far, denoising included. (On a moving camera, the same
  denoiser's error and flicker along an orbit: ``bench_denoise.py``.)
- **at equal time** (issue 14: "the neural renderer with its best denoiser beats the path tracer with OIDN from 50 ms
  to 1 s"): per budget of ``--budgets`` ms (default 50, 100, 200, 500, 1000), the least error each side reaches
  within it, over all its rows (the neural renderer: every camera estimator, spp and denoiser; the path tracer:
  plain, + OIDN, + WRLS), and which is lower. The path tracer's plain curve ends where it reaches the neural rows'
  least error, so past that time its last point stands for it (it has won there).

Bundles: ``--bundle SCENE=PATH``, else those of ``bench_render.py`` (``bench/results/render/<scene>.pfn``,
trained there when missing). Output: a table on stdout, JSON (default ``bench/results/equal_error.json``) with the
machine record, and a plot of error against time per scene beside it (PNG).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_render import bundle_for  # noqa: E402
from common import add_reference_args, finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.denoise.oidn import denoise_oidn, oidn_available  # noqa: E402
from photon_fields.runtime.denoise.wrls import for_scene  # noqa: E402
from photon_fields.runtime.eval.metrics import relative_l2  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.renderers.neural import render_neural  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.ray_marcher import render_ray_marched  # noqa: E402
from photon_fields.runtime.renderers.registry import CAMERA_ESTIMATOR_NAMES  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "equal_error.json"
DEFAULT_WORK = HERE / "results" / "equal_error"


def reference(scene: Scene, spp: int, work: Path) -> np.ndarray:
    """The path tracer's L at ``spp`` (cached in ``work`` per scene, size and spp)."""
    cam = scene.camera
    path = work / f"ref_{scene.name}_{cam.width}x{cam.height}_{spp}.npy"
    if not path.exists():
        t0 = time.perf_counter()
        img = render_path_traced(scene, spp=spp, seed=10_000, progress=False).layers["L"]
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, img)
        print(f"  reference {scene.name} {spp} spp: {time.perf_counter() - t0:.1f} s", flush=True)
    return np.load(path)


def measure(render: Callable[[int], np.ndarray], ref: np.ndarray, repeats: int,
            denoise: Callable[[np.ndarray], np.ndarray] | None = None) -> dict[str, float]:
    """Best wall time and mean rel. L2 over ``repeats`` seeds of ``render(seed) -> L`` (denoised after, if given)."""
    times, errors = [], []
    for seed in range(repeats):
        t0 = time.perf_counter()
        img = render(seed)
        if denoise is not None:
            img = denoise(img)
        times.append(time.perf_counter() - t0)
        errors.append(relative_l2(img, ref))
    return {"ms": min(times) * 1e3, "rel_l2": float(np.mean(errors)), "rel_l2_spread": float(np.std(errors))}


def time_to_error(curve: list[dict[str, float]], error: float) -> tuple[float, bool]:
    """The path tracer's time (ms) to reach ``error``, log-log interpolated on ``curve`` (rows with ms and
    rel_l2, spp ascending); extrapolated beyond its ends from the two nearest points (then True)."""
    ms = np.log([c["ms"] for c in curve])
    err = np.log([c["rel_l2"] for c in curve])
    e = np.log(error)
    for i in range(len(curve) - 1):
        if err[i] >= e >= err[i + 1]:
            f = (err[i] - e) / max(err[i] - err[i + 1], 1e-12)
            return float(np.exp(ms[i] + f * (ms[i + 1] - ms[i]))), False
    i = 0 if e > err[0] else len(curve) - 2
    slope = (ms[i + 1] - ms[i]) / min(err[i + 1] - err[i], -1e-12)
    return float(np.exp(ms[i] + (e - err[i]) * slope)), True


def progressive_wrls(frame: Callable[[int], np.ndarray], scene: Scene, ref: np.ndarray, frames: list[int],
                     repeats: int) -> list[dict[str, Any]]:
    """Static camera: ``frame(i)`` (a 1-spp L with its own samples) accumulated, the running mean denoised by
    WRLS after every frame; per count in ``frames``, the best time of all frames so far and the mean rel. L2
    over ``repeats`` sequences (seeds ``1000 r + i``)."""
    last = max(frames)
    times: dict[int, list[float]] = {k: [] for k in frames}
    errors: dict[int, list[float]] = {k: [] for k in frames}
    for r in range(repeats):
        denoiser = for_scene(scene)
        acc = np.zeros_like(ref, dtype=np.float64)
        elapsed = 0.0
        for i in range(1, last + 1):
            t0 = time.perf_counter()
            acc += frame(1000 * r + i)
            out = denoiser.denoise((acc / i).astype(np.float32))
            elapsed += time.perf_counter() - t0
            if i in times:
                times[i].append(elapsed)
                errors[i].append(relative_l2(out, ref))
    return [{"spp": k, "frames": k, "ms": min(times[k]) * 1e3, "rel_l2": float(np.mean(errors[k])),
             "rel_l2_spread": float(np.std(errors[k]))} for k in frames]


def path_tracer_curve(point: Callable[[int], dict[str, float]], pt_spps: list[int] | None, target: float,
                      ref_spp: int, label: str = "") -> list[dict[str, Any]]:
    """The path tracer's error-time curve: ``point(spp)`` at ``pt_spps``, or (None) at 1, 2, 4, ... spp until its
    error is at or below ``target`` (two points at least) or the next count would pass ``ref_spp / 4`` (then a line
    says so, naming ``label``)."""
    if pt_spps is not None:
        return [{"spp": s, **point(s)} for s in pt_spps]
    rows: list[dict[str, Any]] = []
    spp = 1
    while True:
        rows.append({"spp": spp, **point(spp)})
        if len(rows) < 2:  # two points at least: time_to_error interpolates between them
            spp *= 2
            continue
        if rows[-1]["rel_l2"] <= target:
            return rows
        if 2 * spp > ref_spp // 4:
            print(f"  {label}: the path tracer's curve stops at {spp} spp (rel. L2 {rows[-1]['rel_l2']:.3f} > "
                  f"{target:.3f}): a quarter of the reference's; --ref-spp {8 * spp} would let it reach further",
                  flush=True)
            return rows
        spp *= 2


def scene_curves(scene: Scene, est: Any, ref: np.ndarray, args: argparse.Namespace, pt_spps: list[int] | None,
                 denoise: Callable[[np.ndarray], np.ndarray] | None) -> dict[str, list[dict[str, Any]]]:
    """Per method, its (spp, ms, rel. L2) points: the path tracer's curve, the neural renderer's per camera
    estimator and, with ``denoise``, both at ``--oidn-spps`` denoised."""

    def pt(spp: int) -> Callable[[int], np.ndarray]:
        return lambda seed: render_path_traced(scene, spp=spp, seed=seed, progress=False).layers["L"]

    def neural(spp: int, camera: str, gather_after: int | None = None) -> Callable[[int], np.ndarray]:
        return lambda seed: render_neural(scene, est, spp=spp, seed=seed, progress=False, camera=camera,
                                          final_gather_after=gather_after).layers["L"]

    def raymarch_field(spp: int) -> Callable[[int], np.ndarray]:
        return lambda seed: render_ray_marched(scene, spp=spp, seed=seed, progress=False, estimator=est).layers["L"]

    curves: dict[str, list[dict[str, Any]]] = {}
    for camera in args.cameras:
        curves[f"neural {camera}"] = [{"spp": s, **measure(neural(s, camera), ref, args.repeats)} for s in args.spps]
    target = min((row["rel_l2"] for rows in curves.values() for row in rows), default=math.inf)
    curves = {"path tracer": path_tracer_curve(lambda s: measure(pt(s), ref, args.repeats), pt_spps, target,
                                               args.ref_spp, scene.name), **curves}
    if args.raymarch_field:
        curves["raymarch-field"] = [{"spp": s, **measure(raymarch_field(s), ref, args.repeats)} for s in args.spps]
    curves["path tracer + WRLS (progressive)"] = progressive_wrls(pt(1), scene, ref, args.wrls_frames, args.repeats)
    for camera in args.cameras:
        curves[f"neural {camera} + WRLS (progressive)"] = progressive_wrls(neural(1, camera), scene, ref,
                                                                         args.wrls_frames, args.repeats)
    if args.raymarch_field:
        curves["raymarch-field + WRLS (progressive)"] = progressive_wrls(raymarch_field(1), scene, ref,
                                                                         args.wrls_frames, args.repeats)
    if denoise is not None:
        curves["path tracer + OIDN"] = [{"spp": s, **measure(pt(s), ref, args.repeats, denoise)}
                                        for s in args.oidn_spps]
        for camera in args.cameras:
            curves[f"neural {camera} + OIDN"] = [{"spp": s, **measure(neural(s, camera), ref, args.repeats, denoise)}
                                                 for s in args.oidn_spps]
            if args.gather_oidn_spps:  # every sample gathered (--final-gather-after 0): less of the field's bias
                curves[f"neural {camera} + gather + OIDN"] = [
                    {"spp": s, **measure(neural(s, camera, 0), ref, args.repeats, denoise)}
                    for s in args.gather_oidn_spps]
    return curves


def plot(results: dict[str, Any], path: Path) -> None:
    """Error against time, log-log, one panel per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.8), dpi=100, squeeze=False)
    colours = plt.get_cmap("tab20").colors  # one colour per method (the default cycle repeats after ten)
    for ax, (name, r) in zip(axes[0], results.items(), strict=True):
        for k, (method, rows) in enumerate(r["curves"].items()):
            style = "s--" if method.startswith("path tracer") else "o-"  # the competitor dashed
            ax.plot([p["ms"] for p in rows], [p["rel_l2"] for p in rows], style, ms=3, label=method,
                    color=colours[k % len(colours)])
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("ms per image")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("rel. L2 against the reference")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


#: Frame-time budgets (ms) of the equal-time comparison (issue 14: from 50 ms to 1 s a 256x256 frame).
BUDGETS_MS = (50.0, 100.0, 200.0, 500.0, 1000.0)


def best_within(curves: dict[str, list[dict[str, Any]]], prefix: str, budget: float) -> dict[str, Any] | None:
    """The least-error row (with its method) among ``curves``' methods that start with ``prefix`` and take at most
    ``budget`` ms; None when none fits."""
    rows = [{"method": m, **row} for m, rs in curves.items() if m.startswith(prefix) for row in rs
            if row["ms"] <= budget]
    return min(rows, key=lambda row: row["rel_l2"]) if rows else None


def equal_time(curves: dict[str, list[dict[str, Any]]], budgets: list[float]) -> list[dict[str, Any]]:
    """Per budget: the neural renderer's and the path tracer's least error within it (:func:`best_within`) and
    whether the neural one is lower (None where a side has no row that fast)."""
    out = []
    for budget in budgets:
        neural, pt = best_within(curves, "neural", budget), best_within(curves, "path tracer", budget)
        # a side with no frame within the budget loses to one that has one
        wins = None if neural is None and pt is None else (pt is None or neural is not None and
                                                              neural["rel_l2"] < pt["rel_l2"])
        out.append({"budget_ms": budget, "neural": neural, "path_tracer": pt, "neural_wins": wins})
    return out


def describe(row: dict[str, Any] | None) -> str:
    if row is None:
        return "none this fast"
    return f"{row['rel_l2']:.3f} ({row['method']}, {row['spp']} spp, {row['ms']:.0f} ms)"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_reference_args(ap)
    ap.add_argument("--pt-max-spp", type=int, default=0,
                    help="the path tracer's curve up to this many spp (0: until it reaches the neural rows' least "
                         "error, at most a quarter of --ref-spp)")
    ap.add_argument("--spps", type=int, nargs="*", default=[1, 4, 32], help="neural samples per pixel")
    ap.add_argument("--cameras", nargs="*", default=list(CAMERA_ESTIMATOR_NAMES), choices=CAMERA_ESTIMATOR_NAMES,
                    help="camera estimators")
    ap.add_argument("--no-raymarch-field", dest="raymarch_field", action="store_false",
                    help="leave out the ray marcher with the field's L_i (--method raymarch-field)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--wrls-frames", type=int, nargs="*", default=[1, 4, 32],
                    help="progressive WRLS: rel. L2 after these many 1-spp frames")
    ap.add_argument("--bundle", action="append", default=[], metavar="SCENE=PATH")
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK)
    ap.add_argument("--oidn-spps", type=int, nargs="*", default=[1, 4],
                    help="samples per pixel of the OIDN-denoised rows (more to follow the path tracer to 1 s)")
    ap.add_argument("--gather-oidn-spps", type=int, nargs="*", default=[],
                    help="samples per pixel of neural rows with the final gather from the first sample "
                         "(pfn-render --final-gather-after 0), OIDN-denoised (default: none)")
    ap.add_argument("--budgets", type=float, nargs="*", default=list(BUDGETS_MS),
                    help="ms per image of the equal-time comparison")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    given = dict(b.split("=", 1) for b in args.bundle)
    # As pfn-render --denoise: the marched estimator's rare negative pixels clamped to 0 first.
    denoise = (lambda img: denoise_oidn(np.maximum(img, 0.0))) if oidn_available() else None
    if denoise is None:
        print("pyoidn is not installed: no OIDN rows (pip install 'photon-fields[oidn]')")
    info = machine_info()
    results: dict[str, Any] = {}
    pt_spps = [1 << i for i in range(int(np.log2(args.pt_max_spp)) + 1)] if args.pt_max_spp > 0 else None
    for name in parse_scenes(args.scenes):
        base = builtin_scene(name)
        scene = base.with_overrides(width=args.size, height=args.size)
        field = PhotonField.load(bundle_for(name, base, given), expected_fingerprint=base.fingerprint())
        est = field.estimator()
        ref = reference(scene, args.ref_spp, args.work)
        warm = scene.with_overrides(width=32, height=32)
        render_path_traced(warm, spp=1, progress=False)
        for camera in args.cameras:
            render_neural(warm, est, spp=1, progress=False, camera=camera)
        # auto probes once per scene and pixel size (runtime/wavefront/camera_choice.py): before the timed frames,
        # as a viewer's or a progressive render's later frames find it made
        chosen = render_neural(scene, est, spp=1, progress=False).stats["camera_estimator"]
        if args.raymarch_field:
            render_ray_marched(warm, spp=1, progress=False, estimator=est)

        curves = scene_curves(scene, est, ref, args, pt_spps, denoise)
        for method, rows in curves.items():
            if method == "path tracer":
                continue
            for row in rows:
                t, extrapolated = time_to_error(curves["path tracer"], row["rel_l2"])
                row["equal_error_speedup"] = t / row["ms"]
                row["extrapolated"] = extrapolated
        timed = equal_time(curves, args.budgets)
        results[name] = {"bundle": str(bundle_for(name, base, given)), "curves": curves, "auto_chose": chosen,
                         "equal_time": timed}
        print(f"\n{name} ({args.size}x{args.size}, reference: path tracer {args.ref_spp} spp; auto: {chosen})")
        print(f"  {'method':36s} {'spp':>4s} {'ms':>8s} {'rel. L2':>8s} {'speedup':>8s}")
        for method, rows in curves.items():
            for row in rows:
                speed = row.get("equal_error_speedup")
                mark = ">" if row.get("extrapolated") else " "
                speed_s = f"{mark}{speed:6.1f}x" if speed is not None else ""
                print(f"  {method:36s} {row['spp']:4d} {row['ms']:8.1f} {row['rel_l2']:8.3f} {speed_s:>8s}", flush=True)
        print("  at equal time, the least error within each budget:")
        for t in timed:
            verdict = {True: "neural", False: "path tracer", None: "-"}[t["neural_wins"]]
            print(f"  {t['budget_ms']:6.0f} ms  neural {describe(t['neural'])}  path tracer "
                  f"{describe(t['path_tracer'])}  lower: {verdict}", flush=True)
    info = finish_info(info, {})
    pt_record = pt_spps or "until the neural rows' least error (each scene's curve lists its points)"
    write_report(args.out, "equal_error", info, {"size": args.size, "ref_spp": args.ref_spp, "pt_spps": pt_record,
                                                 "spps": args.spps, "cameras": args.cameras,
                                                 "repeats": args.repeats, "oidn": denoise is not None,
                                                 "wrls_frames": args.wrls_frames,
                                                 "raymarch_field": args.raymarch_field, "budgets": args.budgets,
                                                 "oidn_spps": args.oidn_spps,
                                                 "gather_oidn_spps": args.gather_oidn_spps},
                 results=results)
    plot(results, args.out.with_suffix(".png"))
    print(f"wrote {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
