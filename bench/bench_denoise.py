"""WRLS temporal denoiser (runtime/denoise/wrls.py) on 1-spp orbits: error, flicker and cost.

For each scene (default: every builtin) an orbit around the scene camera's target at ``--size`` (default
256x256), ``--degrees-per-frame`` (default 1, a 360-degree turn in 12 s at 30 fps): ``--warmup`` frames
(default 16) that are only rendered and denoised, then ``--frames`` measured frames (default 12). Per measured
frame:

- the reference: the path tracer at ``--ref-spp`` (default 128) as two independent halves ``h1``, ``h2``
  (cached in ``--work``), ``R = (h1 + h2) / 2``;
- 1-spp frames of the neural renderer (the bundle's field, the camera estimator ``--camera``, default the
  renderer's, seed = frame) and of
  the path tracer, each denoised by its own :class:`WRLSDenoiser` (medium given, so it computes the depth maps
  itself) that has seen the whole orbit so far.

Errors are rel. L2 against the *converged* image, estimated without bias from the noisy reference: an unbiased
renderer's halves differ by ``||h1 - h2||^2 = 2 V`` in expectation (V: a half's variance summed over pixels and
channels), so the reference's own variance is ``||h1 - h2||^2 / 4`` and

- ``rel_l2(x) = sqrt(max(||x - R||^2 - ||h1 - h2||^2 / 4, 0)) / ||R||`` (``rel_l2_raw``: against R, uncorrected);
- the path tracer at S spp: ``rel_l2 = ||h1 - h2|| sqrt(h / (2 S)) / ||R||`` (h: a half's spp), the error a
  64-spp render has on average: the goal's yardstick.

Flicker: the mean absolute change from one frame to the next over the measured frames, over the reference's
mean (the reference's own includes its noise, at ``--ref-spp``). It includes what the converged image changes as
the camera turns, which every sequence shares: an input with little noise (the marched camera estimator's) cannot
show a large reduction by it. ``temporal_error`` is that change less the references' change, debiased for their
noise (:func:`temporal_error`): the part of the frame-to-frame change that is error. Goals (issue 14, item 3):
denoised 1-spp neural rel. L2 <= the path tracer's at 64 spp on every scene; flicker >= 3x lower than undenoised.
The neural renderer takes ``--camera`` (default the renderers' ``auto``; the JSON records what it chose).

Static camera (``--progressive-frames``, default 32; the scene camera, a reference as above): the running mean of
the 1-spp neural frames (what ``ProgressiveRender`` shows), WRLS fed that running mean, and WRLS fed each frame
alone, rel. L2 after 4, 8, 16 and 32 frames.

Timing (``--timing-size``, default 512x512, on ``--timing-scene``, one scene or several comma-separated):
``--timing-frames`` neural 1-spp frames of an orbit, rendered, their depth maps computed and denoised; median
milliseconds of each (the renderer's stages and the denoiser's too), with the CPU model and the foreign load
(:class:`common.Contention`); then the denoiser alone on the recorded frames, ``--alternations`` sequences.
``--base COMMIT`` times that commit's code too (extracted as package ``pf_base``, as ``ab_tracking.py`` does),
alternating with the working tree frame by frame, and reports new / base ratios and whether the renders and
the denoised frames are identical: on a shared machine only such same-run ratios compare code versions.
Goals: denoiser <= 30 ms per 512x512 frame on 2 cores; neural frame + denoising <= 100 ms.

Bundles: ``--bundle SCENE=PATH``, else ``/tmp/bundles/<scene>/field.pfn`` when present, else those of
``bench_render.py`` (trained there when missing). Output: a table on stdout and JSON (default
``bench/results/denoise.json``) with the machine record. ``--params alpha=0.8,bandwidth=1e9`` overrides the
denoiser's parameters (:class:`WRLSParams`). Default run: ~9 min for the references on 2 cores the first time
(cached after), ~3 min then.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from common import Contention, finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.denoise.wrls import WRLSDenoiser, WRLSParams  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.renderers.neural import render_neural  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.registry import CAMERA_ESTIMATOR_NAMES, CAMERA_OPTION  # noqa: E402
from photon_fields.runtime.scene.camera import orbit_camera  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "denoise.json"
DEFAULT_WORK = Path("/tmp/pfn_bench_denoise")
PT_SPP = 64  # the goal's yardstick


def bundle_path(name: str, scene: Scene, given: dict[str, str]) -> Path:
    if name in given:
        return Path(given[name])
    tmp = Path("/tmp/bundles") / name / "field.pfn"
    if tmp.exists():
        return tmp
    from bench_render import bundle_for

    return bundle_for(name, scene, given)


def reference_halves(scene: Scene, frame: int, spp: int, key: str, work: Path) -> tuple[np.ndarray, np.ndarray]:
    """Two independent path-traced renders of ``spp / 2`` each (cached)."""
    path = work / f"ref_{key}_{frame:04d}_{spp}.npz"
    if path.exists():
        data = np.load(path)
        return data["h1"], data["h2"]
    half = spp // 2
    h1 = render_path_traced(scene, spp=half, seed=1_000_003 + 2 * frame, progress=False).layers["L"]
    h2 = render_path_traced(scene, spp=half, seed=1_000_004 + 2 * frame, progress=False).layers["L"]
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, h1=h1, h2=h2)
    return h1, h2


def sq(a: np.ndarray) -> float:
    return float(np.sum(np.square(a, dtype=np.float64)))


def flicker(frames: list[np.ndarray], scale: float) -> float:
    return float(np.mean([np.mean(np.abs(b.astype(np.float64) - a)) for a, b in zip(frames, frames[1:],
                                                                                       strict=False)]) / scale)


def temporal_error(frames: list[np.ndarray], refs: list[np.ndarray], ref_vars: list[float]) -> float:
    """The frame-to-frame change of a sequence's error: sqrt of the mean over consecutive frames of
    ||(x_t - x_t-1) - (R_t - R_t-1)||^2 less the references' own noise (var_t + var_t-1, each ``||h1 - h2||^2 / 4``),
    over the mean ||R||^2. Unlike :func:`flicker` it leaves out what the converged image itself changes as the
    camera moves, so an input with less noise is not charged for the motion both share (module docstring)."""
    num = [sq((b.astype(np.float64) - a) - (rb - ra)) - va - vb
           for a, b, ra, rb, va, vb in zip(frames, frames[1:], refs, refs[1:], ref_vars, ref_vars[1:], strict=False)]
    return float(np.sqrt(max(float(np.mean(num)), 0.0) / np.mean([sq(r) for r in refs])))


def camera_option(args: argparse.Namespace) -> dict[str, str]:
    """``render_neural``'s camera estimator keyword for ``--camera`` (none for the default, so that a ``--base``
    commit from before the keyword still runs)."""
    return {} if args.camera == CAMERA_OPTION.default else {"camera": args.camera}


def run_scene(name: str, args: argparse.Namespace, params: dict[str, Any], given: dict[str, str]) -> dict[str, Any]:
    scene = builtin_scene(name).with_overrides(width=args.size, height=args.size)
    field = PhotonField.load(bundle_path(name, scene, given))
    est = field.estimator()
    key = f"{name}_{args.size}_{args.degrees_per_frame:g}"
    small = scene.with_overrides(width=16, height=16)
    render_neural(small, est, spp=1, progress=False)  # warm-up: compilation, onnxruntime start-up
    render_path_traced(small, spp=1, progress=False)
    denoisers = {r: WRLSDenoiser(args.size, args.size, medium=scene.medium(), **params) for r in ("neural", "pt")}
    total = args.warmup + args.frames
    rows: dict[str, list[float]] = {k: [] for k in ("noisy_neural", "wrls_neural", "noisy_pt", "wrls_pt",
                                                   "pt64", "raw_noisy_neural", "raw_wrls_neural", "raw_wrls_pt")}
    seqs: dict[str, list[np.ndarray]] = {k: [] for k in ("noisy_neural", "wrls_neural", "noisy_pt", "wrls_pt", "ref")}
    ref_vars: list[float] = []
    ms: dict[str, list[float]] = {"denoise": [], "depth": [], "neural": [], "reference": []}
    t_scene = time.perf_counter()
    with Contention() as busy:
        for i in range(total):
            cam = orbit_camera(scene.camera, args.degrees_per_frame * i)
            view = scene.with_overrides(camera=cam)
            t0 = time.perf_counter()
            result = render_neural(view, est, spp=1, seed=i, progress=False, **camera_option(args))
            noisy, chosen = {"neural": result.layers["L"]}, result.stats.get("camera_estimator")
            ms["neural"].append((time.perf_counter() - t0) * 1e3)
            noisy["pt"] = render_path_traced(view, spp=1, seed=i, progress=False).layers["L"]
            den = {}
            for r, dn in denoisers.items():
                den[r] = dn.denoise(noisy[r], camera=cam)
            ms["denoise"].append(denoisers["neural"].timings_ms["total"] - denoisers["neural"].timings_ms["depth"])
            ms["depth"].append(denoisers["neural"].timings_ms["depth"])
            if i < args.warmup:
                continue
            t0 = time.perf_counter()
            h1, h2 = reference_halves(view, i, args.ref_spp, key, Path(args.work))
            ms["reference"].append((time.perf_counter() - t0) * 1e3)
            ref = 0.5 * (h1.astype(np.float64) + h2)
            ref_sq = sq(ref)
            diff_sq = sq(h1.astype(np.float64) - h2)
            half = args.ref_spp // 2
            rows["pt64"].append(float(np.sqrt(diff_sq * half / (2 * PT_SPP) / ref_sq)))
            for label, img in (("noisy_neural", noisy["neural"]), ("wrls_neural", den["neural"]),
                               ("noisy_pt", noisy["pt"]), ("wrls_pt", den["pt"])):
                e2 = sq(img - ref)
                rows[label].append(float(np.sqrt(max(e2 - diff_sq / 4, 0.0) / ref_sq)))
                if "raw_" + label in rows:
                    rows["raw_" + label].append(float(np.sqrt(e2 / ref_sq)))
                seqs[label].append(img)
            seqs["ref"].append(ref)
            ref_vars.append(diff_sq / 4)
    scale = float(np.mean([r.mean() for r in seqs["ref"]]))
    out: dict[str, Any] = {"bundle": str(bundle_path(name, scene, given)), "other_cores": busy.other_cores,
                           "seconds": time.perf_counter() - t_scene, "camera_estimator": chosen}
    out["rel_l2"] = {k: float(np.mean(v)) for k, v in rows.items()}
    out["rel_l2_per_frame"] = rows
    out["flicker"] = {k: flicker(v, scale) for k, v in seqs.items()}
    out["ms_per_frame"] = {k: float(np.median(v)) for k, v in ms.items() if v}
    out["goal_rel_l2"] = out["rel_l2"]["wrls_neural"] <= out["rel_l2"]["pt64"]
    out["flicker_reduction_neural"] = out["flicker"]["noisy_neural"] / out["flicker"]["wrls_neural"]
    out["flicker_reduction_pt"] = out["flicker"]["noisy_pt"] / out["flicker"]["wrls_pt"]
    out["temporal_error"] = {k: temporal_error(v, seqs["ref"], ref_vars) for k, v in seqs.items() if k != "ref"}
    t = out["temporal_error"]
    out["temporal_error_reduction_neural"] = t["noisy_neural"] / max(t["wrls_neural"], 1e-12)
    return out


def run_progressive(name: str, args: argparse.Namespace, params: dict[str, Any],
                    given: dict[str, str]) -> dict[str, Any]:
    """Static camera: running mean, WRLS of the running mean, WRLS of each frame (module docstring)."""
    scene = builtin_scene(name).with_overrides(width=args.size, height=args.size)
    est = PhotonField.load(bundle_path(name, scene, given)).estimator()
    h1, h2 = reference_halves(scene, 0, args.ref_spp, f"{name}_{args.size}_static", Path(args.work))
    ref = 0.5 * (h1.astype(np.float64) + h2)
    ref_sq, ref_var = sq(ref), sq(h1.astype(np.float64) - h2) / 4

    def rel(img: np.ndarray) -> float:
        return float(np.sqrt(max(sq(img - ref) - ref_var, 0.0) / ref_sq))

    on_mean = WRLSDenoiser(args.size, args.size, **params)
    on_frames = WRLSDenoiser(args.size, args.size, **params)
    acc = np.zeros((args.size, args.size, 3))
    rows: dict[str, dict[int, float]] = {"running_mean": {}, "wrls_of_running_mean": {}, "wrls_of_frames": {}}
    for n in range(1, args.progressive_frames + 1):
        frame = render_neural(scene, est, spp=1, seed=50_000 + n, progress=False, **camera_option(args)).layers["L"]
        acc += frame
        mean = (acc / n).astype(np.float32)
        a, b = on_mean.denoise(mean), on_frames.denoise(frame)
        if n in (1, 4, 8, 16, 32, 64, 128) or n == args.progressive_frames:
            rows["running_mean"][n] = rel(mean)
            rows["wrls_of_running_mean"][n] = rel(a)
            rows["wrls_of_frames"][n] = rel(b)
    return rows


class Side:
    """One code version's entry points for the timing: the working tree's, or ``--base``'s (``pf_base``)."""

    def __init__(self, label: str, package: str) -> None:
        import importlib

        self.label = label

        def mod(name: str) -> Any:
            return importlib.import_module(f"{package}.{name}")

        self.builtin_scene = mod("runtime.scene.scene").builtin_scene
        self.orbit_camera = mod("runtime.scene.camera").orbit_camera
        self.PhotonField = mod("runtime.field.field").PhotonField
        self.render_neural = mod("runtime.renderers.neural").render_neural
        self.DepthEstimator = mod("runtime.denoise.depth").DepthEstimator
        self.WRLSDenoiser = mod("runtime.denoise.wrls").WRLSDenoiser


