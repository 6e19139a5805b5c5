"""Final gather: what one real bounce before the field buys in the converged image, and what it costs per second.

The neural renderer's converged L carries the field's bias (issue 13); ``final_gather`` (runtime.wavefront.
final_gather) takes one real bounce before asking the field, so the field's error reaches the image attenuated
and blurred, at more time and noise per sample. Per scene at ``--size`` (default 128x128), against the mean of
two path-traced L at ``--ref-spp`` each (default 2048; cached in ``--work``; half their difference is the
reference's own noise), for the neural renderer (forced camera estimator) without and with the final gather at
each of ``--spps``: two renders with different seeds, their best time, their mean rel. L2, the noise of one
render (the rel. L2 between the two / sqrt 2) and the error left without either image's noise
(sqrt(e^2 - noise^2 - ref_noise^2): what more samples would not remove). Then, per gathered point, the plain
renderer's error at the same time (log-log interpolation on its curve): below 1, the gather is the better image
for that time. ``--photon-map`` adds the photon-map renderer (the field's training targets) the same two ways.
``--default-spps`` (default 512 2048) adds the neural renderer as ``pfn-render`` runs it by default (plain
samples, gathered from the ``registry.DEFAULT_GATHER_AFTER``-th on) at those counts: issue 13's converged-L goal
is judged on it.

Bundles: ``--bundle SCENE=PATH`` (the run folder's ``map.npz`` beside it for ``--photon-map``), else those of
``bench_render.py``. Output: a table, JSON (default ``bench/results/final_gather.json``) with the machine record,
and a plot of error against time per scene beside it.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
from bench_render import bundle_for  # noqa: E402
from common import finish_info, machine_info, parse_scenes, write_report  # noqa: E402

from photon_fields.runtime.eval.metrics import relative_l2  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.renderers.neural import render_neural  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.renderers.registry import DEFAULT_GATHER_AFTER  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, builtin_scene  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE / "results" / "final_gather.json"
DEFAULT_WORK = HERE / "results" / "final_gather"
#: The plot's noise-free error starts at this many spp (from two 1-spp images the noise estimate is too rough).
MIN_BIAS_SPP = 16


def reference_halves(scene: Scene, spp: int, work: Path) -> tuple[np.ndarray, float]:
    """The mean of two path-traced L at ``spp`` (cached) and that mean's own noise (rel. L2 / 2 of the halves)."""
    halves = []
    for seed in (4321, 4322):
        cam = scene.camera
        path = work / f"ref_{scene.name}_{cam.width}x{cam.height}_{spp}_{scene.g:+.3f}_{seed}.npy"
        if not path.exists():
            t0 = time.perf_counter()
            path.parent.mkdir(parents=True, exist_ok=True)
            np.save(path, render_path_traced(scene, spp=spp, seed=seed, progress=False).layers["L"])
            print(f"  reference {scene.name} {spp} spp, seed {seed}: {time.perf_counter() - t0:.0f} s", flush=True)
        halves.append(np.load(path))
    return 0.5 * (halves[0] + halves[1]), relative_l2(halves[0], halves[1]) / 2.0


def point(render: Callable[[int], np.ndarray], ref: np.ndarray, ref_noise: float) -> dict[str, float]:
    """Two renders (seeds 7, 8): best time, mean error, one render's noise, the error left without noise."""
    times, images = [], []
    for seed in (7, 8):
        t0 = time.perf_counter()
        images.append(render(seed))
        times.append(time.perf_counter() - t0)
    errors = [relative_l2(img, ref) for img in images]
    noise = relative_l2(images[0], images[1]) / np.sqrt(2.0)
    e = float(np.mean(errors))
    return {"ms": min(times) * 1e3, "rel_l2": e, "noise_rel_l2": float(noise),
            "bias_rel_l2": float(np.sqrt(max(0.0, e**2 - noise**2 - ref_noise**2))),
            "mean_ratio": float(np.mean([img.mean() for img in images]) / ref.mean())}


def error_at_time(curve: list[dict[str, float]], ms: float) -> float | None:
    """``curve``'s rel. L2 at ``ms``, log-log interpolated; None outside its time range."""
    t = np.log([c["ms"] for c in curve])
    e = np.log([c["rel_l2"] for c in curve])
    x = np.log(ms)
    if not t[0] <= x <= t[-1]:
        return None
    return float(np.exp(np.interp(x, t, e)))


