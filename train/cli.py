"""``pfn-train``: photon tracing (and, as they land, field fitting and export).

Examples::

    pfn-train trace vortex --photons 1M --out maps/vortex.npz
    pfn-train trace my_scene.json --photons 3M --phases -0.75 0 0.75 --seed 7 --out maps/mine.npz

Bad input exits with status 2 and one line on stderr: ``error: <input>: <problem>``.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Sequence
from pathlib import Path

from models_spec import DEFAULT_PHASES
from runtime.cli_common import OneLineArgumentParser, check_seed, guarded, prepare_output, set_threads
from runtime.errors import InputError

_COUNT = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([kKmMgG]?)\s*$")


def parse_count(text: str, what: str = "--photons") -> int:
    """'1M' -> 1_000_000, '250k' -> 250_000, '4000' -> 4000."""
    m = _COUNT.match(str(text))
    if not m:
        raise InputError(what, f"expected a count such as 1M, 250k or 4000, got {text!r}")
    value = float(m.group(1)) * {"": 1, "k": 1e3, "m": 1e6, "g": 1e9}[m.group(2).lower()]
    if value < 1 or value != int(value):
        raise InputError(what, f"must be a positive whole number, got {text!r}")
    return int(value)


def build_parser() -> argparse.ArgumentParser:
    p = OneLineArgumentParser(prog="pfn-train", description="Photon Field Networks: photon tracing and training.")
    sub = p.add_subparsers(dest="command", required=True)
    t = sub.add_parser("trace", help="multi-phase photon tracing (Alg. 1) into a photon map",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    t.add_argument("scene", help="builtin scene name (vortex, blobs, shell) or a scene JSON file")
    t.add_argument("--photons", default="1M", help="records to store, e.g. 1M, 250k")
    t.add_argument("--phases", type=float, nargs="+", default=list(DEFAULT_PHASES), help="the phase set G")
    t.add_argument("--max-bounces", type=int, default=16, help="max collisions per photon path")
    t.add_argument("--seed", type=int, default=0, help="random seed: same seed, same map")
    t.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    t.add_argument("--out", required=True, help="output photon map (.npz)")
    return p


def cmd_trace(args: argparse.Namespace) -> int:
    from runtime.scene import load_scene
    from train.photon_tracing import check_phases, trace_photons

    out = Path(args.out)
    photons = parse_count(args.photons)
    check_phases(args.phases, "--phases")
    check_seed(args.seed)
    set_threads(args.threads)
    scene = load_scene(args.scene)
    prepare_output(out, ".npz")
    pmap = trace_photons(scene, photons, phases=args.phases, max_bounces=args.max_bounces, seed=args.seed,
                         progress=not args.quiet)
    pmap.save(out)
    meta = pmap.metadata()
    secs = meta["trace_seconds"]
    print(f"traced {meta['stored']:,} photons ({meta['emitted']:,} paths) in {secs:.2f} s "
          f"({meta['stored'] / max(secs, 1e-9) / 1e6:.2f} M/s) -> {out}")
    print(json.dumps({"per_phase": meta["per_phase"], "phases": meta["phases"]}))
    return 0


@guarded
def _main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return {"trace": cmd_trace}[args.command](args)


def main(argv: Sequence[str] | None = None) -> int:
    sys.exit(_main(argv))