def base_side(commit: str) -> Side:
    """``commit``'s code as package ``pf_base`` (``ab_tracking.extract_base``), extracted once per commit into
    ``/tmp/pfn_ab_base/<sha>`` so that numba's on-disk cache of the base's kernels survives between runs."""
    import subprocess
    import sys

    from ab_tracking import extract_base

    sha = subprocess.run(["git", "-C", str(HERE.parent), "rev-parse", commit], check=True, capture_output=True,
                         text=True).stdout.strip()
    into = Path("/tmp/pfn_ab_base") / sha
    if not (into / "pf_base").exists():
        tmp = into.with_name(sha + ".partial")
        tmp.mkdir(parents=True, exist_ok=True)
        extract_base(sha, tmp)
        tmp.rename(into)
    sys.path.insert(0, str(into))
    return Side(f"base {commit} ({sha[:8]})", "pf_base")


def _ms(stages: dict[str, list[float]], key: str, value: float) -> None:
    stages.setdefault(key, []).append(value)


def run_timing(args: argparse.Namespace, params: dict[str, Any], given: dict[str, str], name: str,
               sides: list[Side]) -> dict[str, Any]:
    """Milliseconds per ``--timing-size`` frame of scene ``name``: neural 1-spp render (per stage), depth map,
    denoiser (and its stages), for each code version in ``sides``, alternating frame by frame (the order
    swapped every frame), so that a shared machine's drift hits every side alike. With two sides, their renders
    and denoised frames are compared (``identical``: bit for bit; ``max_rel_diff``: the largest difference of a
    denoised pixel over the frame's mean), and the denoisers are also timed back to back on the first side's
    recorded frames (the same input for every side), alternating whole sequences."""
    size = args.timing_size
    st: dict[str, dict[str, Any]] = {}
    for side in sides:
        scene = side.builtin_scene(name).with_overrides(width=size, height=size)
        est = side.PhotonField.load(bundle_path(name, builtin_scene(name), given)).estimator()
        side.render_neural(scene.with_overrides(width=16, height=16), est, spp=1, progress=False)
        st[side.label] = {"scene": scene, "est": est, "depth_of": side.DepthEstimator(scene.medium()),
                          "dn": side.WRLSDenoiser(size, size, **params), "stages": {}, "recorded": []}
    same_render, same_denoised, max_rel = True, True, 0.0
    with Contention() as busy:
        for i in range(args.timing_frames):
            outputs = {}
            for side in sides if i % 2 == 0 else sides[::-1]:
                s = st[side.label]
                cam = side.orbit_camera(s["scene"].camera, args.degrees_per_frame * i)
                t0 = time.perf_counter()
                result = side.render_neural(s["scene"].with_overrides(camera=cam), s["est"], spp=1, seed=i,
                                            progress=False, **camera_option(args))
                t1 = time.perf_counter()
                depth = s["depth_of"].depth(cam)
                t2 = time.perf_counter()
                out = s["dn"].denoise(result.layers["L"], camera=cam, depth=depth)
                t3 = time.perf_counter()
                outputs[side.label] = (result.layers["L"], out)
                s["recorded"].append((result.layers["L"], cam, depth))
                if i < 2:  # compilation / cache loading, first-frame allocations
                    continue
                stages = s["stages"]
                for k, v in (("neural_render", t1 - t0), ("depth", t2 - t1), ("denoise", t3 - t2)):
                    _ms(stages, k, v * 1e3)
                for k, v in result.timings_ms.items():
                    _ms(stages, f"render.{k}", v)
                for k, v in s["dn"].timings_ms.items():
                    if k not in ("depth", "total"):
                        _ms(stages, f"denoise.{k}", v)
            if len(sides) > 1:
                (r0, d0), (r1, d1) = outputs[sides[0].label], outputs[sides[1].label]
                same_render &= bool(np.array_equal(r0, r1))
                same_denoised &= bool(np.array_equal(d0, d1))
                max_rel = max(max_rel, float(np.max(np.abs(d0.astype(np.float64) - d1)) / max(float(d0.mean()),
                                                                                               1e-30)))
        # The same frames again, denoised back to back (no render in between: the denoiser alone).
        recorded = st[sides[0].label]["recorded"]
        for rep in range(args.alternations):
            for side in sides if rep % 2 == 0 else sides[::-1]:
                again = side.WRLSDenoiser(size, size, **params)
                for i, ((frame, _, depth), (_, cam, _)) in enumerate(zip(recorded, st[side.label]["recorded"],
                                                                         strict=True)):
                    t0 = time.perf_counter()
                    again.denoise(frame, camera=cam, depth=depth)
                    if i >= 2:
                        _ms(st[side.label]["stages"], "denoise_back_to_back", (time.perf_counter() - t0) * 1e3)
    result: dict[str, Any] = {"scene": name, "size": [size, size], "frames_timed": args.timing_frames - 2,
                              "other_cores": busy.other_cores, "sides": {}}
    for side in sides:
        stages = st[side.label]["stages"]
        med = {k: float(np.median(v)) for k, v in stages.items()}
        med["frame_with_denoising"] = med["neural_render"] + med["depth"] + med["denoise"]
        result["sides"][side.label] = {"median_ms": med, "min_ms": {k: float(np.min(v)) for k, v in stages.items()}}
    if len(sides) > 1:
        a, b = (result["sides"][s.label]["median_ms"] for s in sides)
        result["ratio_new_over_base"] = {k: b[k] / a[k] for k in a if k in b and a[k] > 0}
        result["identical_renders"] = same_render
        result["identical_denoised"] = same_denoised
        result["denoised_max_rel_diff"] = max_rel
    return result


