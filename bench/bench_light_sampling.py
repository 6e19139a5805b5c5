"""NEE with one light per sample against a shadow ray to every light: frame time, noise and efficiency.

For each scene (default: the embedded scenes with more than one light), the neural renderer at ``--size``
(default 512x512), 1 spp, with ``light_sampling="all"`` and ``"one"`` (runtime.transport.direct_light), in one run:

- frame time and its NEE stage (``estimate_direct``): the median of ``--frames`` frames per setting, the settings
  alternating frame by frame (the same seeds for both), after a warm-up of each;
- noise: rel. L2 of each 1-spp frame's L and L_d against the renderer's own ``--ref-spp`` image ("all"; both
  settings estimate the same image, tests/runtime/transport/test_light_sampling.py), mean over the frames;
- efficiency 1 / (rel. L2^2 x ms) of L, and its ratio one / all (> 1: "one" gives less noise per millisecond).

Bundles: ``--bundle SCENE=PATH`` or bench_render.py's (trained on first use). Output: a table on stdout and JSON
(default ``bench/results/light_sampling.json``), with the CPU model and the other processes' load.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_render import bundle_for  # noqa: E402
from common import Contention, finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.renderers.neural import render_neural  # noqa: E402
from photon_fields.runtime.scene.scene import builtin_scene  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "light_sampling.json"
SETTINGS = ("all", "one")


def rel_l2(img: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((img - ref) ** 2) / max(np.mean(ref**2), 1e-30)))


def measure(name: str, size: int, frames: int, ref_spp: int, bundle: Path) -> dict[str, Any]:
    scene = builtin_scene(name).with_overrides(width=size, height=size)
    est = PhotonField.load(bundle).estimator()

    def frame(setting: str, seed: int, spp: int = 1) -> Any:
        return render_neural(scene, est, spp=spp, seed=seed, progress=False, light_sampling=setting,
                             final_gather_after=None, camera="forced")  # one estimator for both settings

    ref = frame("all", 10_000, ref_spp).layers
    for s in SETTINGS:
        frame(s, 0)
    rows: dict[str, dict[str, list[float]]] = {s: {"ms": [], "nee_ms": [], "L": [], "L_d": []} for s in SETTINGS}
    with Contention() as busy:
        for seed in range(1, frames + 1):
            for s in SETTINGS if seed % 2 else SETTINGS[::-1]:
                t0 = time.perf_counter()
                r = frame(s, seed)
                rows[s]["ms"].append((time.perf_counter() - t0) * 1e3)
                rows[s]["nee_ms"].append(r.timings_ms.get("estimate_direct", 0.0))
                for layer in ("L", "L_d"):
                    rows[s][layer].append(rel_l2(r.layers[layer], ref[layer]))
    out: dict[str, Any] = {"lights": len(scene.lights), "size": size, "frames": frames, "ref_spp": ref_spp,
                           "other_cores": busy.other_cores}
    for s in SETTINGS:
        ms, err = float(np.median(rows[s]["ms"])), float(np.mean(rows[s]["L"]))
        out[s] = {"ms": ms, "nee_ms": float(np.median(rows[s]["nee_ms"])), "rel_l2_L": err,
                  "rel_l2_L_d": float(np.mean(rows[s]["L_d"])), "efficiency": 1.0 / (err**2 * ms)}
    out["efficiency_one_over_all"] = out["one"]["efficiency"] / out["all"]["efficiency"]
    out["time_one_over_all"] = out["one"]["ms"] / out["all"]["ms"]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=None, help="builtin scenes (default: those with several lights)")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--ref-spp", type=int, default=64)
    ap.add_argument("--bundle", action="append", default=[], metavar="SCENE=PATH")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    args = ap.parse_args()
    given = dict(b.split("=", 1) for b in args.bundle)
    names = parse_scenes(args.scenes)
    if not args.scenes:
        names = [n for n in names if len(builtin_scene(n).lights) > 1]
    info = machine_info()
    print(f"{info['cpu'].get('model', '?')}, {info['usable_cores']} cores; {args.size}x{args.size}, 1 spp, "
          f"{args.frames} frames per setting, noise against {args.ref_spp} spp")
    results = {}
    for name in names:
        r = results[name] = measure(name, args.size, args.frames, args.ref_spp,
                                    bundle_for(name, builtin_scene(name), given))
        a, o = r["all"], r["one"]
        print(f"{name:8s} ({r['lights']} lights) all: {a['ms']:6.1f} ms (NEE {a['nee_ms']:5.1f}) rel. L2 L "
              f"{a['rel_l2_L']:.3f} L_d {a['rel_l2_L_d']:.3f} | one: {o['ms']:6.1f} ms (NEE {o['nee_ms']:5.1f}) "
              f"L {o['rel_l2_L']:.3f} L_d {o['rel_l2_L_d']:.3f} | time {r['time_one_over_all']:.2f}x, efficiency "
              f"{r['efficiency_one_over_all']:.2f}x (other cores {r['other_cores']})")
    write_report(Path(args.out), "bench_light_sampling", finish_info(info, results), vars(args), results=results)


if __name__ == "__main__":
    main()
