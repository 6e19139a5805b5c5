"""PVRT (Zhang, Dong, Ma 2013; runtime/pvrt): precomputation cost, frame time after a light change, and the
error against the path tracer (and against a neural field retrained for each light) under several lights.

Per builtin scene (default vortex, at ``--resolution``^3 voxels, its directional light only):

1. precompute a transfer (``--grid``, ``--order``, ``--paths`` per basis light): trace and CPCA seconds, the
   process's peak RSS growth (``ru_maxrss``), the file's size;
2. frame time after a light change at each of ``--sizes`` (1 spp; the light direction changes before every frame,
   so every frame re-projects the lighting, re-evaluates the radiance volume and re-marches the light volume):
   median and best of ``--repeats`` frames after a warm-up, with the stages' split (of the median frame), for
   ``render_pvrt`` (the whole march: what a frame after a camera change costs too) and for ``Relighting`` (the
   view kept: the camera samples marched once, their cost reported as "keep", and summed under each new light),
   and the largest relative difference of the two frames' L_d and L_i (the float32 of the kept samples);
3. accuracy, per light: the scene's directional light turned about the vertical axis in ``--dirs`` + 1 even steps
   (default 8 directions, 45 degrees apart), then each of ``--maps`` (default two environment maps built here, no
   files: "sky", bench_envmap's sky with a small warm sun, and "studio", three soft patches on a dark background;
   64 x 128) replacing the scene's lights. The one transfer of step 1 is relit for every light (the point of PVRT).
   PVRT (``--pvrt-spp`` samples: its jittered march and NEE are noisy too, like the neural renderer's) against two
   path-traced images (``--ref-spp`` each, seeds 1 and 2; cached in ``--work``) at ``--ref-size``:
   mean ratios of L_d, L_i and L, the relative L2 of L and L_i and the SSIM of L against the first reference,
   beside the references' own rel. L2 (the L2 between the two / sqrt 2: what the reference's noise alone gives);
4. with ``--neural`` (slow): for each light a neural field trained for exactly that scene and light
   (``--neural-photons`` photons, preset ``--neural-preset``, as bench_render.bundle_for; the run and bundle cached
   in ``--work`` by scene, resolution, light, photons and preset, reused while the bundle's scene fingerprint is the
   scene's), rendered at ``--neural-spp`` (seed 7): its tracing and fitting seconds, the same errors, and PVRT's
   rel. L2 of L over the field's, raw and without the reference's noise ("clean", sqrt(e^2 - noise^2) of each: the
   issue's goal, <= 1.5 for every light, is judged on it);
5. one PNG per scene beside the JSON (``<json stem>_<scene>_lights.png``, e.g. ``pvrt_vortex_lights.png``): a row per
   light, columns reference | PVRT | neural, all of a row tone-mapped with the reference's automatic exposure
   (recorded per row in the JSON), each image labelled with the light and its rel. L2 of L.

Output: a table and JSON (default ``bench/results/pvrt.json``) with the machine record (CPU model, load).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_envmap import sky  # noqa: E402
from common import Contention, finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.eval.metrics import relative_l2, ssim  # noqa: E402
from photon_fields.runtime.io.images import auto_exposure_stops, tonemap_srgb, write_png  # noqa: E402
from photon_fields.runtime.pvrt.transfer import precompute_transfer, save_transfer  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.pvrt import Relighting, render_pvrt  # noqa: E402
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentMap  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "pvrt.json"
DEFAULT_WORK = HERE / "results" / "pvrt"
MAP_HEIGHT = 64  # the environment maps' rows (128 columns)
CELL = 192  # at least this many pixels a side per image of the PNG (nearest-neighbour enlarged)


def with_lights(scene: Scene, lights: tuple) -> Scene:
    """``scene`` with other lights. The medium ignores the lights, so the copy shares it, as the viewer's scene
    after a light edit does (``runtime/viewer/session.py``): a light change rebuilds no majorant grid."""
    out = replace(scene, lights=tuple(lights), _cache={})
    if "medium" in scene._cache:
        out._cache["medium"] = scene._cache["medium"]
    return out


def turned(scene: Scene, degrees: float) -> Scene:
    """``scene`` with its directional lights (only) turned by ``degrees`` about the vertical (y) axis."""
    a = math.radians(degrees)
    r = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    return with_lights(scene, tuple(DirectionalLight(r @ lt.direction, lt.color, lt.power) for lt in scene.lights
                                    if isinstance(lt, DirectionalLight)))


def studio(h: int) -> np.ndarray:
    """A studio: three soft bright patches (key, fill, rim: angular Gaussians about the directions light arrives
    from, in the map's lat-long convention, ``runtime/transport/environment_map.py``) on a dark grey background."""
    theta = np.pi * (np.arange(h) + 0.5) / h
    phi = 2 * np.pi * (np.arange(2 * h) + 0.5) / (2 * h)
    tt, pp = np.meshgrid(theta, phi, indexing="ij")
    w = np.stack([np.sin(tt) * np.sin(pp), np.cos(tt), -np.sin(tt) * np.cos(pp)], axis=-1)
    img = np.full((h, 2 * h, 3), 0.02)
    for towards, width, rgb in (([1.0, 0.8, 0.3], 0.25, [10.0, 9.5, 8.5]),  # key: above, right of the camera
                                ([-0.2, 0.1, 1.0], 0.35, [1.6, 1.9, 2.4]),  # fill: low, bluish, left of it
                                ([-0.7, 0.4, -0.7], 0.2, [12.0, 12.0, 12.0])):  # rim: behind the volume
        d = np.asarray(towards) / np.linalg.norm(towards)
        img += np.exp((w @ d - 1.0) / width**2)[..., None] * np.asarray(rgb)
    return img.astype(np.float32)


MAPS = {"sky": sky, "studio": studio}


def lights_of(base: Scene, dirs: int, maps: list[str]) -> list[tuple[str, dict[str, Any], Scene]]:
    """(tag, description, scene) per light: the scene's directional light turned in ``dirs`` + 1 even steps about
    y, then each environment map alone (the base's medium shared)."""
    out = []
    for i in range(dirs + 1):
        deg = 360.0 / (dirs + 1) * i
        scene = turned(base, deg)
        out.append((f"{deg:.0f}", {"kind": "directional", "turn_degrees": deg,
                                   "direction": [float(x) for x in scene.lights[0].direction]}, scene))
    for name in maps:
        out.append((name, {"kind": "environment_map", "map": name, "map_shape": [MAP_HEIGHT, 2 * MAP_HEIGHT]},
                    with_lights(base, (EnvironmentMap(name, image=MAPS[name](MAP_HEIGHT)),))))
    return out


def reference(scene: Scene, spp: int, seed: int, work: Path, tag: str) -> dict[str, np.ndarray]:
    """Path-traced layers (cached as .npz in ``work``, with the scene's fingerprint: another scene re-renders)."""
    cam = scene.camera
    path = work / f"ref_{scene.name}_{tag}_{cam.width}x{cam.height}_{spp}_{seed}.npz"
    if path.exists():
        with np.load(path) as z:
            if "fingerprint" not in z.files or str(z["fingerprint"]) == scene.fingerprint():
                return {k: z[k] for k in ("L", "L_d", "L_i")}
        print(f"  reference {path.name} is of another scene (fingerprint): rendering it again", flush=True)
    t0 = time.perf_counter()
    path.parent.mkdir(parents=True, exist_ok=True)
    layers = render_path_traced(scene, spp=spp, seed=seed, progress=False).layers
    np.savez(path, fingerprint=np.array(scene.fingerprint()), **{k: layers[k] for k in ("L", "L_d", "L_i")})
    print(f"  reference {tag} {spp} spp seed {seed}: {time.perf_counter() - t0:.0f} s", flush=True)
    return {k: layers[k] for k in ("L", "L_d", "L_i")}


def neural_field(scene: Scene, tag: str, args: argparse.Namespace) -> tuple[Path, dict[str, Any]]:
    """The bundle of a field trained for exactly ``scene`` (its light included), as ``bench_render.bundle_for``
    trains one, and its training record: cached in ``--work`` and reused while the bundle records this scene's
    fingerprint (a field is tied to its lights: ``PhotonField.load`` refuses another scene's); else trained now."""
    from photon_fields.runtime.field.bundle_reader import read_manifest

    folder = args.work / f"field_{scene.name}_{args.resolution}_{tag}_{args.neural_photons}_{args.neural_preset}"
    bundle, record = folder / "field.pfn", folder / "train.json"
    fp = scene.fingerprint()
    if bundle.is_dir() and record.is_file():
        recorded = read_manifest(bundle).scene_fingerprint
        if recorded == fp:
            return bundle, {**json.loads(record.read_text()), "cached": True}
        print(f"  {folder.name}: trained for another scene (fingerprint {recorded[:12]}, not {fp[:12]}): "
              "training again", flush=True)
    from bench_render import train_field

    from photon_fields.train.export.bundle import export_bundle, write_run_domain

    run = folder / "run"
    with Contention() as c:
        records, trace_s, fit_s = train_field(scene, run, args.neural_photons, args.neural_preset)
    write_run_domain(run, scene)
    export_bundle(run, bundle, scene=scene, force=True)
    doc = {"trace_s": trace_s, "fit_s": fit_s, "photon_records": records, "preset": args.neural_preset,
           "fingerprint": fp, "other_cores": c.other_cores}
    record.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"  field {tag}: traced {records} photon records in {trace_s:.0f} s, fitted ({args.neural_preset}) "
          f"in {fit_s:.0f} s", flush=True)
    return bundle, {**doc, "cached": False}


