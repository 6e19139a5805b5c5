"""Training targets: seconds per batch of photon-map estimates against how many are computed at once.

A fit draws a fresh batch every step and estimates its targets from the search structure of each sample's
phase or window (:mod:`photon_fields.train.fit.targets`). With 16 windows a batch of 4096 gives each structure
~256 queries: spread over the whole volume, each finds its photons out of cache. The sampler therefore
computes ``per_set`` targets per structure at once and serves the batches from that pool (``TARGETS_PER_SET``).
This bench times the estimate (draw, search, support fraction) per 4096 samples for each ``--per-set``, as a
ratio against one batch's share (the first value, default 256), on one traced map per scene and ``g_sampling``
(the default map and the ``cpu`` preset's window sampling; ``--discrete`` adds the five-phase map).
``--samplings support visible`` times the same at the sampler's default ``per_set`` for each training-position
mode (:data:`photon_fields.train.fit.targets.SAMPLING_MODES`) as a ratio against the first, the modes
alternating repeat by repeat so that a changing load falls on all of them. ``--fits STEPS`` fits the default
preset for STEPS steps on each scene's map with the targets computed beside the training (the product's way) and
by the training loop itself, alternated ``--repeats`` times: wall seconds, the ratio, and whether the two fits'
validation losses are the same (they must be: the same batches).

Output: a table on stdout and JSON (default ``bench/results/targets.json``) with the machine record.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from common import Contention, finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.models_spec import DEFAULT_MAP_PHASES, DEFAULT_PHASES  # noqa: E402
from photon_fields.runtime.scene.scene import builtin_scene  # noqa: E402
from photon_fields.train.fit.presets import PRESETS  # noqa: E402
from photon_fields.train.fit.targets import TARGETS_PER_SET, TargetSampler  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "targets.json"
BATCH = 4096


def time_per_batch(sampler: TargetSampler, per_set: int, repeats: int, radius: float,
                   mode: str | None = None) -> float:
    """Seconds per BATCH samples when ``per_set`` targets per search structure are estimated at once (median of
    ``repeats`` pools), positions drawn by ``mode`` (default: the sampler's)."""
    n = per_set * sampler.sets
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        x, d, g, ph = sampler.draw(sampler.rng, n, mode or sampler.sampling)
        sampler.estimate(x, d, g, ph, radius)
        times.append((time.perf_counter() - t0) / n * BATCH)
    return float(np.median(times))


def compare_samplings(sampler: TargetSampler, modes: list[str], repeats: int, radius: float) -> dict[str, float]:
    """Seconds per BATCH samples (draw and estimate) for each position mode at TARGETS_PER_SET, the modes
    alternating repeat by repeat (median per mode)."""
    times: dict[str, list[float]] = {m: [] for m in modes}
    for m in modes:
        time_per_batch(sampler, 64, 1, radius, m)  # compile
    for _ in range(repeats):
        for m in modes:
            times[m].append(time_per_batch(sampler, TARGETS_PER_SET, 1, radius, m))
    return {m: float(np.median(t)) for m, t in times.items()}


class _Alone(TargetSampler):
    """The sampler as the loop used it before the worker: every pool computed in the training's thread."""

    def __init__(self, *args: Any, background: bool = False, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)


def compare_fits(scene: Any, pmap: Any, steps: int, repeats: int) -> dict[str, Any]:
    """Fit walls (s) of the default preset with the targets beside the training and alone, alternated."""
    import tempfile

    from photon_fields.train.fit import loop
    from photon_fields.train.fit.settings import FitSettings

    walls: dict[str, list[float]] = {"beside": [], "alone": []}
    losses: dict[str, set[float]] = {"beside": set(), "alone": set()}
    try:
        for r in range(repeats):
            for mode in ("beside", "alone") if r % 2 == 0 else ("alone", "beside"):
                loop.TargetSampler = TargetSampler if mode == "beside" else _Alone
                with tempfile.TemporaryDirectory() as tmp:
                    t0 = time.perf_counter()
                    res = loop.fit(scene, pmap, tmp, FitSettings.from_preset("cpu", steps=steps), progress=False)
                    walls[mode].append(time.perf_counter() - t0)
                losses[mode].add(res.log["validation"][-1]["val_loss"])
    finally:
        loop.TargetSampler = TargetSampler
    beside, alone = float(np.median(walls["beside"])), float(np.median(walls["alone"]))
    return {"steps": steps, "beside_s": beside, "alone_s": alone, "ratio": beside / alone,
            "same_fit": losses["beside"] == losses["alone"] and len(losses["alone"]) == 1, "walls": walls}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", default=["vortex", "shell"], help="builtin scenes")
    ap.add_argument("--photons", type=int, default=5_000_000)
    ap.add_argument("--per-set", type=int, nargs="*", default=[256, 512, 1024, 2048, 4096],
                    help="targets per phase (or per set of the binned index's pool) computed at once; the first is "
                         "the baseline")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--discrete", action="store_true", help="also the five-phase map with discrete g (cpu-phases)")
    ap.add_argument("--samplings", nargs="*", default=[],
                    help="training-position modes to compare at the default per_set (the first is the baseline)")
    ap.add_argument("--fits", type=int, default=0, metavar="STEPS",
                    help="also fit the default preset for STEPS steps with the targets beside the training and alone")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    info = machine_info()
    kinds = [("window", DEFAULT_MAP_PHASES, "cpu")] + ([("discrete", DEFAULT_PHASES, "cpu-phases")]
                                                       if args.discrete else [])
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes):
        scene = builtin_scene(name)
        for g_sampling, phases, preset_name in kinds:
            preset = PRESETS[preset_name]
            pmap = trace_photons(scene, args.photons, phases=phases, seed=args.seed, progress=False)
            sampler = TargetSampler(pmap, scene.medium(), k=preset.k, psi=1e-3, seed=args.seed,
                                    sampling=preset.sampling, g_sampling=g_sampling)
            time_per_batch(sampler, 64, 1, 0.05)  # compile
            with Contention() as busy:
                rows = {p: time_per_batch(sampler, p, args.repeats, 0.05) for p in args.per_set}
            base = rows[args.per_set[0]]
            key = f"{name}/{g_sampling}"
            results[key] = {"structures": len(sampler.indices), "k": preset.k, "index_build_s": sampler.build_seconds,
                            "ms_per_batch": {str(p): 1e3 * t for p, t in rows.items()},
                            "speedup": {str(p): base / t for p, t in rows.items()}, "other_cores": busy.other_cores}
            print(f"{key}: {len(sampler.indices)} search structures, K {preset.k}, built in "
                  f"{sampler.build_seconds:.1f} s; ms per {BATCH} targets: "
                  + ", ".join(f"{p} at once {1e3 * t:.1f} (x{base / t:.2f})" for p, t in rows.items()), flush=True)
            if args.samplings:
                with Contention() as busy:
                    modes = compare_samplings(sampler, args.samplings, args.repeats, 0.05)
                first = modes[args.samplings[0]]
                results[key]["samplings"] = {m: {"ms_per_batch": 1e3 * t, "over_first": t / first,
                                                 "other_cores": busy.other_cores} for m, t in modes.items()}
                print(f"{key}: ms per {BATCH} samples drawn and estimated by position mode: "
                      + ", ".join(f"{m} {1e3 * t:.1f} (x{t / first:.2f})" for m, t in modes.items()), flush=True)
            if args.fits and g_sampling == "window":
                with Contention() as busy:
                    fits = compare_fits(scene, pmap, args.fits, args.repeats)
                results[key]["fits"] = {**fits, "other_cores": busy.other_cores}
                print(f"{key}: fit of {args.fits} steps {fits['beside_s']:.1f} s with the targets beside the training, "
                      f"{fits['alone_s']:.1f} s alone (x{fits['ratio']:.2f}; the same fit: {fits['same_fit']})",
                      flush=True)
    write_report(args.out, "targets", finish_info(info, results),
                 {k: v for k, v in vars(args).items() if k != "out"}, results=results)


if __name__ == "__main__":
    main()