def print_timing(t: dict[str, Any]) -> None:
    size = t["size"][0]
    for label, r in t["sides"].items():
        m = r["median_ms"]
        split = ", ".join(f"{k.removeprefix('render.')} {v:.1f}" for k, v in m.items()
                          if k.startswith("render.") and k != "render.total" and v >= 0.5)
        print(f"{size}x{size} {t['scene']} {label} (median ms): neural 1 spp {m['neural_render']:.1f} ({split}), "
              f"depth {m['depth']:.1f}, denoise {m['denoise']:.1f} (back to back {m['denoise_back_to_back']:.1f}; "
              f"prepare {m.get('denoise.prepare', 0.0):.1f}, temporal {m['denoise.temporal']:.1f}, spatial "
              f"{m['denoise.spatial']:.1f}); frame with denoising {m['frame_with_denoising']:.1f}")
    if "ratio_new_over_base" in t:
        keys = ("neural_render", "render.sample_first_interactions", "render.estimate_indirect",
                "render.estimate_direct", "depth", "denoise", "denoise_back_to_back", "frame_with_denoising")
        ratios = ", ".join(f"{k.removeprefix('render.')} {t['ratio_new_over_base'][k]:.2f}" for k in keys
                           if k in t["ratio_new_over_base"])
        print(f"  new / base: {ratios}; renders identical: {t['identical_renders']}, denoised identical: "
              f"{t['identical_denoised']} (max diff / mean {t['denoised_max_rel_diff']:.2e})")
    print(f"  other cores busy: {t['other_cores']}", flush=True)