def errors(got: dict[str, np.ndarray], ref: dict[str, np.ndarray], ref_noise: float) -> dict[str, float]:
    """Mean ratios of L_d, L_i and L, rel. L2 of L and L_i, SSIM of L: ``got`` against ``ref``; and the rel. L2 of L
    without the reference's own noise ``ref_noise`` (sqrt(e^2 - noise^2): independent errors add in squares)."""
    e = float(relative_l2(got["L"], ref["L"]))
    return {**{f"{k}_ratio": float(got[k].mean() / ref[k].mean()) for k in ("L_d", "L_i", "L")},
            "rel_l2_L": e, "rel_l2_L_without_ref_noise": math.sqrt(max(0.0, e * e - ref_noise * ref_noise)),
            "rel_l2_L_i": float(relative_l2(got["L_i"], ref["L_i"])), "ssim_L": float(ssim(got["L"], ref["L"]))}


def accuracy(name: str, base: Scene, transfer: Any, args: argparse.Namespace) -> tuple[list[dict[str, Any]], Path]:
    """Step 3-5 of the module docstring for one scene: the rows, printed as they come, and the PNG's path."""
    if args.neural:
        from photon_fields.runtime.field.field import PhotonField
        from photon_fields.runtime.renderers.neural import render_neural
    rows, images = [], []
    print(f"  {'light':>8s} {'L_d':>6s} {'L_i':>6s} {'L':>6s} | {'PVRT L2':>7s} {'SSIM':>5s} | {'neural L2':>9s} "
          f"{'SSIM':>5s} {'ratio':>5s} {'clean':>6s} {'train s':>7s} | {'ref noise':>9s}")
    for tag, about, lit in lights_of(base, args.dirs, args.maps):
        scene = lit.with_overrides(width=args.ref_size, height=args.ref_size)
        refs = [reference(scene, args.ref_spp, seed, args.work, f"{args.resolution}_{tag}") for seed in (1, 2)]
        t0 = time.perf_counter()
        got = render_pvrt(scene, transfer=transfer, spp=args.pvrt_spp, seed=7, progress=False).layers
        ref_noise = float(relative_l2(refs[1]["L"], refs[0]["L"]) / math.sqrt(2))
        row: dict[str, Any] = {"light": tag, **about, **errors(got, refs[0], ref_noise),
                               "pvrt_render_s": time.perf_counter() - t0, "ref_noise_rel_l2_L": ref_noise,
                               "ref_noise_rel_l2_L_i": float(relative_l2(refs[1]["L_i"], refs[0]["L_i"])
                                                             / math.sqrt(2))}
        cells = [refs[0]["L"], got["L"]]
        neural = ""
        if args.neural:
            bundle, train = neural_field(lit, tag, args)
            est = PhotonField.load(bundle, expected_fingerprint=scene.fingerprint()).estimator()
            t0 = time.perf_counter()
            layers = render_neural(scene, est, spp=args.neural_spp, seed=7, progress=False).layers
            row["neural"] = {**errors(layers, refs[0], ref_noise), "render_s": time.perf_counter() - t0,
                             "spp": args.neural_spp, "bundle": str(bundle), "train": train}
            row["pvrt_over_neural_rel_l2_L"] = row["rel_l2_L"] / row["neural"]["rel_l2_L"]
            # the goal, judged without the reference's noise (common to both, it pulls the ratio towards 1)
            clean = "rel_l2_L_without_ref_noise"
            row["pvrt_over_neural_without_ref_noise"] = row[clean] / max(row["neural"][clean], 1e-12)
            row["goal_met"] = row["pvrt_over_neural_without_ref_noise"] <= 1.5
            cells.append(layers["L"])
            nr = row["neural"]
            neural = (f"{nr['rel_l2_L']:9.3f} {nr['ssim_L']:5.3f} {row['pvrt_over_neural_rel_l2_L']:5.2f} "
                      f"{row['pvrt_over_neural_without_ref_noise']:6.2f} {train['trace_s'] + train['fit_s']:7.0f}")
        row["png_exposure_stops"] = auto_exposure_stops(refs[0]["L"])
        rows.append(row)
        images.append([tonemap_srgb(img, row["png_exposure_stops"]) for img in cells])
        print(f"  {tag:>8s} {row['L_d_ratio']:6.3f} {row['L_i_ratio']:6.3f} {row['L_ratio']:6.3f} | "
              f"{row['rel_l2_L']:7.3f} {row['ssim_L']:5.3f} | {neural or '-':>36s} | {row['ref_noise_rel_l2_L']:9.3f}",
              flush=True)
    png = args.out.parent / f"{args.out.stem}_{name}_lights.png"
    write_png(png, side_by_side(images, rows, ["reference", "PVRT", "neural"]))
    print(f"  images: {png}", flush=True)
    return rows, png


