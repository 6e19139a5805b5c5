"""``pfn-train pvrt``: precompute a PVRT transfer (Zhang et al. 2013; :mod:`photon_fields.runtime.pvrt`) for
``pfn-render --method pvrt --transfer NAME.pvrt``.

:func:`add_pvrt_parser` adds the subcommand and its options (defaults from ``runtime.pvrt.constants``) to
``pfn-train``'s parser; :func:`cmd_pvrt` checks every option, then precomputes and writes the transfer. The
precomputation itself lives in the runtime (no torch); this module only reads the command line.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from photon_fields.runtime.cli.common import check_seed, parse_count, prepare_output
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.threads import set_threads
from photon_fields.train.cli.progress_option import add_job_options, open_progress, stage_callback


def add_pvrt_parser(sub: argparse._SubParsersAction) -> None:
    # Defaults from runtime.pvrt.constants (a light module: numpy and models_spec only).
    from photon_fields.runtime.pvrt import constants as c

    v = sub.add_parser("pvrt", help="precompute a PVRT transfer (basis-light photon tracing, splatting, CPCA) for "
                       "pfn-render --method pvrt", formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    v.add_argument("scene", help="builtin scene name or scene JSON file (its volume, transfer function and g; its "
                                 "lights are not used: the transfer is relit at render time)")
    v.add_argument("--out", required=True, help="output transfer file (NAME.pvrt)")
    v.add_argument("--basis", choices=list(c.BASIS_KINDS), default="dsf",
                   help="lighting basis: dsf (the paper's discrete spherical functions) or sh")
    v.add_argument("--order", type=int, default=None,
                   help=f"basis order: DSF subdivision level in {list(c.DSF_ORDERS)} (12, 42, 162, 642 lights; "
                        f"default {c.DEFAULT_DSF_ORDER}, or 1 where it would not fit the memory budget at "
                        f"{c.MIN_AUTO_GRID} cells a side) or SH l_max in {list(c.SH_ORDERS)} (default "
                        f"{c.DEFAULT_SH_ORDER})")
    v.add_argument("--grid", default="auto",
                   help=f"transfer cells along the box's longest side in {list(c.GRID_RANGE)}, or auto: the most up "
                        f"to {c.DEFAULT_GRID} whose uncompressed transfer fits {c.TRANSFER_BUDGET_BYTES >> 20} MB")
    v.add_argument("--paths", default=str(c.DEFAULT_PATHS_PER_BASIS),
                   help="photon paths per basis light (e.g. 64k)")
    v.add_argument("--exitance-order", default="auto",
                   help=f"SH l_max of each cell's radiance in {list(c.EXITANCE_ORDERS)}, or auto: the least whose "
                        f"first dropped band g^(l_max + 1) weighs <= {c.EXITANCE_TOLERANCE:.3f} (0 for g = 0)")
    v.add_argument("--clusters", type=int, default=c.DEFAULT_CLUSTERS, help="CPCA clusters")
    v.add_argument("--pca-bases", type=int, default=c.DEFAULT_PCA_BASES, help="CPCA bases per cluster")
    v.add_argument("--g", type=float, default=None, help="Henyey-Greenstein g the photons scatter with (default: "
                                                         "the scene's; the renderer refuses another)")
    v.add_argument("--seed", type=int, default=0, help="random seed: same seed, same transfer bytes")
    add_job_options(v, replaces="an existing transfer file")


def cmd_pvrt(args: argparse.Namespace) -> int:
    """``pfn-train pvrt``: check every option, then precompute and write the transfer (``runtime.pvrt``)."""
    from photon_fields.models_spec.pvrt_transfer import PVRT_SUFFIX
    from photon_fields.runtime.pvrt.basis import check_basis
    from photon_fields.runtime.pvrt.constants import (
        DEFAULT_DSF_ORDER,
        DEFAULT_GRID,
        DEFAULT_SH_ORDER,
        DSF_ORDERS,
        EXITANCE_ORDERS,
        GRID_RANGE,
        SH_ORDERS,
    )
    from photon_fields.runtime.pvrt.precompute import check_settings
    from photon_fields.runtime.pvrt.transfer import precompute_transfer, save_transfer
    from photon_fields.runtime.scene.scene import load_scene

    out = Path(args.out)
    paths = parse_count(args.paths, "--paths")
    order = args.order  # None: precompute_transfer's default (DSF: by the memory budget)
    lo, hi = DSF_ORDERS if args.basis == "dsf" else SH_ORDERS
    if order is not None and not lo <= order <= hi:
        raise InputError("--order", f"a {args.basis} order must be an integer in [{lo}, {hi}], got {order}")
    check_basis(args.basis, (DEFAULT_DSF_ORDER if args.basis == "dsf" else DEFAULT_SH_ORDER) if order is None
                else order, "--basis")
    exitance = _auto_or_int(args.exitance_order, "--exitance-order", EXITANCE_ORDERS)
    grid = _auto_or_int(args.grid, "--grid", GRID_RANGE)
    ranges = (("--paths", paths, (1, 2**32 - 1)),)
    for flag, value, (lo, hi) in ranges:
        if not lo <= value <= hi:
            raise InputError(flag, f"must be an integer in [{lo}, {hi}], got {value}")
    check_settings(DEFAULT_GRID if grid is None else grid, 0 if exitance is None else exitance, paths)
    for flag, value, lo, hi in (("--clusters", args.clusters, 1, 4096), ("--pca-bases", args.pca_bases, 0, 64)):
        if not lo <= value <= hi:
            raise InputError(flag, f"must be an integer in [{lo}, {hi}], got {value}")
    if args.g is not None:
        from photon_fields.runtime.transport.phase import check_g

        check_g(args.g, "--g")
    check_seed(args.seed)
    set_threads(args.threads)
    scene = load_scene(args.scene).with_overrides(g=args.g)
    prepare_output(out, PVRT_SUFFIX, force=args.force, what="a transfer file")
    progress = open_progress(args, ("trace", "cpca"))
    transfer = precompute_transfer(scene, basis=args.basis, order=order, grid=grid,
                                   exitance_order=exitance, paths=paths, clusters=args.clusters,
                                   bases=args.pca_bases, seed=args.seed, progress=not args.quiet,
                                   on_progress=stage_callback(progress, "trace"))
    save_transfer(transfer, out, force=args.force)
    if progress is not None:
        progress.finish("done", f"transfer {out}")
    mf = transfer.manifest
    secs = transfer.seconds or {"trace": 0.0, "cpca": 0.0}
    print(f"precomputed {transfer.basis.size} {mf['basis']['kind']} basis lights x {paths:,} paths on a "
          f"{'x'.join(map(str, mf['grid']))} grid in {secs['trace']:.1f} s (CPCA {secs['cpca']:.1f} s, "
          f"{mf['cpca']['clusters']} clusters x {mf['cpca']['bases']} bases, relative error "
          f"{mf['cpca']['relative_error']:.3f}) -> {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0


def _auto_or_int(text: str, flag: str, limits: tuple[int, int]) -> int | None:
    """An option that is ``auto`` (None: the precomputation chooses) or an integer within ``limits``."""
    if text == "auto":
        return None
    lo, hi = limits
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not lo <= value <= hi:
        raise InputError(flag, f"must be auto or an integer in [{lo}, {hi}], got {text!r}")
    return value