def parse_params(text: str | None) -> dict[str, Any]:
    if not text:
        return {}
    types = {f.name: f.type for f in fields(WRLSParams)}
    out: dict[str, Any] = {}
    for item in text.split(","):
        key, _, value = item.partition("=")
        if key not in types:
            raise SystemExit(f"--params: unknown parameter {key!r}; known: {', '.join(types)}")
        kind = types[key]
        out[key] = value if kind == "str" else int(value) if kind == "int" else float(value)
    WRLSParams(**out)  # validate
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=None)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--frames", type=int, default=12, help="measured frames (with references)")
    ap.add_argument("--warmup", type=int, default=16, help="frames rendered and denoised before the measured ones")
    ap.add_argument("--degrees-per-frame", type=float, default=1.0)
    ap.add_argument("--ref-spp", type=int, default=128, help="reference spp (two halves; even)")
    ap.add_argument("--progressive-frames", type=int, default=32, help="static-camera frames (0: skip)")
    ap.add_argument("--timing-size", type=int, default=512)
    ap.add_argument("--timing-frames", type=int, default=12)
    ap.add_argument("--timing-scene", default="vortex", help="scene(s) of the timing, comma-separated")
    ap.add_argument("--base", default=None, help="also time this commit's code (as pf_base), alternating")
    ap.add_argument("--alternations", type=int, default=4, help="back-to-back denoiser sequences per side")
    ap.add_argument("--no-timing", action="store_true")
    ap.add_argument("--timing-only", action="store_true", help="only the timing part (no orbits, no references)")
    ap.add_argument("--bundle", action="append", default=[], help="SCENE=PATH")
    ap.add_argument("--camera", default=CAMERA_OPTION.default, choices=CAMERA_ESTIMATOR_NAMES,
                    help="the neural renderer's camera estimator")
    ap.add_argument("--params", default=None, help="denoiser parameters, e.g. alpha=0.8,bandwidth=1e9")
    ap.add_argument("--work", default=str(DEFAULT_WORK), help="reference cache")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args()
    if args.ref_spp < 2 or args.ref_spp % 2:
        raise SystemExit("--ref-spp must be an even number >= 2")
    scenes = parse_scenes(args.scenes)
    given = dict(b.split("=", 1) for b in args.bundle)
    params = parse_params(args.params)
    info = machine_info()
    results: dict[str, Any] = {}
    print(f"{'scene (estimator)':18s} {'neural 1spp':>11s} {'+WRLS':>7s} {'PT 64spp':>9s} {'goal':>5s} | "
          f"{'PT 1spp':>8s} {'+WRLS':>7s} | flicker noisy / WRLS / ref (neural)  | ms denoise / depth (256^2)")
    for name in [] if args.timing_only else scenes:
        r = run_scene(name, args, params, given)
        if args.progressive_frames > 0:
            r["static_camera"] = run_progressive(name, args, params, given)
        results[name] = r
        e, f = r["rel_l2"], r["flicker"]
        label = f"{name} ({r['camera_estimator']})"
        print(f"{label:18s} {e['noisy_neural']:11.3f} {e['wrls_neural']:7.3f} {e['pt64']:9.3f} "
              f"{'yes' if r['goal_rel_l2'] else 'no':>5s} | {e['noisy_pt']:8.3f} {e['wrls_pt']:7.3f} | "
              f"{f['noisy_neural']:.3f} / {f['wrls_neural']:.3f} / {f['ref']:.3f} "
              f"({r['flicker_reduction_neural']:.1f}x)    | {r['ms_per_frame']['denoise']:.1f} / "
              f"{r['ms_per_frame']['depth']:.1f}", flush=True)
        te = r["temporal_error"]
        print(f"{'':18s} temporal error (frame-to-frame change of the error) neural noisy / WRLS "
              f"{te['noisy_neural']:.3f} / {te['wrls_neural']:.3f} ({r['temporal_error_reduction_neural']:.1f}x), "
              f"path tracer {te['noisy_pt']:.3f} / {te['wrls_pt']:.3f}", flush=True)
        if "static_camera" in r:
            st = r["static_camera"]
            cells = [f"{n}: {st['running_mean'][n]:.3f} / {st['wrls_of_running_mean'][n]:.3f} / "
                     f"{st['wrls_of_frames'][n]:.3f}" for n in st["running_mean"]]
            print(f"         static camera, frames {'  '.join(cells)}   (running mean / WRLS of it / WRLS of each "
                  "frame)", flush=True)
    timing = None
    timings: dict[str, Any] = {}
    if not args.no_timing:
        sides = [Side("new", "photon_fields")]
        if args.base:
            sides.insert(0, base_side(args.base))
        for name in parse_scenes(args.timing_scene.split(",")):
            timings[name] = run_timing(args, params, given, name, sides)
            print_timing(timings[name])
            results[f"_timing_{name}"] = {"other_cores": timings[name]["other_cores"]}
        timing = next(iter(timings.values()))
    info = finish_info(info, results)
    for name in timings:
        results.pop(f"_timing_{name}", None)
    config = {"size": args.size, "frames": args.frames, "warmup": args.warmup,
              "degrees_per_frame": args.degrees_per_frame, "ref_spp": args.ref_spp, "pt_spp": PT_SPP,
              "params": asdict(WRLSParams(**params)), "progressive_frames": args.progressive_frames,
              "timing_size": args.timing_size, "timing_scenes": list(timings), "base": args.base,
              "timing_frames": args.timing_frames, "camera": args.camera}
    write_report(args.out, "denoise", info, config, scenes=results, timing=timing, timing_scenes=timings)


if __name__ == "__main__":
    main()
