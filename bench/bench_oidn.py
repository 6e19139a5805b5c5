"""Intel Open Image Denoise (``photon_fields.runtime.denoise.oidn``): what it costs, and whether an albedo helps it.

Two parts, everything in one process after a warm-up:

1. **Cost**: ms per image at each ``--sizes`` (default 256 and 512 square): the first call of the process
   (importing pyoidn, creating the device and filter), then the reused filter (best of ``--repeats``), with one
   thread, and at quality "fast".
2. **Albedo** (the data behind the choice of ``pfn-render --denoise oidn``, docs/rendering.md): per scene at
   ``--size`` (default 256x256), against the path tracer at ``--ref-spp`` (default 512; the references of
   ``bench_equal_error.py``, cached in its ``--work``), the rel. L2 (mean over ``--seeds`` seeds) of the path tracer
   and the neural renderer (forced camera estimator) at ``--spps`` (default 1 and 4), noisy and denoised
   - with colour only (what ``--denoise oidn`` does),
   - with a *same-sample* albedo AOV: the mean over the image's own samples of albedo(x1) * W at each camera ray's
     first interaction x1 (0 where none; the path tracer's first vertex, W = 1), the AOV a renderer would add,
   - with a *noise-free* albedo: its expectation, E[albedo(x1) W] = integral of albedo sigma_t T along the ray,
     marched at ``--march-step`` voxels along one jittered ray per pixel (no Monte Carlo noise, but a pass of its
     own: its ms is reported),
   - with colour only at quality "fast";
   with the frame's, OIDN's and the albedo pass's ms (best over the seeds).

Bundles: ``--bundle SCENE=PATH``, else those of ``bench_render.py`` (trained there when missing). Output: tables
on stdout and JSON (default ``bench/results/oidn.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_equal_error import DEFAULT_WORK, reference  # noqa: E402
from bench_render import bundle_for  # noqa: E402
from common import Contention, finish_info, machine_info, parse_scenes, write_report  # noqa: E402
from numba import njit, prange  # noqa: E402

from photon_fields.runtime.denoise.oidn import denoise_oidn, oidn_version, require_oidn  # noqa: E402
from photon_fields.runtime.eval.metrics import relative_l2  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.renderers.neural import render_neural  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402
from photon_fields.runtime.transport.medium import Medium, albedo_at, extinction_at  # noqa: E402
from photon_fields.runtime.transport.rng import next_float  # noqa: E402
from photon_fields.runtime.wavefront.first_interaction import (  # noqa: E402
    FirstInteractions,
    compact_first_interactions,
    sample_first_interactions,
)
from photon_fields.runtime.wavefront.rays import clip_rays_to_volume, generate_camera_rays  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "oidn.json"


def same_sample_albedo(scene: Scene, spp: int, seed: int, camera: str) -> np.ndarray:
    """Mean over the ``spp`` samples of albedo(x1) * W at each camera ray's first interaction, with the renderers'
    own random streams (``camera`` "delta": the path tracer's first vertices, bit for bit; "forced": the neural
    renderer's)."""
    cam, m = scene.camera, scene.medium()
    n = cam.width * cam.height
    total = n * spp
    batch = min(1 << 18, total)
    scratch, status, transmit = FirstInteractions.empty(batch), np.empty(batch, np.uint8), np.empty(batch)
    acc = np.zeros((3, n))
    for start in range(0, total, batch):
        count = min(batch, total - start)
        counts = sample_first_interactions(scene, m, start, count, seed, scratch, status, transmit, camera)
        fi = compact_first_interactions(scratch, counts)
        w = fi.albedo * fi.weight if camera == "forced" else fi.albedo
        for c in range(3):
            acc[c] += np.bincount(fi.pixel, weights=w[c], minlength=n)
    # W is an unbiased estimate of a probability, so a pixel's mean can exceed 1 by noise: clipped, as OIDN wants
    return np.clip((acc / spp).T.reshape(cam.height, cam.width, 3), 0.0, 1.0).astype(np.float32)


@njit(cache=True, parallel=True)
def _march_albedo(m: Medium, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, states: np.ndarray, h: float,
                  out: np.ndarray) -> None:
    for i in prange(o.shape[1]):
        states[i], jitter = next_float(states[i])
        T, t_prev, t = 1.0, 0.0, jitter * h
        while t_prev < tmax[i] and T > 1e-4:
            t_next = min(t, tmax[i])
            seg = t_next - t_prev
            tm = 0.5 * (t_prev + t_next)
            x, y, z = o[0, i] + tm * d[0, i], o[1, i] + tm * d[1, i], o[2, i] + tm * d[2, i]
            sigma = extinction_at(m, x, y, z)
            if sigma > 0.0 and seg > 0.0:
                a0, a1, a2 = albedo_at(m, x, y, z)
                w = T * (1.0 - math.exp(-sigma * seg))
                out[0, i] += w * a0
                out[1, i] += w * a1
                out[2, i] += w * a2
                T *= math.exp(-sigma * seg)
            t_prev = t_next
            t = t_next + h


def marched_albedo(scene: Scene, seed: int, step: float) -> np.ndarray:
    """E[albedo(x1) W] per pixel: one jittered camera ray per pixel, the albedo marched along it (no Monte Carlo
    noise from the first interaction, only the midpoint rule's error)."""
    cam, m = scene.camera, scene.medium()
    n = cam.width * cam.height
    rays = generate_camera_rays(cam, np.arange(n, dtype=np.int64), seed)
    rays = rays.compact(clip_rays_to_volume(m, rays))
    out = np.zeros((3, len(rays)))
    _march_albedo(m, rays.o, rays.d, rays.tmax, rays.rng, step * scene.volume.voxel_size, out)
    acc = np.zeros((3, n))
    for c in range(3):
        acc[c] = np.bincount(rays.pixel, weights=out[c], minlength=n)
    return acc.T.reshape(cam.height, cam.width, 3).astype(np.float32)


def cost(sizes: list[int], repeats: int) -> dict[str, Any]:
    """ms per image of the denoiser at each size: first call of the process, reused filter, 1 thread, fast."""
    t0 = time.perf_counter()
    require_oidn()
    out: dict[str, Any] = {"import_ms": (time.perf_counter() - t0) * 1e3}
    rng = np.random.default_rng(0)
    for k, size in enumerate(sizes):
        y, x = np.mgrid[0:size, 0:size] / size
        img = np.stack([x, y, 1 - x], axis=-1) * rng.gamma(2.0, 0.5, (size, size, 3))
        img = img.astype(np.float32)

        def best(**kw: Any) -> float:
            times = []
            for _ in range(repeats):
                t = time.perf_counter()
                denoise_oidn(img, **kw)  # noqa: B023
                times.append((time.perf_counter() - t) * 1e3)
            return min(times)

        with Contention() as busy:
            t = time.perf_counter()
            denoise_oidn(img)
            first = (time.perf_counter() - t) * 1e3
            row = {"first_call_ms": first, "reused_ms": best(), "one_thread_ms": best(threads=1),
                   "fast_ms": best(quality="fast")}
        row["other_cores"] = busy.other_cores
        if k == 0:
            row["note"] = "first_call_ms: creates the device and filter (the import is import_ms)"
        out[f"{size}x{size}"] = row
        print(f"  {size}x{size}: " + ", ".join(f"{k} {v:.1f}" for k, v in row.items() if k.endswith("_ms"))
              + f" (other processes kept {row['other_cores']} cores busy)", flush=True)
    return out


def albedo_rows(scene: Scene, est: Any, ref: np.ndarray, args: argparse.Namespace) -> dict[str, Any]:
    """Per method and spp, the mean rel. L2 over the seeds of every variant (module docstring)."""
    rows: dict[str, Any] = {}
    for method in ("path tracer", "neural forced"):
        for spp in args.spps:
            errs: dict[str, list[float]] = {}
            march_ms, oidn_ms, render_ms = [], [], []
            for seed in range(args.seeds):
                t = time.perf_counter()
                if method == "path tracer":
                    img = render_path_traced(scene, spp=spp, seed=seed, progress=False).layers["L"]
                    render_ms.append((time.perf_counter() - t) * 1e3)
                    same = same_sample_albedo(scene, spp, seed, "delta")
                else:
                    img = render_neural(scene, est, spp=spp, seed=seed, progress=False, camera="forced").layers["L"]
                    render_ms.append((time.perf_counter() - t) * 1e3)
                    same = same_sample_albedo(scene, spp, seed, "forced")
                t = time.perf_counter()
                clean = marched_albedo(scene, seed + 1000, args.march_step)
                march_ms.append((time.perf_counter() - t) * 1e3)
                t = time.perf_counter()
                colour = denoise_oidn(img)
                oidn_ms.append((time.perf_counter() - t) * 1e3)
                variants = (("noisy", img), ("oidn", colour), ("oidn + same-sample albedo", denoise_oidn(img, same)),
                            ("oidn + noise-free albedo", denoise_oidn(img, clean)),
                            ("oidn fast", denoise_oidn(img, quality="fast")))
                for name, out in variants:
                    errs.setdefault(name, []).append(relative_l2(out, ref))
            row = {k: float(np.mean(v)) for k, v in errs.items()}
            row.update({"render_ms": float(min(render_ms)), "oidn_ms": float(min(oidn_ms)),
                        "noise_free_albedo_ms": float(min(march_ms))})
            rows[f"{method} {spp} spp"] = row
            print(f"  {method + f' {spp} spp':22s} " + " ".join(f"{row[k]:8.4f}" for k in errs)
                  + f" {row['render_ms']:9.0f} {row['oidn_ms']:8.0f} {row['noise_free_albedo_ms']:8.0f}", flush=True)
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--size", type=int, default=256, help="albedo part: image side")
    ap.add_argument("--sizes", type=int, nargs="*", default=[256, 512], help="cost part: image sides")
    ap.add_argument("--ref-spp", type=int, default=512)
    ap.add_argument("--spps", type=int, nargs="*", default=[1, 4])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--march-step", type=float, default=1.0, help="noise-free albedo: step in voxels")
    ap.add_argument("--bundle", action="append", default=[], metavar="SCENE=PATH")
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK, help="reference cache (bench_equal_error.py's)")
    ap.add_argument("--parts", nargs="*", default=["cost", "albedo"], choices=["cost", "albedo"])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    given = dict(b.split("=", 1) for b in args.bundle)
    info = machine_info()
    costs: dict[str, Any] = {}
    if "cost" in args.parts:
        print(f"OIDN cost (pyoidn {oidn_version()}), ms per image")
        costs = cost(args.sizes, args.repeats)
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes) if "albedo" in args.parts else []:
        base = builtin_scene(name)
        scene = base.with_overrides(width=args.size, height=args.size)
        est = PhotonField.load(bundle_for(name, base, given), expected_fingerprint=base.fingerprint()).estimator()
        ref = reference(scene, args.ref_spp, args.work)
        warm = scene.with_overrides(width=16, height=16)
        render_path_traced(warm, spp=1, progress=False)
        render_neural(warm, est, spp=1, progress=False)
        marched_albedo(warm, 0, args.march_step)
        print(f"\n{name} ({args.size}x{args.size}, rel. L2 against the path tracer at {args.ref_spp} spp, mean of "
              f"{args.seeds} seeds)")
        print(f"  {'':22s} {'noisy':>8s} {'oidn':>8s} {'+same':>8s} {'+clean':>8s} {'fast':>8s} {'render ms':>9s} "
              f"{'oidn ms':>8s} {'clean ms':>8s}")
        results[name] = albedo_rows(scene, est, ref, args)
    info = finish_info(info, {size: row for size, row in costs.items() if isinstance(row, dict)})
    write_report(args.out, "oidn", info, {"size": args.size, "sizes": args.sizes, "ref_spp": args.ref_spp,
                                          "spps": args.spps, "seeds": args.seeds, "repeats": args.repeats,
                                          "march_step": args.march_step, "pyoidn": oidn_version()},
                 cost=costs, scenes=results)


if __name__ == "__main__":
    main()