def plot(results: dict[str, Any], path: Path) -> None:
    """Error against time, log-log, one panel per scene; the noise-free error dashed (from MIN_BIAS_SPP on)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.8), dpi=100, squeeze=False)
    for ax, (name, r) in zip(axes[0], results.items(), strict=True):
        for method, rows in r["curves"].items():
            line, = ax.plot([p["ms"] for p in rows], [p["rel_l2"] for p in rows], "o-", ms=3, label=method)
            sure = [p for p in rows if p["spp"] >= MIN_BIAS_SPP]  # below, two images' noise estimate is too rough
            ax.plot([p["ms"] for p in sure], [max(p["bias_rel_l2"], 1e-3) for p in sure], "--",
                    color=line.get_color(), lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("ms per image")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("rel. L2 (dashed: without noise)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="*", help="builtin scenes (default: all)")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=2048, help="samples of each of the reference's two halves")
    ap.add_argument("--spps", type=int, nargs="*", default=[1, 4, 16, 64, 256])
    ap.add_argument("--photon-map", action="store_true", help="also the photon-map renderer, with and without")
    ap.add_argument("--default-spps", type=int, nargs="*", default=[512, 2048],
                    help="the neural renderer's default (gathered from DEFAULT_GATHER_AFTER on) at these spp")
    ap.add_argument("--bundle", action="append", default=[], metavar="SCENE=PATH")
    ap.add_argument("--work", type=Path, default=DEFAULT_WORK)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    given = dict(b.split("=", 1) for b in args.bundle)
    info = machine_info()
    results: dict[str, Any] = {}
    for name in parse_scenes(args.scenes):
        base = builtin_scene(name)
        scene = base.with_overrides(width=args.size, height=args.size)
        bundle = bundle_for(name, base, given)
        est = PhotonField.load(bundle, expected_fingerprint=base.fingerprint()).estimator()
        ref, ref_noise = reference_halves(scene, args.ref_spp, args.work)
        # (spp, seed, final_gather_after) -> L
        renderers: dict[str, Callable[[int, int, int | None], np.ndarray]] = {
            "neural": lambda spp, seed, after, scene=scene, est=est: render_neural(
                scene, est, spp=spp, seed=seed, progress=False, final_gather_after=after,
                camera="forced").layers["L"]}
        if args.photon_map:
            from photon_fields.runtime.photons.photon_map import PhotonMap
            from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped

            pmap = PhotonMap.load(Path(bundle).parent / "map.npz")
            renderers["photon map"] = lambda spp, seed, after, scene=scene, pmap=pmap: render_photon_mapped(
                scene, pmap, k=64, spp=spp, seed=seed, progress=False, final_gather_after=after,
                camera="forced").layers["L"]
        warm = scene.with_overrides(width=16, height=16)
        render_neural(warm, est, spp=1, progress=False, final_gather_after=0)
        curves: dict[str, list[dict[str, Any]]] = {}
        for rname, render in renderers.items():
            for after in (None, 0):
                method = f"{rname}{'' if after is None else ' + final gather'}"
                curves[method] = [{"spp": s, **point(lambda seed, s=s, a=after, r=render: r(s, seed, a), ref,
                                                       ref_noise)}
                                  for s in args.spps]
            for row in curves[f"{rname} + final gather"]:
                plain = error_at_time(curves[rname], row["ms"])
                row["plain_error_at_equal_time"] = plain
                row["error_over_plain_at_equal_time"] = row["rel_l2"] / plain if plain else None
        if args.default_spps:
            curves[f"neural, default (gather from {DEFAULT_GATHER_AFTER})"] = [
                {"spp": s, **point(lambda seed, s=s, r=renderers["neural"]: r(s, seed, DEFAULT_GATHER_AFTER), ref,
                                   ref_noise)} for s in args.default_spps]
        results[name] = {"bundle": str(bundle), "g": scene.g, "reference": {"spp": 2 * args.ref_spp,
                                                                          "noise_rel_l2": ref_noise},
                         "curves": curves}
        print(f"\n{name} ({args.size}x{args.size}, g = {scene.g:+.2f}; reference: 2 x {args.ref_spp} spp, its noise "
              f"{ref_noise:.4f})")
        print(f"  {'method':28s} {'spp':>4s} {'ms':>8s} {'rel. L2':>8s} {'noise':>7s} {'no noise':>8s} {'mean':>6s} "
              f"{'vs plain, equal time':>20s}")
        for method, rows in curves.items():
            for r in rows:
                ratio = r.get("error_over_plain_at_equal_time")
                print(f"  {method:28s} {r['spp']:4d} {r['ms']:8.1f} {r['rel_l2']:8.4f} {r['noise_rel_l2']:7.4f} "
                      f"{r['bias_rel_l2']:8.4f} {r['mean_ratio']:6.3f} {'' if ratio is None else f'{ratio:.3f}':>20s}",
                      flush=True)
    info = finish_info(info, {})
    write_report(args.out, "final_gather", info, {"size": args.size, "ref_spp": args.ref_spp, "spps": args.spps,
                                                  "default_spps": args.default_spps, "photon_map": args.photon_map,
                                                  "default_gather_after": DEFAULT_GATHER_AFTER}, results=results)
    plot(results, args.out.with_suffix(".png"))
    print(f"wrote {args.out} and {args.out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
