"""Probe: could the field output the incident light's angular moments and apply HG analytically?

HG's Legendre coefficients are g^l: p_g(mu) = sum_l (2l + 1) / (4 pi) g^l P_l(mu). A field that outputs the
spherical-harmonic moments of the light arriving at x up to band N would give Q(x, d, g) for every g from one
set of outputs (the last bounce's g-dependence exact), at the price of (N + 1)^2 outputs per colour channel
instead of one. Evaluating the photon-map estimate (Eq. 5) with HG truncated at band N is exactly what such a
field would compute from perfect moments (the photons' directions projected on the bands <= N), so the
truncation error below is a floor for that design, with no training involved.

For each scene and g: the camera's first interactions at ``--size`` (1 spp), the K = 64 photons within the
final radius from the map's kernel in g, and Q with the full HG against HG truncated at N. Reported: mean of
the truncated Q over the full one (the bias an image mean shows) and their rel. L2.

Output: a table on stdout and JSON (default ``bench/results/angular_moments.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from common import finish_info, machine_info, parse_scenes, write_report  # noqa: E402
from numpy.polynomial import legendre  # noqa: E402

from photon_fields.models_spec import DEFAULT_PHOTONS, PHASE_WINDOW  # noqa: E402
from photon_fields.runtime.photons.estimate import PhotonMapEstimator  # noqa: E402
from photon_fields.runtime.photons.knn import knn_query  # noqa: E402
from photon_fields.runtime.photons.photon_grid import PhotonIndex  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402
from photon_fields.runtime.wavefront.first_interaction import render_first_interaction  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

HERE = Path(__file__).resolve().parent
BANDS = (2, 4, 6, 8, 12)
GS = (-0.75, -0.6, -0.3, 0.3, 0.6, 0.75)
K = 64  # the cpu preset's targets


def first_interactions(scene: Scene, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Positions and view directions (q, 3) of the camera's first interactions at 1 spp."""
    seen: list[tuple[np.ndarray, np.ndarray]] = []

    class Recorder:
        def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
            seen.append((x.copy(), d.copy()))
            return np.zeros_like(x)

    view = scene.with_overrides(width=size, height=size)
    # delta: every recorded point has weight 1 (forced collisions would need their weights in the mean)
    render_first_interaction(view, Recorder(), spp=1, seed=7, progress=False, direct=False, camera="delta")
    return (np.ascontiguousarray(np.concatenate([s[0] for s in seen], 1).T),
            np.ascontiguousarray(np.concatenate([s[1] for s in seen], 1).T))


def neighbours(index: PhotonIndex, x: np.ndarray, d: np.ndarray, k: int,
               radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Scattering cosines (q, k) and luminance weights Phi w_b / sigma_t (q, k; 0 where no photon) of the
    photons the estimate over ``index`` (the renderer's window index at g) sums."""
    idx, _ = knn_query(index.grid, x, k, radius)  # indices in the index's input order
    at = np.empty_like(index.grid.order)
    at[index.grid.order] = np.arange(at.shape[0])  # input order -> grid order, where the attributes are
    found = np.where(idx >= 0, at[np.where(idx >= 0, idx, 0)], 0)
    cos = -np.einsum("qkc,qc->qk", index.directions[found].astype(np.float64), d)
    return cos, np.where(idx >= 0, index.weights[found].astype(np.float64).mean(2), 0.0)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--photons", type=int, default=DEFAULT_PHOTONS)
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--radius", type=float, default=0.05, help="final search radius (the cpu preset's)")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "angular_moments.json")
    args = ap.parse_args(argv)
    info = machine_info()
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes):
        scene = builtin_scene(name)
        pmap = trace_photons(scene, args.photons, seed=0, progress=False)
        estimator = PhotonMapEstimator(pmap, scene.medium(), k=K, radius=args.radius, g_window=PHASE_WINDOW)
        rows = []
        for g in GS:
            x, d = first_interactions(scene.with_overrides(g=g), args.size)
            cos, w = neighbours(estimator.window_index(g), x, d, K, args.radius)
            full = ((1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos) ** 1.5) * w).sum(1)
            row: dict[str, Any] = {"g": g}
            for n in BANDS:
                trunc = (legendre.legval(cos, [(2 * l + 1) / (4 * np.pi) * g**l for l in range(n + 1)]) * w).sum(1)
                row[f"N{n}"] = {"mean": float(trunc.mean() / full.mean()),
                                "rel_l2": float(np.linalg.norm(trunc - full) / np.linalg.norm(full))}
            rows.append(row)
            print(f"{name} g {g:+.2f}  " + "  ".join(f"N{n}: {row[f'N{n}']['mean']:.3f} / {row[f'N{n}']['rel_l2']:.3f}"
                                                     for n in BANDS), flush=True)
        results[name] = {"rows": rows}
    write_report(args.out, "probe_angular_moments", finish_info(info, {}),
                 {"photons": args.photons, "size": args.size, "radius": args.radius, "k": K, "bands": BANDS},
                 results=results)


if __name__ == "__main__":
    main()
