"""``pfn-view``: explore a scene in the browser, rendered progressively on this machine (issue 15).

    pfn-view vortex --bundle runs/vortex/field.pfn   # the neural renderer; prints the page's address
    pfn-view my_scene.json                            # no bundle: the path tracer
    pfn-view vortex --transfer vortex.pvrt            # adds PVRT relighting (pfn-train pvrt vortex --out ...)

Binds to 127.0.0.1 unless ``--host`` says otherwise (with a warning: the page can drive renders and write
screenshots). Bad input is refused in one ``error:`` line with exit status 2, before anything is served.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import time
import webbrowser
from collections.abc import Sequence

from photon_fields.runtime.cli.common import OneLineArgumentParser, check_seed, guarded, parse_count
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.renderers.registry import CAMERA_ESTIMATOR_NAMES, DEFAULT_GATHER_AFTER, spp_or_never
from photon_fields.runtime.threads import set_threads


def build_parser() -> OneLineArgumentParser:
    p = OneLineArgumentParser(prog="pfn-view", description="Interactive progressive viewer in the browser.")
    p.add_argument("scene", nargs="?", default=None,
                   help="builtin scene (vortex, blobs, shell, head) or a scene JSON file (default: the bundle's)")
    p.add_argument("--bundle", default=None, help="photon-field bundle (NAME.pfn): enables the neural renderer")
    p.add_argument("--map", default=None, help="photon map (.npz): enables the photon-map renderer")
    p.add_argument("--transfer", default=None,
                   help="PVRT transfer (NAME.pvrt, from pfn-train pvrt): enables the pvrt renderer, which relights "
                        "the resting view at once when a light moves; it must match the scene's volume, transfer "
                        "function and g")
    p.add_argument("--direct", default=None, choices=["nee", "transfer"],
                   help="pvrt: directional lights' direct term: nee (a light volume of their transmittance, sharp "
                        "shadows; the default) or transfer (from the lighting basis, blurred)")
    p.add_argument("--light-grid", type=int, default=None, metavar="CELLS",
                   help="pvrt --direct nee: light-volume cells along the box's longest side (default 64)")
    p.add_argument("--renderer", default=None, choices=["neural", "pt", "preview", "marched", "photonmap", "pvrt"],
                   help="renderer to start with (default: neural with --bundle, else pt; preview: the ray marcher, "
                   "single scattering without training, follows every edit at once; marched: the preview plus the "
                   "field's L_i, needs --bundle)")
    p.add_argument("--camera-estimator", default=None, choices=list(CAMERA_ESTIMATOR_NAMES),
                   help="the neural renderer's camera estimator (default forced; marched: the preview's cached light "
                        "along each ray, corrected at three points: less noise per millisecond on sparse transfer "
                        "functions, e.g. 0.4x the error of a forced frame for 3x its time; docs/rendering.md)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=0, help="port (default 0: any free port)")
    p.add_argument("--out", default="pfn_view_out", help="folder screenshots are written to (the only one)")
    p.add_argument("--size", default="512x512",
                   help="the largest frame WIDTHxHEIGHT (default 512x512): frames take the size of the page's view "
                        "in device pixels, scaled down to at most WIDTH*HEIGHT pixels keeping the view's aspect "
                        "ratio (the page scales them up); before the page reports its size, WIDTHxHEIGHT itself")
    p.add_argument("--seed", type=int, default=0, help="random seed: the same inputs give the same frames")
    p.add_argument("--max-spp", type=int, default=1024, help="stop refining a resting view at this many samples")
    p.add_argument("--final-gather-after", type=spp_or_never, default=DEFAULT_GATHER_AFTER, metavar="SPP",
                   help=f"once a resting view has SPP samples (default {DEFAULT_GATHER_AFTER}), the neural renderer's "
                        "further samples take one real bounce before the field: slower and noisier per sample, less "
                        "biased once converged; 0: from the first resting sample, never: not at all")
    p.add_argument("--drag-scale", type=_drag_scale, default="auto",
                   help="render moving frames at this fraction of the frame size, in [0.25, 1], or auto: the size that "
                        "keeps ~8 frames/s while moving (resting frames: always full size)")
    p.add_argument("--interactive-level", type=_level, default="auto", metavar="LEVEL",
                   help="the preview's first frame after each camera move or edit marches this level of the volume "
                        "(blocks of 2^LEVEL voxels averaged; resting frames: the full volume); auto (default): a level "
                        "chosen by the volume's size (docs/viewer.md), 0: always the full volume")
    p.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")
    p.add_argument("--retrain-photons", default="1M",
                   help="photons of the map a background retrain traces after a transfer-function or light edit")
    p.add_argument("--no-auto-retrain", action="store_true",
                   help="retrain only when the page's retrain button is pressed (default: after every edit that "
                        "makes L_i stale, once the edits rest)")
    p.add_argument("--force", action="store_true", help="use a bundle or map made for another scene")
    p.add_argument("--no-browser", action="store_true", help="only print the address")
    p.add_argument("--quiet", action="store_true", help="log warnings only")
    return p


def _drag_scale(text: str) -> float | str:
    """``--drag-scale``: ``auto`` or a number (its range is checked by :func:`launch.start`)."""
    return "auto" if text == "auto" else float(text)


def _level(text: str) -> int | str:
    """``--interactive-level``: ``auto`` or an integer (its range is checked by :func:`launch.start`)."""
    return "auto" if text == "auto" else int(text)


def parse_size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d{1,6})\s*[xX]\s*(\d{1,6})\s*", text)
    if m is None:
        raise InputError("--size", f"expected WIDTHxHEIGHT such as 512x512, got {text!r}")
    return int(m.group(1)), int(m.group(2))


@guarded
def _main(argv: Sequence[str] | None = None) -> int:
    from photon_fields.runtime.viewer.launch import check_size, is_loopback, start

    args = build_parser().parse_args(argv)
    size = check_size(parse_size(args.size))
    check_seed(args.seed)
    if not 1 <= args.max_spp <= 1 << 16:
        raise InputError("--max-spp", f"must be an integer in [1, {1 << 16}], got {args.max_spp}")
    set_threads(args.threads)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO, format="pfn-view: %(message)s")
    if not args.quiet:
        from photon_fields.runtime.compile_notice import announce_compiles

        announce_compiles(logging.getLogger("photon_fields.viewer").info)
    from photon_fields.runtime.viewer.retrain import RetrainSettings

    pvrt_options = None
    if args.direct is not None or args.light_grid is not None:
        from photon_fields.runtime.viewer.pvrt_view import LIGHT_GRID_RANGE, PvrtOptions

        lo, hi = LIGHT_GRID_RANGE
        if args.light_grid is not None and not lo <= args.light_grid <= hi:
            raise InputError("--light-grid", f"must be an integer in [{lo}, {hi}], got {args.light_grid}")
        defaults = PvrtOptions()
        pvrt_options = PvrtOptions(args.direct or defaults.direct, args.light_grid or defaults.light_grid)
    retrain = RetrainSettings(photons=str(parse_count(args.retrain_photons, "--retrain-photons")),
                              auto=not args.no_auto_retrain)
    server = start(args.scene, bundle=args.bundle, map=args.map, out=args.out, size=size, host=args.host,
                   port=args.port, seed=args.seed, threads=args.threads, force=args.force, renderer=args.renderer,
                   max_spp=args.max_spp, drag_scale=args.drag_scale, retrain=retrain,
                   interactive_level=args.interactive_level,
                   gather_after=args.final_gather_after, transfer=args.transfer, pvrt_options=pvrt_options,
                   camera_estimator=args.camera_estimator)
    if not is_loopback(args.host):
        print(f"warning: listening on {args.host}: anyone who can reach it can drive renders and write screenshots "
              f"into {args.out}", file=sys.stderr)
    print(f"pfn-view: {server.url} (Ctrl-C to stop)", flush=True)
    if not args.no_browser:
        webbrowser.open(server.url)
    try:
        while server.thread.is_alive():
            time.sleep(0.5)
    finally:
        server.stop()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    # One OpenBLAS thread unless the user chose otherwise, set before numpy loads: the viewer's frames are numba
    # and onnxruntime work, and OpenBLAS's spinning threads made building a procedural volume (matrix products)
    # many times slower whenever another process held a core (docs/viewer.md), which delayed the first frame.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    sys.exit(_main(argv))


if __name__ == "__main__":
    main()
