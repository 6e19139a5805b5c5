"""What an environment map costs: reading it, building its sampling tables, rotating it, and path tracing under it
compared with the constant environment of the same mean radiance.

Usage::

    .venv/bin/python bench/bench_envmap.py                  # 2048x1024 map, vortex at 128x128, 4 spp
    .venv/bin/python bench/bench_envmap.py --size 256 --map-height 256

Prints a table and writes ``bench/results/envmap.json`` (with the machine facts of :mod:`common`). Figures are
medians of ``--repeats`` runs after a warm-up (numba compiled), on a quiet machine only comparable within a run.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import finish_info, machine_info, median_ms  # noqa: E402

from photon_fields.runtime.io.hdr_images import read_environment_image, write_radiance_hdr  # noqa: E402
from photon_fields.runtime.io.images import write_exr  # noqa: E402
from photon_fields.runtime.renderers.path_tracer import render_path_traced  # noqa: E402
from photon_fields.runtime.scene.lights import EnvironmentLight, EnvironmentMap  # noqa: E402
from photon_fields.runtime.scene.scene import builtin_scene  # noqa: E402
from photon_fields.runtime.transport.environment_map import build_env_map  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "envmap.json"


def sky(h: int) -> np.ndarray:
    """A sky with a small bright sun (what environment maps look like: most power in few pixels)."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(2 * h) + 0.5) / (2 * h)
    vv, uu = np.meshgrid(v, u, indexing="ij")
    sun = 2000.0 * (((vv - 0.3) ** 2 + (uu - 0.6) ** 2) < (2.0 / h) ** 2)
    base = np.where(vv < 0.5, 1.2 - vv, 0.15)
    return (base[..., None] * [0.5, 0.7, 1.0] + sun[..., None] * [1.0, 0.9, 0.8]).astype(np.float32)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--map-height", type=int, default=1024)
    p.add_argument("--size", type=int, default=128, help="image side of the path-traced renders")
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args(argv)
    info = machine_info()
    img = sky(args.map_height)
    res: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        hdr, exr = Path(tmp) / "sky.hdr", Path(tmp) / "sky.exr"
        write_radiance_hdr(hdr, img)
        write_exr(exr, {"L": img})
        res["read_hdr"] = {"ms": median_ms(lambda _: read_environment_image(hdr), args.repeats)}
        res["read_exr"] = {"ms": median_ms(lambda _: read_environment_image(exr), args.repeats)}
    # A fresh radiance each call (the cache is keyed by the radiance's hash): the cost of a new map's tables.
    res["build_tables"] = {"ms": median_ms(lambda s: build_env_map(img * (1.0 + s)), args.repeats)}
    base = builtin_scene("vortex").with_overrides(width=args.size, height=args.size)
    light = EnvironmentMap("sky", image=img)
    with_map = base.__class__(base.volume, base.tf, (light,), base.camera, base.g, "vortex-map")
    with_map.packed_environment_map()

    def rotate(s: int) -> None:
        scene = base.__class__(base.volume, base.tf, (light.rotated(10.0 * s),), base.camera, base.g, "vortex-map")
        scene.packed_environment_map()

    res["rotate_scene"] = {"ms": median_ms(rotate, args.repeats)}
    mean = float(np.mean(with_map.packed_environment_map().integral) / (4 * math.pi))
    constant = base.__class__(base.volume, base.tf, (EnvironmentLight([mean] * 3),), base.camera, base.g, "vortex-env")
    for name, scene in (("pt_constant_environment", constant), ("pt_environment_map", with_map)):
        ms = median_ms(lambda s, sc=scene: render_path_traced(sc, spp=args.spp, seed=s, progress=False),
                       args.repeats)
        res[name] = {"ms": ms, "samples_per_s": args.size**2 * args.spp / (ms / 1e3)}
    for name, r in res.items():
        extra = f"  {r['samples_per_s'] / 1e6:.2f} M samples/s" if "samples_per_s" in r else ""
        print(f"{name:26s} {r['ms']:9.1f} ms{extra}")
    report = {"map": [args.map_height, 2 * args.map_height], "size": args.size, "spp": args.spp, "results": res,
              "machine": finish_info(info, {})}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
