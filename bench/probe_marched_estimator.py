"""Probe: an unbiased marched camera estimator for the neural renderer (issue 14's lead, not built in the product).

Per camera ray, strata partition the ray (each at most a voxel and at most half a majorant optical depth long, a
partition fixed by the medium) with one jitter per ray; at each stratum's jittered point t_k the weight is
``w_k = len_k sigma_t(t_k) T^(t_k)``, unbiased for the integral of T sigma_t f when T^(t_k) is an unbiased
transmittance estimate independent of the jitter. T^ is residual ratio tracking (Novak et al. 2014):
``exp(-integral of sigma_c) * prod (1 - (sigma_t - sigma_c) / mu)`` over Poisson events at the plain majorant mu,
with the control sigma_c each stratum's midpoint extinction (piecewise constant: its integral is exact). Then

    L_d = sum_k w_k a_k D_lv(x_k) + W a_J (NEE - D_lv)(x_J),    L_i = W a_J Q(x_J, d, g),    J ~ w_k / W

with D_lv the ray marcher's light volume (delta lights; filled completely here) as a control variate, NEE
``--shadow-rays`` boosted shadow rays at the pick, Q the photon field there. Against the forced camera estimator's
1-spp frame (rel. L2 of L, L_d, L_i against the path tracer at ``--ref-spp``, and the means), per scene. The probe
walks with a global majorant thinned to the local one (so its run time says nothing about a product kernel's),
stops a ray once exp(-tau_c) |R| < 1e-4 (a product would use roulette) and picks by the weight's value (negative
weights, R < 0, are rare; a product would pick by |w| and keep the sign). docs/rendering.md has the figures.

Output: a table on stdout and JSON (default ``bench/results/marched_estimator.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_render import scenes_with_fields  # noqa: E402
from common import add_reference_args, finish_info, machine_info, write_report  # noqa: E402
from numba import njit, prange  # noqa: E402

from photon_fields.runtime.denoise.reprojection import DU, DV, EYE, ORIGIN, pack_view  # noqa: E402
from photon_fields.runtime.eval.metrics import relative_l2  # noqa: E402
from photon_fields.runtime.renderers.neural import render_neural  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.ray_marcher import light_volume_settings, scene_light_volume  # noqa: E402
from photon_fields.runtime.transport.cell_grid import stencil  # noqa: E402
from photon_fields.runtime.transport.direct_light import direct_light_batch  # noqa: E402
from photon_fields.runtime.transport.emitters import delta_light_direction  # noqa: E402
from photon_fields.runtime.transport.light_volume import WANTED, fill_wanted, light_transmittance  # noqa: E402
from photon_fields.runtime.transport.medium import albedo_batch, extinction_albedo_at  # noqa: E402
from photon_fields.runtime.transport.phase import hg_eval  # noqa: E402
from photon_fields.runtime.transport.rng import next_float  # noqa: E402
from photon_fields.runtime.transport.tracking import majorant_at  # noqa: E402
from photon_fields.runtime.wavefront.rays import camera_ray, clip_to_box  # noqa: E402

HERE = Path(__file__).resolve().parent
STRATA_PER_DEPTH = 2.0  # strata per unit of majorant optical depth (and at most one voxel long)


@njit(cache=True, inline="always")
def _lv_direct(kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, lv: np.ndarray, grid: Any, x: float,
               y: float, z: float, dx: float, dy: float, dz: float) -> tuple[float, float, float]:
    """D_lv: the delta lights' direct light at x from the light volume (phase, fall-off, colour)."""
    ci, cj, ck, fx, fy, fz = stencil(grid, x, y, z)
    r = gg = b = 0.0
    for k in range(kind.shape[0]):
        lx, ly, lz, scale, _ = delta_light_direction(kind[k], vec[k], x, y, z)
        if scale > 0.0:
            c = hg_eval(g, dx * lx + dy * ly + dz * lz) * scale * light_transmittance(lv, k, ci, cj, ck, fx, fy, fz)
            r += c * rgb[k, 0]
            gg += c * rgb[k, 1]
            b += c * rgb[k, 2]
    return r, gg, b


