"""Did a refactoring change any output? Seeded jobs with the console scripts, then a byte comparison.

Usage (from a checkout with its .venv)::

    .venv/bin/python bench/same_outputs.py run OUT_A            # at the commit before the change (a new folder)
    .venv/bin/python bench/same_outputs.py run OUT_B            # after it (clear numba's caches first)
    .venv/bin/python bench/same_outputs.py compare OUT_A OUT_B  # exit status 0: identical

``run`` refuses a folder that holds files unless ``--force`` is given. It traces 30k photons and fits a
``tiny`` field on blobs (seed 3), exports it, and renders 48x40 images
with every renderer (path tracer, ray marcher, photon map, field). ``compare`` requires identical bytes for
the ONNX model, the tables and every EXR and PNG, identical photon arrays, and identical map metadata and
manifest apart from the wall-clock timings they record (``trace_seconds``, ``wall_s``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

IMAGES = ("pt.exr", "rm.exr", "pm.exr", "nf.exr", "pt.png", "nf.png")
BUNDLE_FILES = ("run/field.pfn/field.onnx", "run/field.pfn/tables.npz")
RENDER = ("--scene", "blobs", "--size", "48x40", "--seed", "5", "--quiet")


def run(out: Path, force: bool = False) -> None:
    """The seeded jobs, into ``out``: a new or empty folder, or an earlier run's with ``force``."""
    if out.exists() and any(out.iterdir()) and not force:
        raise SystemExit(f"error: {out}: exists and is not empty; pass --force to replace its outputs")
    bindir = Path(sys.executable).parent
    out.mkdir(parents=True, exist_ok=True)
    jobs = [
        ["pfn-train", "all", "blobs", "--photons", "30k", "--preset", "tiny", "--steps", "20", "--seed", "3",
         "--out", "run", "--quiet", "--force"],
        ["pfn-render", *RENDER, "--method", "pt", "--spp", "4", "--out", "pt.exr", "--force"],
        ["pfn-render", *RENDER, "--method", "raymarch", "--spp", "2", "--out", "rm.exr", "--force"],
        ["pfn-render", *RENDER, "--method", "photonmap", "--map", "run/map.npz", "--g", "0", "--spp", "2",
         "--out", "pm.exr", "--force"],
        ["pfn-render", *RENDER, "--method", "field", "--bundle", "run/field.pfn", "--spp", "2", "--out", "nf.exr",
         "--force"],
    ]
    for job in jobs:
        subprocess.run([str(bindir / job[0]), *job[1:]], cwd=out, check=True, stdout=subprocess.DEVNULL)


def _without(d: Any, key: str) -> Any:
    if isinstance(d, dict):
        return {k: _without(v, key) for k, v in d.items() if k != key}
    if isinstance(d, list):
        return [_without(v, key) for v in d]
    return d


def compare(a: Path, b: Path) -> bool:
    """Print one line per output and whether it is identical; True when all are."""
    same: dict[str, bool] = {f: (a / f).read_bytes() == (b / f).read_bytes() for f in (*BUNDLE_FILES, *IMAGES)}
    with np.load(a / "run/map.npz") as za, np.load(b / "run/map.npz") as zb:
        arrays = za.files == zb.files and all(
            k == "meta" or (za[k].dtype == zb[k].dtype and np.array_equal(za[k], zb[k])) for k in za.files)
        meta = _without(json.loads(bytes(za["meta"])), "trace_seconds") == \
            _without(json.loads(bytes(zb["meta"])), "trace_seconds")
    same["run/map.npz (photons; meta without trace_seconds)"] = arrays and meta
    manifests = [json.loads((d / "run/field.pfn/manifest.json").read_text()) for d in (a, b)]
    same["run/field.pfn/manifest.json (without wall_s)"] = _without(manifests[0], "wall_s") == \
        _without(manifests[1], "wall_s")
    for name, ok in same.items():
        print(f"{'identical' if ok else 'DIFFERENT'}  {name}")
    return all(same.values())


def main(argv: list[str]) -> int:
    force = "--force" in argv
    argv = [a for a in argv if a != "--force"]
    if len(argv) == 2 and argv[0] == "run":
        run(Path(argv[1]), force)
        return 0
    if len(argv) == 3 and argv[0] == "compare":
        return 0 if compare(Path(argv[1]), Path(argv[2])) else 1
    print(__doc__.split("\n\n")[1], file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
