"""Probe: where the noise of a 1-spp frame's L_d comes from with the forced camera estimator.

Issue 14 asks for a camera estimator with less variance at equal time. The forced estimator's L_d sample of a
pixel is ``W a(x) NEE(x)``: W the camera walk's estimate of the collision probability 1 - T(t_max), x the collision
resampled along the ray, NEE one ratio-tracked shadow ray per light. Three sources of noise, separated here by
replacing one at a time with a (nearly) noise-free version, on the same collisions:

- **shadow**: NEE averaged over ``--shadow-rays`` (default 16) independent shadow rays instead of one;
- **W**: the mean of ``--walks`` (default 64) independent camera walks' W instead of the walk's own (the collision
  stays the first walk's);
- **placement**: what is left with both, i.e. where along the ray the collision falls, and the pixel jitter.

Variance shares follow by differences of squared relative noise (rel. RMS deviation from a ``--ref-frames``-frame
mean of the plain estimator, over the reference's RMS). The FORCED_MIN_WEIGHT roulette of the renderer is left
out (it does not change these shares measurably). What the shares imply: K collisions per camera walk, each with
its own shadow ray, divide the shadow and placement variance by K and leave W's; a better transmittance estimator
for shadow rays removes at most the shadow share.

Output: a table on stdout and JSON (default ``bench/results/camera_noise.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from common import finish_info, machine_info, parse_scenes, write_report  # noqa: E402
from numba import njit, prange  # noqa: E402

from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402
from photon_fields.runtime.transport.direct_light import direct_light_batch  # noqa: E402
from photon_fields.runtime.transport.medium import Medium, albedo_at  # noqa: E402
from photon_fields.runtime.transport.tracking import resampled_collision  # noqa: E402
from photon_fields.runtime.wavefront.rays import camera_ray, clip_to_box  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "camera_noise.json"
_GOLDEN = 0x9E3779B97F4A7C15


@njit(cache=True, parallel=True)
def _collisions(m: Medium, eye: np.ndarray, origin: np.ndarray, du: np.ndarray, dv: np.ndarray, width: int, n: int,
                first: int, seed: int, walks: int, x: np.ndarray, d: np.ndarray, albedo: np.ndarray,
                w_own: np.ndarray, w_mean: np.ndarray, hit: np.ndarray, rng: np.ndarray) -> None:
    """Per pixel: the forced estimator's collision and W (as the renderer draws them), and the mean W of
    ``walks`` walks along the same ray (the first is the renderer's)."""
    for i in prange(n):
        dx, dy, dz, _, s = camera_ray(origin, du, dv, width, n, first + i, np.uint64(seed))
        inside, ox, oy, oz, tmax = clip_to_box(m, eye[0], eye[1], eye[2], dx, dy, dz)
        hit[i] = False
        if not inside:
            continue
        t, w, _, s = resampled_collision(m, ox, oy, oz, dx, dy, dz, 0.0, tmax, s)
        total = w
        for k in range(walks - 1):
            other = s ^ np.uint64((_GOLDEN * (k + 7)) & 0xFFFFFFFFFFFFFFFF)
            _, w2, _, _ = resampled_collision(m, ox, oy, oz, dx, dy, dz, 0.0, tmax, other)
            total += w2
        if not math.isfinite(t):
            continue
        hit[i] = True
        px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
        x[0, i], x[1, i], x[2, i] = px, py, pz
        d[0, i], d[1, i], d[2, i] = dx, dy, dz
        albedo[0, i], albedo[1, i], albedo[2, i] = albedo_at(m, px, py, pz)
        w_own[i] = w
        w_mean[i] = total / walks
        rng[i] = s


def l_d(scene: Scene, seed: int, frame: int, shadow_rays: int, walks: int) -> np.ndarray:
    """One 1-spp L_d image (3, n) of the forced estimator with ``shadow_rays`` averaged and, for ``walks`` > 1,
    W averaged over that many walks."""
    m = scene.medium()
    kind, vec, rgb = scene.packed_lights()
    env = scene.packed_environment_map()
    cam = scene.camera
    origin, du, dv = cam.image_plane()
    n = cam.width * cam.height
    x, d, albedo = np.zeros((3, n)), np.zeros((3, n)), np.zeros((3, n))
    w_own, w_mean, hit, rng = np.zeros(n), np.zeros(n), np.zeros(n, np.bool_), np.zeros(n, np.uint64)
    _collisions(m, np.ascontiguousarray(cam.eye, dtype=np.float64), origin, du, dv, cam.width, n, frame * n, seed,
                walks, x, d, albedo, w_own, w_mean, hit, rng)
    idx = np.flatnonzero(hit)
    xs, ds = np.ascontiguousarray(x[:, idx]), np.ascontiguousarray(d[:, idx])
    nee = np.zeros((3, idx.size))
    for k in range(shadow_rays):
        states = rng[idx] ^ np.uint64((_GOLDEN * (k + 1)) & 0xFFFFFFFFFFFFFFFF) if k else rng[idx].copy()
        nee += direct_light_batch(m, kind, vec, rgb, env, scene.g, xs, ds, states, False)
    img = np.zeros((3, n))
    img[:, idx] = nee / shadow_rays * albedo[:, idx] * (w_mean[idx] if walks > 1 else w_own[idx])
    return img


def run_scene(name: str, args: argparse.Namespace) -> dict[str, Any]:
    scene = builtin_scene(name).with_overrides(width=args.size, height=args.size)
    ref = np.mean([l_d(scene, 10_000 + f, f, 1, 1) for f in range(args.ref_frames)], axis=0)
    norm = float(np.sqrt(np.mean(ref**2)))
    noise = {}
    for label, shadow, walks in (("plain", 1, 1), ("shadow_averaged", args.shadow_rays, 1),
                                 ("w_averaged", 1, args.walks), ("both_averaged", args.shadow_rays, args.walks)):
        errs = [float(np.sqrt(np.mean((l_d(scene, s, 0, shadow, walks) - ref) ** 2))) / norm
                for s in range(args.repeats)]
        noise[label] = float(np.mean(errs))
    total = noise["plain"] ** 2
    shares = {"shadow": (total - noise["shadow_averaged"] ** 2) / total,
              "w": (noise["shadow_averaged"] ** 2 - noise["both_averaged"] ** 2) / total,
              "placement": noise["both_averaged"] ** 2 / total}
    return {"rel_noise": noise, "variance_share": shares}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["vortex", "shell"])
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--shadow-rays", type=int, default=16)
    ap.add_argument("--walks", type=int, default=64)
    ap.add_argument("--ref-frames", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args()
    info = machine_info()
    results = {}
    print(f"{'scene':8s} {'plain':>7s} {'shadow avg':>10s} {'W avg':>7s} {'both':>7s} | variance share: shadow / W / "
          "placement")
    for name in parse_scenes(args.scenes):
        r = results[name] = run_scene(name, args)
        n, s = r["rel_noise"], r["variance_share"]
        print(f"{name:8s} {n['plain']:7.3f} {n['shadow_averaged']:10.3f} {n['w_averaged']:7.3f} "
              f"{n['both_averaged']:7.3f} | {s['shadow']:.2f} / {s['w']:.2f} / {s['placement']:.2f}", flush=True)
    write_report(args.out, "camera_noise", finish_info(info, results), vars(args) | {"out": str(args.out)},
                 results=results)


if __name__ == "__main__":
    main()