@njit(cache=True, parallel=True)
def _frame(m: Any, view: np.ndarray, width: int, n_pixels: int, seed: int, voxel: float, mu_g: float,
           kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, lv: np.ndarray,
           grid: Any) -> tuple[np.ndarray, ...]:
    """Per pixel: M (3), the pick (x, d), W, found, its random state, residual events and strata with medium."""
    M = np.zeros((3, n_pixels))
    xs = np.zeros((3, n_pixels))
    ds = np.zeros((3, n_pixels))
    W = np.zeros(n_pixels)
    found = np.zeros(n_pixels, np.bool_)
    states = np.zeros(n_pixels, np.uint64)
    counts = np.zeros((2, n_pixels))
    origin, du, dv = view[ORIGIN:ORIGIN + 3], view[DU:DU + 3], view[DV:DV + 3]
    ex, ey, ez = view[EYE], view[EYE + 1], view[EYE + 2]
    for i in prange(n_pixels):
        dx, dy, dz, p, s = camera_ray(origin, du, dv, width, n_pixels, i, np.uint64(seed))
        hit, ox, oy, oz, tmax = clip_to_box(m, ex, ey, ez, dx, dy, dz)
        if not hit:
            continue
        s, u = next_float(s)
        s, v = next_float(s)
        te = -math.log(1.0 - v) / mu_g  # next event of the global process, thinned to the local majorant
        R = 1.0
        tau_c = 0.0
        wsum = 0.0
        kept = -1.0
        start = 0.0
        while start < tmax:
            mu_s = majorant_at(m, ox + start * dx, oy + start * dy, oz + start * dz)
            length = voxel if mu_s * voxel * STRATA_PER_DEPTH <= 1.0 else 1.0 / (STRATA_PER_DEPTH * mu_s)
            mid = start + 0.5 * length
            sc, _, _, _ = extinction_albedo_at(m, ox + mid * dx, oy + mid * dy, oz + mid * dz)
            ts = start + u * length
            end = min(start + length, tmax)
            for part in range(2):  # events before the stratum's point, the point, the events after it
                lim = ts if part == 0 else end
                while te < lim:
                    x, y, z = ox + te * dx, oy + te * dy, oz + te * dz
                    loc = majorant_at(m, x, y, z)
                    s, a = next_float(s)
                    if a * mu_g < loc:
                        counts[0, p] += 1.0
                        sig, _, _, _ = extinction_albedo_at(m, x, y, z)
                        R *= 1.0 - (sig - sc) / loc
                    s, a = next_float(s)
                    te += -math.log(1.0 - a) / mu_g
                if part == 0 and ts < tmax:
                    x, y, z = ox + ts * dx, oy + ts * dy, oz + ts * dz
                    sig, a0, a1, a2 = extinction_albedo_at(m, x, y, z)
                    if sig > 0.0:
                        counts[1, p] += 1.0
                        w = length * sig * math.exp(-(tau_c + sc * (ts - start))) * R
                        l0, l1, l2 = _lv_direct(kind, vec, rgb, g, lv, grid, x, y, z, dx, dy, dz)
                        M[0, p] += w * a0 * l0
                        M[1, p] += w * a1 * l1
                        M[2, p] += w * a2 * l2
                        wsum += w
                        s, a = next_float(s)
                        if w != 0.0 and a * wsum < w:
                            kept = ts
            tau_c += sc * (end - start)
            start += length
            if math.exp(-tau_c) * abs(R) < 1e-4:
                break
        if kept >= 0.0:
            found[p] = True
            xs[0, p], xs[1, p], xs[2, p] = ox + kept * dx, oy + kept * dy, oz + kept * dz
            ds[0, p], ds[1, p], ds[2, p] = dx, dy, dz
            W[p] = wsum
            states[p] = s
    return M, xs, ds, W, found, states, counts


@njit(cache=True, parallel=True)
def _lv_direct_batch(kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, lv: np.ndarray, grid: Any,
                     x: np.ndarray, d: np.ndarray) -> np.ndarray:
    out = np.zeros((3, x.shape[1]))
    for i in prange(x.shape[1]):
        out[0, i], out[1, i], out[2, i] = _lv_direct(kind, vec, rgb, g, lv, grid, x[0, i], x[1, i], x[2, i],
                                                     d[0, i], d[1, i], d[2, i])
    return out