def side_by_side(images: list[list[np.ndarray]], rows: list[dict[str, Any]], columns: list[str]) -> np.ndarray:
    """One uint8 image: a row per light, a column per renderer, each cell enlarged to >= CELL pixels a side (nearest),
    2 px of grey between cells, and a label (light, renderer, rel. L2 of L) in each cell's corner."""
    from PIL import Image, ImageDraw

    h, w = images[0][0].shape[:2]
    k = max(1, -(-CELL // max(h, w)))
    gap = 2
    n = max(len(r) for r in images)
    canvas = np.full((len(images) * (h * k + gap) - gap, n * (w * k + gap) - gap, 3), 64, np.uint8)
    for i, cells in enumerate(images):
        for j, img in enumerate(cells):
            y, x = i * (h * k + gap), j * (w * k + gap)
            canvas[y:y + h * k, x:x + w * k] = np.repeat(np.repeat(img, k, axis=0), k, axis=1)
    pil = Image.fromarray(canvas)
    draw = ImageDraw.Draw(pil)
    for i, row in enumerate(rows):
        errs = ["", f"{row['rel_l2_L']:.3f}", f"{row['neural']['rel_l2_L']:.3f}" if "neural" in row else ""]
        for j in range(len(images[i])):
            y, x = i * (h * k + gap), j * (w * k + gap)
            text = f"{row['light']} {columns[j]} {errs[j]}".strip()
            draw.text((x + 4, y + 3), text, fill=(0, 0, 0))
            draw.text((x + 3, y + 2), text, fill=(255, 255, 255))
    return np.asarray(pil)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["vortex"], help="builtin scenes with a directional light")
    ap.add_argument("--resolution", type=int, default=48, help="voxels along each side of the builtin volume")
    ap.add_argument("--grid", type=int, default=None,
                    help="transfer cells along the longest side (default: the product's, runtime/pvrt/constants.py)")
    ap.add_argument("--order", type=int, default=None, help="DSF order (default: the product's; 2: 162 basis lights)")
    ap.add_argument("--paths", type=int, default=None, help="photon paths per basis light (default: the product's)")
    ap.add_argument("--sizes", type=int, nargs="*", default=[256, 512], help="frame sizes timed (square)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ref-size", type=int, default=96)
    ap.add_argument("--ref-spp", type=int, default=64)
    ap.add_argument("--dirs", type=int, default=7,
                    help="light directions besides the scene's (turned in steps of 360 / (dirs + 1) deg)")
    ap.add_argument("--maps", nargs="*", default=list(MAPS), choices=list(MAPS),
                    help="environment maps (built here), each replacing the scene's lights")
    ap.add_argument("--neural", action="store_true", help="also a neural field trained for each light (slow)")
    ap.add_argument("--neural-photons", type=int, default=1_000_000, help="photon records a field is trained on")
    ap.add_argument("--neural-preset", default="cpu", help="training preset of the fields (train/fit/presets.py)")
    ap.add_argument("--neural-spp", type=int, default=64, help="samples per pixel of the neural renders")
    ap.add_argument("--pvrt-spp", type=int, default=64,
                    help="samples per pixel of the PVRT renders compared (their march jitter and NEE are noisy too)")
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    info = machine_info()
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes):
        scene0 = builtin_scene(name, args.resolution)
        if not any(isinstance(lt, DirectionalLight) for lt in scene0.lights):
            raise SystemExit(f"scene {name} has no directional light")
        base = turned(scene0, 0.0)
        rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        with Contention() as c_pre:
            t0 = time.perf_counter()
            given = {k: v for k, v in (("order", args.order), ("grid", args.grid), ("paths", args.paths))
                     if v is not None}
            transfer = precompute_transfer(base, seed=0, progress=False, **given)
            pre_s = time.perf_counter() - t0
        peak_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
        with tempfile.TemporaryDirectory() as tmp:
            size_mb = save_transfer(transfer, Path(tmp) / "t.pvrt").stat().st_size / 1e6
        pre = {"seconds": pre_s, **(transfer.seconds or {}), "peak_rss_growth_mb": peak_mb, "file_mb": size_mb,
               "grid": transfer.manifest["grid"], "basis_lights": transfer.basis.size,
               "basis": transfer.manifest["basis"], "exitance_order": transfer.exitance_order,
               "paths_per_basis": transfer.manifest["photons"]["paths_per_basis"],
               "cpca_settings": {k: transfer.manifest["cpca"][k] for k in ("clusters", "bases")},
               "cpca_relative_error": transfer.manifest["cpca"]["relative_error"], "other_cores": c_pre.other_cores}
        print(f"\n{name} {args.resolution}^3: precompute {pre_s:.1f} s (trace {pre.get('trace', 0):.1f}, CPCA "
              f"{pre.get('cpca', 0):.1f}), peak RSS +{peak_mb:.0f} MB, file {size_mb:.1f} MB, grid {pre['grid']}, "
              f"{pre['basis_lights']} basis lights, CPCA error {pre['cpca_relative_error']:.3f}", flush=True)
        frames: dict[str, Any] = {}
        for size in args.sizes:
            scene = base.with_overrides(width=size, height=size)
            render_pvrt(turned(scene, 7.0), transfer=transfer, progress=False)  # warm-up (compiles)
            t0 = time.perf_counter()
            relit = Relighting(scene, transfer)
            keep_ms = (time.perf_counter() - t0) * 1e3
            relit.render(turned(scene, 7.0).lights)  # warm-up
            times: dict[str, list[float]] = {"march": [], "relit": []}
            stages: dict[str, list[dict[str, float]]] = {"march": [], "relit": []}
            diff = 0.0
            with Contention() as c:
                for r in range(args.repeats):
                    lit = turned(scene, 15.0 * (r + 1))  # a light change before every frame
                    layers = {}
                    for kind in ("march", "relit"):
                        t0 = time.perf_counter()
                        res = (render_pvrt(lit, transfer=transfer, progress=False) if kind == "march"
                               else relit.render(lit.lights))
                        times[kind].append((time.perf_counter() - t0) * 1e3)
                        stages[kind].append(res.timings_ms)
                        layers[kind] = res.layers
                    diff = max(diff, *(float(np.abs(layers["relit"][k] - layers["march"][k]).max()
                                             / max(float(np.abs(layers["march"][k]).max()), 1e-30))
                                       for k in ("L_d", "L_i")))
            row: dict[str, Any] = {"keep_ms": keep_ms, "kept_samples": relit.samples, "relit_max_rel_diff": diff,
                                   "other_cores": c.other_cores}
            for kind, prefix in (("march", ""), ("relit", "relit_")):
                mid = int(np.argsort(times[kind])[len(times[kind]) // 2])
                best = int(np.argmin(times[kind]))
                row.update({f"{prefix}median_ms": float(np.median(times[kind])), f"{prefix}ms": times[kind],
                            f"{prefix}stages_ms": stages[kind][mid], f"{prefix}best_stages_ms": stages[kind][best]})
                split = ", ".join(f"{k} {v:.0f}" for k, v in sorted(stages[kind][mid].items(), key=lambda kv: -kv[1])
                                  if k != "total")
                what = "march" if kind == "march" else "relit (kept samples)"
                print(f"  frame {size}x{size} after a light change, {what}: {np.median(times[kind]):.0f} ms, best "
                      f"{min(times[kind]):.0f} ({split})", flush=True)
            print(f"  kept {relit.samples} camera samples in {keep_ms:.0f} ms; relit vs march: max rel. diff "
                  f"{diff:.1e}", flush=True)
            frames[f"{size}x{size}"] = row
        rows, png = accuracy(name, base, transfer, args)
        results[name] = {"precompute": pre, "frames": frames, "accuracy": rows, "png": str(png)}
    # machine_busy from the precompute's and the timed frames' foreign load (the accuracy part is not timed)
    info = finish_info(info, {name: {"other_cores": max([r["precompute"]["other_cores"] or 0.0]
                                                        + [f["other_cores"] or 0.0 for f in r["frames"].values()])}
                              for name, r in results.items()})
    write_report(args.out, "pvrt", info, {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                 results=results)


if __name__ == "__main__":
    main()
