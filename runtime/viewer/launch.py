"""Starting a viewer: load the scene, bundle and photon map once, serve the page on a background thread.

:func:`start` is what ``pfn-view`` and a Jupyter cell call; it returns a :class:`ViewerServer` whose ``url`` is
the page's address (its ``_repr_html_`` shows the page inline in a notebook). Inputs are checked before the
server starts, each bad one refused with one :class:`photon_fields.runtime.errors.InputError` line. The socket
is bound before ``start`` returns, so ``port=0`` gives a free port that is known at once.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.renderers.registry import DEFAULT_GATHER_AFTER
from photon_fields.runtime.viewer.messages import MAX_PIXELS, MAX_SIDE, MIN_SIDE
from photon_fields.runtime.viewer.retrain import RetrainSettings

log = logging.getLogger("photon_fields.viewer")


@dataclass
class ViewerInputs:
    """What every page's session shares: the scene, the field's estimator, the photon map, the PVRT transfer, the
    options."""

    scene: Any
    estimator: Any
    pmap: Any
    out_dir: Path
    seed: int
    width: int  # width x height: the largest frame (pfn-view --size), the size before a page sends its own
    height: int
    renderer: str | None
    info: dict[str, Any]
    threads: int | None = None
    transfer: Any = None  # a PVRT transfer checked against the scene (pfn-view --transfer), or None
    pvrt_options: Any = None  # PvrtOptions of its frames (pfn-view --direct, --light-grid), None: the defaults
    camera_estimator: str | None = None  # the neural renderer's (pfn-view --camera-estimator), None: its default


def load_inputs(scene: str | None, *, bundle: str | None = None, map_path: str | None = None,
                out_dir: str | Path = "pfn_view_out", size: tuple[int, int] | None = None, seed: int = 0,
                threads: int | None = None, force: bool = False, renderer: str | None = None,
                transfer_path: str | None = None) -> ViewerInputs:
    """Load and check everything a viewer needs (one-line :class:`InputError` for anything wrong)."""
    from photon_fields.runtime.scene.scene import load_scene

    if scene is None and bundle is None:
        raise InputError("SCENE", "name a scene (vortex, blobs, shell, head or a scene JSON file) or pass --bundle")
    if scene is None:
        from photon_fields.runtime.field.bundle_reader import scene_for_bundle

        sc, _ = scene_for_bundle(bundle, force=force)
    else:
        sc = load_scene(scene)
    if getattr(sc.tf, "categorical", False):  # a label scene: the page shows a row per label present
        from photon_fields.runtime.scene.labels import volume_labels
        from photon_fields.runtime.viewer.transfer_edit import MAX_PANEL_LABELS

        count = volume_labels(sc.volume).values.size
        if count > MAX_PANEL_LABELS:
            raise InputError(scene or bundle, f"its volume has {count} labels; the viewer's label panel shows at most "
                                              f"{MAX_PANEL_LABELS} (render it with pfn-render)")
    if size is not None:
        check_size(size)
        sc = sc.with_overrides(width=size[0], height=size[1])
    elif sc.camera.width * sc.camera.height > MAX_PIXELS:
        raise InputError("--size", f"the scene camera's {sc.camera.width}x{sc.camera.height} is more than the "
                         f"viewer's {MAX_PIXELS} pixels; pass --size")
    estimator = pmap = None
    info: dict[str, Any] = {"bundle": None, "map": None}
    if bundle is not None:
        from photon_fields.runtime.field.field import PhotonField

        field = PhotonField.load(bundle, threads=threads, precision="fp32", expected_fingerprint=sc.fingerprint(),
                                 force=force, expected_parts=sc.fingerprint_parts(),
                                 expected_lights=sc.light_identities())
        if field.scene_warning:
            log.warning("%s", field.scene_warning)
        if field.light_note:
            log.info("%s", field.light_note)
        estimator = field.estimator()
        info["bundle"] = str(Path(bundle).resolve())
    if map_path is not None:
        from photon_fields.runtime.photons.estimate import map_for_scene
        from photon_fields.runtime.photons.photon_map import PhotonMap

        pmap, warning, note = map_for_scene(PhotonMap.load(map_path), sc, force)
        if warning:
            log.warning("%s", warning)
        if note:
            log.info("%s", note)
        info["map"] = str(Path(map_path).resolve())
    transfer = None
    if transfer_path is not None:
        transfer = load_pvrt_transfer(transfer_path, sc)
        info["transfer"] = str(Path(transfer_path).resolve())
    from photon_fields.runtime.viewer.field_in_use import renderers_with_inputs
    from photon_fields.runtime.viewer.messages import RENDERER_NAMES

    has = renderers_with_inputs(estimator, pmap, transfer)
    if renderer is not None and (renderer not in RENDERER_NAMES or not has[renderer]):
        raise InputError("--renderer", f"must be one of {', '.join(n for n in RENDERER_NAMES if has[n])} here "
                         f"(neural and marched need --bundle, photonmap --map, pvrt --transfer), got {renderer!r}")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError("--out", f"{str(out)!r} exists and is not a folder")
    return ViewerInputs(sc, estimator, pmap, out, seed, sc.camera.width, sc.camera.height, renderer, info, threads,
                        transfer)


def load_pvrt_transfer(path: str, scene: Any) -> Any:
    """The PVRT transfer at ``path``, checked as ``pfn-render --method pvrt`` checks it: made for the scene's volume,
    transfer function, g and box (one-line :class:`InputError` otherwise); and the scene's lights must be distant,
    since the page moves them but never changes their kind (a point light is refused here, not on the first
    frame)."""
    from photon_fields.runtime.pvrt.transfer import load_transfer
    from photon_fields.runtime.scene.lights import PointLight

    transfer = load_transfer(path, scene)
    for i, light in enumerate(scene.lights):
        if isinstance(light, PointLight):
            raise InputError("--transfer", f"the scene's light {i} is a point light: PVRT relights distant lights "
                             "only (directional, environment)")
    return transfer


def check_size(size: tuple[int, int]) -> tuple[int, int]:
    w, h = size
    if not (MIN_SIDE <= w <= MAX_SIDE and MIN_SIDE <= h <= MAX_SIDE) or w * h > MAX_PIXELS:
        raise InputError("--size", f"each side must be in [{MIN_SIDE}, {MAX_SIDE}] and at most {MAX_PIXELS} pixels "
                         f"in all, got {w}x{h}")
    return size


def is_loopback(host: str) -> bool:
    """Whether ``host`` is reachable from this machine only (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def warm_kernels(inputs: ViewerInputs) -> None:
    """Render one tiny frame with every renderer the viewer offers and denoise it, so that the kernels are
    compiled (or loaded from numba's cache) before a page asks for a full-size frame."""
    from photon_fields.runtime.viewer.messages import parse
    from photon_fields.runtime.viewer.session import ViewerSession

    t = time.perf_counter()
    session = ViewerSession(inputs.scene.with_overrides(width=16, height=16), estimator=inputs.estimator,
                            pmap=inputs.pmap, transfer=inputs.transfer, out_dir=inputs.out_dir, seed=inputs.seed,
                            width=16, height=16, renderer=inputs.renderer, pvrt_options=inputs.pvrt_options)
    for name in session.available:
        if name != session.state.renderer:
            try:
                session.apply(parse(f'{{"type": "set", "control": "renderer", "value": "{name}"}}'))
            except ValueError:
                continue  # e.g. a photon map that cannot answer the scene's g: its renderer warms on first use
        session.next_frame()
        session.apply(parse('{"type": "orbit", "dx": 1, "dy": 0}'))
        session.next_frame()  # a moving frame: depth and reprojection
    log.info("kernels warm in %.1f s", time.perf_counter() - t)


class ViewerServer:
    """A running viewer: uvicorn serving the app on a daemon thread. ``url`` is the page; :meth:`stop` ends it."""

    def __init__(self, inputs: ViewerInputs, *, host: str = "127.0.0.1", port: int = 0, warm: bool = True,
                 max_spp: int | None = None, drag_scale: float | str = "auto",
                 retrain: RetrainSettings | None = None, gather_after: int | None = DEFAULT_GATHER_AFTER,
                 interactive_level: int | str = "auto") -> None:
        import uvicorn

        from photon_fields.runtime.viewer.server import MAX_FRAME_BYTES, create_app
        from photon_fields.runtime.viewer.session import DEFAULT_MAX_SPP, ViewerSession

        if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
            raise InputError("--port", f"must be an integer in [0, 65535] (0: any free port), got {port!r}")
        self.inputs = inputs
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise InputError("--host/--port", f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        self.sock.listen(16)
        self.host, self.port = host, self.sock.getsockname()[1]
        shown = f"[{host}]" if ":" in host else host
        self.url = f"http://{shown}:{self.port}/"
        origins = {f"http://{shown}:{self.port}"}
        if is_loopback(host):
            origins |= {f"http://localhost:{self.port}", f"http://127.0.0.1:{self.port}"}

        def make_session() -> ViewerSession:
            session = ViewerSession(inputs.scene, estimator=inputs.estimator, pmap=inputs.pmap,
                                    transfer=inputs.transfer, out_dir=inputs.out_dir, seed=inputs.seed,
                                    width=inputs.width, height=inputs.height, renderer=inputs.renderer,
                                    max_spp=max_spp or DEFAULT_MAX_SPP, info=inputs.info, drag_scale=drag_scale,
                                    retrain=retrain, gather_after=gather_after, pvrt_options=inputs.pvrt_options,
                                    interactive_level=interactive_level, camera_estimator=inputs.camera_estimator)
            session.field_threads = inputs.threads
            return session

        app = create_app(make_session, allowed_origins=lambda: origins,
                         warm=(lambda: warm_kernels(inputs)) if warm else None)
        self.app = app
        config = uvicorn.Config(app, log_level="warning", ws="websockets-sansio", ws_max_size=MAX_FRAME_BYTES,
                                lifespan="off", access_log=False)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, name="pfn-view-http",
                                       daemon=True)
        self.thread.start()

    @property
    def stats(self) -> Any:
        return self.app.state.stats

    def stop(self, timeout: float = 10.0) -> None:
        """Close the pages' connections and stop serving."""
        self.server.should_exit = True
        self.thread.join(timeout)
        self.sock.close()

    def _repr_html_(self) -> str:
        return f'<iframe src="{self.url}" width="100%" height="720" style="border:0"></iframe>'


def start(scene: str | None = None, *, bundle: str | None = None, map: str | None = None,  # noqa: A002
          out: str | Path = "pfn_view_out", size: tuple[int, int] | None = None, host: str = "127.0.0.1",
          port: int = 0, seed: int = 0, threads: int | None = None, force: bool = False,
          renderer: str | None = None, warm: bool = True, max_spp: int | None = None,
          drag_scale: float | str = "auto", retrain: RetrainSettings | None = None,
          gather_after: int | None = DEFAULT_GATHER_AFTER, transfer: str | None = None,
          pvrt_options: Any = None, interactive_level: int | str = "auto",
          camera_estimator: str | None = None) -> ViewerServer:
    """Load the inputs and serve the viewer (module docstring); returns the running :class:`ViewerServer`.
    ``transfer``: a PVRT transfer file (NAME.pvrt) of the scene: enables the pvrt renderer, whose frames are made
    as ``pvrt_options`` (:class:`photon_fields.runtime.viewer.pvrt_view.PvrtOptions`; None: its defaults) say.
    ``interactive_level``: the preview's volume level for the first frame of every change
    (:func:`photon_fields.runtime.viewer.drag_levels.changing_level`). ``camera_estimator``: the neural renderer's
    (None: its default)."""
    from photon_fields.runtime.renderers.registry import checked_camera_estimator

    checked_camera_estimator(camera_estimator)
    if drag_scale != "auto" and (isinstance(drag_scale, bool) or not isinstance(drag_scale, (int, float))
                                 or not 0.25 <= drag_scale <= 1.0):
        raise InputError("--drag-scale", f"must be auto or a number in [0.25, 1], got {drag_scale!r}")
    if interactive_level != "auto":
        from photon_fields.runtime.scene.levels import MAX_LEVEL, check_level

        try:
            check_level(interactive_level)  # type: ignore[arg-type]
        except ValueError:
            raise InputError("--interactive-level", f"must be auto or an integer in [0, {MAX_LEVEL}], got "
                                                    f"{interactive_level!r}") from None
    inputs = load_inputs(scene, bundle=bundle, map_path=map, out_dir=out, size=size, seed=seed, threads=threads,
                         force=force, renderer=renderer, transfer_path=transfer)
    if pvrt_options is not None and inputs.transfer is None:
        raise InputError("--direct/--light-grid", "apply to the pvrt renderer only, which needs --transfer")
    inputs.pvrt_options = pvrt_options
    inputs.camera_estimator = camera_estimator
    return ViewerServer(inputs, host=host, port=port, warm=warm, max_spp=max_spp,
                        drag_scale=drag_scale if drag_scale == "auto" else float(drag_scale), retrain=retrain,
                        gather_after=gather_after, interactive_level=interactive_level)