def marched_frame(scene: Any, est: Any, lv: Any, seed: int, shadow_rays: int) -> tuple[np.ndarray, ...]:
    """(L_d, L_i) images of one 1-spp frame of the probe's estimator, and its (events, strata) per ray."""
    m = scene.medium()
    kind, vec, rgb = scene.packed_lights()
    cam = scene.camera
    n = cam.width * cam.height
    M, xs, ds, W, found, states, counts = _frame(m, pack_view(cam), cam.width, n, seed,
                                                 float(scene.volume.voxel_size), float(m.majorant.max()), kind, vec,
                                                 rgb, scene.g, lv.values, lv.grid)
    idx = np.flatnonzero(found)
    x, d = np.ascontiguousarray(xs[:, idx]), np.ascontiguousarray(ds[:, idx])
    thr = albedo_batch(m, x) * W[idx]
    env = scene.packed_environment_map()
    nee = sum(direct_light_batch(m, kind, vec, rgb, env, scene.g, x, d, states[idx] + np.uint64(7919 * r), False,
                                 True) for r in range(shadow_rays)) / shadow_rays
    ld = M.copy()
    ld[:, idx] += (nee - _lv_direct_batch(kind, vec, rgb, scene.g, lv.values, lv.grid, x, d)) * thr
    li = np.zeros((3, n))
    li[:, idx] = est(x, d, scene.g) * thr

    def image(a: np.ndarray) -> np.ndarray:
        return a.reshape(3, cam.height, cam.width).transpose(1, 2, 0)

    per_ray = counts[:, counts[1] > 0].mean(axis=1) if (counts[1] > 0).any() else np.zeros(2)
    return image(ld), image(li), per_ray


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_reference_args(ap)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--shadow-rays", type=int, default=2)
    ap.add_argument("--bundle", action="append", default=[], metavar="SCENE=PATH")
    ap.add_argument("--work", type=Path, default=HERE / "results" / "marched_estimator")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "marched_estimator.json")
    args = ap.parse_args(argv)
    info = machine_info()
    results: dict[str, Any] = {}
    for name, scene, est in scenes_with_fields(args):
        ref_path = args.work / f"ref_{name}_{args.size}_{args.ref_spp}.npz"
        if not ref_path.exists():
            r = render_path_traced(scene, spp=args.ref_spp, seed=10_000, progress=False).layers
            ref_path.parent.mkdir(parents=True, exist_ok=True)
            np.savez(ref_path, **{k: r[k] for k in ("L", "L_e", "L_d", "L_i")})
        ref = np.load(ref_path)
        lv = scene_light_volume(scene, *light_volume_settings(scene))
        lv.values[lv.values < 0] = WANTED  # every cell: the probe reads them anywhere
        lv.wanted[:] = 1
        fill_wanted(scene.medium(), *scene.packed_lights()[:2], lv)
        rows: dict[str, list[list[float]]] = {"neural forced": [], "marched residual": []}
        for seed in range(args.seeds):
            nl = render_neural(scene, est, spp=1, seed=seed, progress=False, camera="forced").layers
            ld, li, per_ray = marched_frame(scene, est, lv, seed, args.shadow_rays)
            for key, (d_, i_) in (("neural forced", (nl["L_d"], nl["L_i"])), ("marched residual", (ld, li))):
                total = d_ + i_ + ref["L_e"]
                rows[key].append([relative_l2(total, ref["L"]), relative_l2(d_, ref["L_d"]),
                                  relative_l2(i_, ref["L_i"]), float(d_.mean() / ref["L_d"].mean()),
                                  float(i_.mean() / ref["L_i"].mean())])
        summary = {k: dict(zip(("L", "L_d", "L_i", "L_d_mean", "L_i_mean"), np.mean(v, axis=0).tolist(),
                               strict=True)) for k, v in rows.items()}
        summary["marched residual"].update({"events_per_ray": float(per_ray[0]), "strata_per_ray": float(per_ray[1])})
        results[name] = summary
        for k, v in summary.items():
            print(f"{name:8s} {k:17s} L {v['L']:.3f}  L_d {v['L_d']:.3f}  L_i {v['L_i']:.3f}  means "
                  f"{v['L_d_mean']:.4f} / {v['L_i_mean']:.4f}", flush=True)
    write_report(args.out, "marched_estimator", finish_info(info, {}),
                 {"size": args.size, "seeds": args.seeds, "ref_spp": args.ref_spp, "shadow_rays": args.shadow_rays},
                 results=results)


if __name__ == "__main__":
    main()
