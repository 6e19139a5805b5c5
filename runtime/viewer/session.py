"""One page's render state machine: what to render next, progressive accumulation, denoising, frames.

A :class:`ViewerSession` is driven from two threads:

- the server's event loop calls :meth:`ViewerSession.apply` with each validated message; it only updates the
  state under a lock (microseconds), so input is never queued behind a render;
- the session's render thread calls :meth:`ViewerSession.next_frame`, which takes a snapshot of the newest
  state, renders one frame of 1 sample per pixel, adds it to the accumulation and returns the encoded image.
  Whatever changed while a frame rendered is picked up by the next one: intermediate camera positions are never
  rendered (newest camera wins), and a frame's samples are never added to the accumulation of a newer state.

Accumulation: every change that alters the image (camera, g, lights, renderer, frame size) starts a new
*generation*; its frames add up sample by sample. The neural renderer's frame ``n`` draws samples
``first_sample = n`` of one seed, so ``n`` frames are exactly one render of ``n`` spp (up to the float32
rounding of each frame's mean); the path tracer and the photon-map renderer, which take no ``first_sample``,
use seed ``seed + n`` for frame ``n``, so the mean converges to the same image statistically.

Denoising (:class:`photon_fields.runtime.denoise.wrls.WRLSDenoiser`): while the camera moves every frame is a
fresh 1-spp frame, denoised with the temporal history reprojected from the previous view. Once the camera rests
the *accumulated* image is fed to the denoiser (its noise falls as 1 / samples, the WRLS docstring's static
use) for the first :attr:`ViewerSession.denoise_frames` frames, then the plain accumulation is shown (the
denoiser's slight blur would stay). A change that is not a camera move (g, lights, renderer, layer, size) is a
cut: the denoiser forgets its history.

Reduced moving frames (``drag_scale`` < 1, or ``"auto"``, ``pfn-view``'s default): while the camera moves, frames
are rendered at that fraction of the size (the page scales them up) and denoised by a denoiser of their own size;
the first frame at rest starts a full-size accumulation. An interactive compromise, so that dragging stays fluid
where a full-size frame is too slow; the page's selector and ``pfn-view --drag-scale`` set it. ``"auto"`` picks
the fraction from :data:`DRAG_LEVELS` after every moving frame (:func:`next_drag_level`) so that moving frames
keep :data:`DRAG_FPS` frames per second (the level a drag ends with is where the next one starts).

Frame size: :attr:`ViewerSession.max_size` (``pfn-view --size``) until the page sends its view box's size (``view``);
then that size, scaled down to ``max_size``'s pixel count (:func:`photon_fields.runtime.viewer.frame_size.fit_view`).
Frame headers carry the frame's size and the view it is for (``view_size``): the page scales it to the box.

Deterministic renderers (the renderer table's ``progressive`` is False: PVRT, ``pfn-view --transfer``): a frame of
theirs is the same image whatever its sample index, so a resting view takes one frame, and it is neither accumulated
further nor denoised. A moving frame of theirs is followed, once the camera rests, by the resting view's own frame:
PVRT keeps that view's camera samples, so that a light change is only a relit frame
(:class:`photon_fields.runtime.viewer.pvrt_view.PvrtView`).

The preview (the ray marcher, no L_i, no training): frame ``n`` is the march of seed ``seed + n``; a resting view
averages a few (:func:`photon_fields.runtime.viewer.field_in_use.resting_frames`), none denoised (docs/viewer.md).
On a large volume the first frame of every change (a camera move or an edit) marches a coarser level of it
(``interactive_level``, :func:`photon_fields.runtime.viewer.drag_levels.changing_level`); the view, once it rests,
takes full-level frames of its own, never averaged with that one.

Final gather at rest: from sample :attr:`ViewerSession.gather_after` of a resting view on, neural frames take one
real bounce before the field (:mod:`photon_fields.runtime.wavefront.final_gather`): noisier, slower, less biased
samples, worth it once many have averaged (``bench_final_gather.py``); headers count them (``gathered``).

Exposure: measured automatically (:func:`photon_fields.runtime.io.images.auto_exposure_stops`) on the first
frame after a cut, and then kept while the camera moves so brightness does not flicker; the page's exposure
control adds stops to it, and ``"auto"`` measures it again.

Transfer-function and light edits (:mod:`photon_fields.runtime.viewer.field_in_use`): the edited scene renders at
once (its medium, L_d, the path tracer), whether the function was edited as control points (``transfer``) or, in
a label scene, in the label panel (``labels``, :class:`photon_fields.runtime.viewer.transfer_edit.LabelPanel`);
the field's L_i follows a single light's power exactly and is marked stale otherwise, while
:class:`photon_fields.runtime.viewer.updater.FieldUpdater` retrains in the background and
:meth:`ViewerSession.poll_updates` swaps the new field in.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.renderers.registry import DEFAULT_GATHER_AFTER, checked_camera_estimator
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.viewer import screenshot
from photon_fields.runtime.viewer.accumulation import Accumulation
from photon_fields.runtime.viewer.camera import OrbitView
from photon_fields.runtime.viewer.drag_levels import DRAG_LEVELS, changing_level, next_drag_level
from photon_fields.runtime.viewer.encode import encode, tonemap
from photon_fields.runtime.viewer.field_in_use import FieldInUse, noisy, progressive, resting_frames
from photon_fields.runtime.viewer.frame_denoisers import FrameDenoisers
from photon_fields.runtime.viewer.frame_size import fit_view
from photon_fields.runtime.viewer.light_control import LightControl, edited_lights
from photon_fields.runtime.viewer.messages import MIN_SIDE, Message, MessageError
from photon_fields.runtime.viewer.pvrt_view import PvrtOptions, PvrtView
from photon_fields.runtime.viewer.render_turns import render_turn
from photon_fields.runtime.viewer.retrain import RetrainSettings
from photon_fields.runtime.viewer.set_controls import apply_set
from photon_fields.runtime.viewer.state_message import state_message
from photon_fields.runtime.viewer.transfer_edit import (
    edited_transfer,
    label_panel,
    shows_something,
    volume_histogram,
)
from photon_fields.runtime.viewer.updater import FieldUpdater
from photon_fields.runtime.viewer.view_state import DEFAULT_MAX_SPP, Frame, ViewState

DEFAULT_DENOISE_FRAMES = 16


class ViewerSession:
    """The render state of one page (module docstring). ``estimator``: a photon field's estimator (enables the
    neural renderer), ``pmap``: a photon map (the photon-map renderer), ``transfer``: a PVRT transfer checked
    against ``scene`` (the pvrt renderer, made as ``pvrt_options`` say); the path tracer is always there.
    ``out_dir``: the only folder screenshots are written to. ``width`` x ``height`` (default: the scene camera's)
    is the largest frame (``pfn-view --size``): frames are rendered at it until the page sends its view's size,
    then at that size scaled down to its pixel count (:func:`photon_fields.runtime.viewer.frame_size.fit_view`)."""

    def __init__(self, scene: Scene, *, estimator: Any = None, pmap: Any = None, transfer: Any = None, out_dir: Path,
                 seed: int = 0, width: int | None = None, height: int | None = None,
                 renderer: str | None = None, max_spp: int = DEFAULT_MAX_SPP,
                 denoise_frames: int = DEFAULT_DENOISE_FRAMES, info: dict[str, Any] | None = None,
                 drag_scale: float | str = 1.0, retrain: RetrainSettings | None = None,
                 gather_after: int | None = DEFAULT_GATHER_AFTER, pvrt_options: PvrtOptions | None = None,
                 interactive_level: int | str = "auto", camera_estimator: str | None = None) -> None:
        self.base_scene = scene
        changing_level(interactive_level, "preview", scene.volume.dims)  # refuses a bad one here
        self.interactive_level = interactive_level
        self.field = FieldInUse(scene, estimator, pmap, FieldInUse.run_folder_of((info or {}).get("bundle")),
                                PvrtView(transfer, scene.tf, pvrt_options) if transfer is not None else None)
        self.out_dir = Path(out_dir)
        self.seed = int(seed)
        self.denoise_frames = int(denoise_frames)
        self.gather_after = None if gather_after is None else int(gather_after)
        self.info = dict(info or {})
        if renderer is None:
            renderer = "neural" if estimator is not None else "pt"
        if renderer not in self.available:
            raise InputError("renderer", f"'{renderer}' needs its input (neural and marched: --bundle, photonmap: "
                                         "--map, pvrt: --transfer)")
        cam = scene.camera
        self.state = ViewState(OrbitView.from_camera(cam), renderer, g=scene.g,
                               lights=[LightControl.from_light(lt) for lt in scene.lights], max_spp=int(max_spp),
                               width=width or cam.width, height=height or cam.height,
                               drag_scale=drag_scale if drag_scale == "auto" else float(drag_scale),
                               transfer=scene.tf, labels=label_panel(scene.tf, scene.volume),
                               camera_estimator=checked_camera_estimator(camera_estimator))
        self.max_size = (self.state.width, self.state.height)  # the largest frame (pfn-view --size)
        self.updater = FieldUpdater(self.out_dir, retrain or RetrainSettings(), seed=self.seed)
        self.drag_level = 0  # drag_scale "auto": the index in DRAG_LEVELS of the next moving frame
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        self.generation = 0  # bumped by every change that alters the image
        self.cut = True  # the next generation starts the denoiser afresh (not a camera move)
        self.redisplay = True  # the next frame must be sent even if nothing is left to render
        self.reexpose = True  # measure the automatic exposure again on the next frame
        self.last_seq: int | None = None
        self.frames = 0
        self.dropped = 0  # refinement frames of a view that changed while they rendered
        self.scene = scene
        self._lights_version = 0
        self._scene_lights_version = 0
        # Owned by the render thread (next_frame), read by screenshot() under self.lock:
        self._acc = Accumulation()
        self._acc_generation = -1
        self._acc_size: tuple[int, int] = (0, 0)  # (width, height) of the accumulation
        # The accumulation is a deterministic renderer's moving frame or a coarser level's frame: the view, once at
        # rest, takes a frame of its own (the one PVRT keeps its camera samples in, so that the next light change is
        # only a relit frame; the preview's full level).
        self._unrested = False
        self._auto_stops: float | None = None
        self._denoisers = FrameDenoisers()
        self._last_header: dict[str, Any] = {}
        self._shot_lock = threading.Lock()
        self._histogram: list[float] | None = None
        self.field_threads: int | None = None  # onnxruntime threads of a retrained field (launch sets --threads)

    # ------------------------------------------------------------------------------------------------
    # input (event-loop thread)

    @property
    def estimator(self) -> Any:
        return self.field.estimator

    @property
    def pmap(self) -> Any:
        return self.field.pmap

    @property
    def available(self) -> list[str]:
        """The renderers this session can use (page names)."""
        return self.field.available

    def apply(self, msg: Message) -> None:
        """Apply a validated message to the state (a :class:`MessageError` if it cannot apply here: a renderer
        without its input, a light that does not exist, a g the photon map cannot answer, all lights off).
        Screenshots are not state: the server calls :meth:`screenshot`."""
        f = msg.fields
        with self.lock:
            s = self.state
            restart, cut, redisplay, reexpose = True, False, False, False
            if msg.type == "orbit":
                s.view = s.view.orbit(f["dx"], f["dy"])
            elif msg.type == "pan":
                s.view = s.view.pan(f["dx"], f["dy"], s.width / s.height)
            elif msg.type == "zoom":
                s.view = s.view.zoom(f["factor"])
            elif msg.type == "reset_camera":
                s.view = OrbitView.from_camera(self.base_scene.camera)
            elif msg.type == "view":
                size = fit_view((f["width"], f["height"]), self.max_size)
                restart = cut = size != (s.width, s.height)
                redisplay = s.view_size != (f["width"], f["height"])  # the page learns which view a frame is for
                s.width, s.height = size
                s.view_size = (f["width"], f["height"])
            elif msg.type == "light":
                s.lights = edited_lights(s.lights, f)
                self._lights_version += 1
                cut = True
            elif msg.type == "set":
                restart, cut, redisplay, reexpose = apply_set(s, self.field, f["control"], f["value"])
            elif msg.type == "screenshot":
                restart = False
            elif msg.type in ("transfer", "labels"):  # control points, or a label scene's panel
                transfer, labels = edited_transfer(msg.type, f, self.base_scene.tf, s.labels)
                self.field.check(s.renderer, s.g, transfer)
                s.transfer, s.labels = transfer, labels
                self._lights_version += 1  # the scene is rebuilt (its medium too) for the next frame
                cut = True
            elif msg.type == "retrain":
                restart = False
                if f["action"] == "cancel":
                    self.updater.cancel()
                elif not shows_something(s.transfer):
                    raise MessageError("retrain: every label is hidden: there is nothing to train a field for")
                else:
                    self.updater.want(self.edited_scene(s), now=True, warm_from=self.field.run_dir)
            else:  # validate() knows no other types; a new one must be handled here first
                raise MessageError(f"message type {msg.type!r} is not handled")
            if msg.seq is not None:
                self.last_seq = msg.seq
            # an edit, or a switch of renderer (a retrain may wait for the page to leave PVRT: FieldUpdater.auto_after);
            # without a field or map nothing is stale, and nothing is trained while every label is hidden
            edit = msg.type in ("transfer", "labels", "light")
            if (edit or (msg.type == "set" and f["control"] == "renderer")) and self.updater.auto_after(
                    edit, self.field.exists and self.field_stale(s) and shows_something(s.transfer),
                    s.renderer == "pvrt"):
                self.updater.want(self.edited_scene(s), warm_from=self.field.run_dir)
            if restart:
                self.generation += 1
            self.cut = self.cut or cut
            self.reexpose = self.reexpose or reexpose
            self.redisplay = self.redisplay or redisplay or restart
            self.changed.notify_all()

    def edited_scene(self, s: ViewState) -> Scene:
        """The scene as the page has edited it (transfer function and lights; camera and g are not part of
        what a field is trained for)."""
        return replace(self.base_scene, tf=s.transfer or self.base_scene.tf,
                       lights=tuple(lt.light() for lt in s.lights), _cache={})

    def field_stale(self, s: ViewState) -> bool:
        """Whether the field's (and the map's) L_i is not the edited scene's: another transfer function, or a
        light edit that :meth:`indirect_scale` cannot follow."""
        return self.field.stale(s.transfer, s.lights)

    # ------------------------------------------------------------------------------------------------
    # rendering (render thread)

    @staticmethod
    def target_spp(s: ViewState) -> int:
        """The samples a resting view of state ``s`` accumulates (:func:`resting_frames`)."""
        return resting_frames(s.renderer, s.max_spp)

    def wants_frame(self) -> bool:
        """Whether :meth:`next_frame` has anything to do (call with :attr:`lock` held)."""
        if self.redisplay or self.generation != self._acc_generation:
            return True
        if self._acc_size != (self.state.width, self.state.height) or self._unrested:
            return True  # the last frame was a (reduced) moving frame: the resting view needs its own
        return self._acc.samples < self.target_spp(self.state)

    def wait_for_work(self, stop: threading.Event, timeout: float = 0.5) -> bool:
        """Block until there is a frame to render (True) or ``timeout`` passes / ``stop`` is set (False)."""
        with self.lock:
            if stop.is_set():
                return False
            if self.wants_frame():
                return True
            self.changed.wait(timeout)
            return not stop.is_set() and self.wants_frame()

    def _scene_for(self, s: ViewState, width: int, height: int) -> Scene:
        """The scene of state ``s`` at ``width`` x ``height`` (lights rebuilt only when they changed; the medium
        is shared)."""
        if self._scene_lights_version != self._lights_version:
            scene = self.edited_scene(s)
            if scene.tf is self.scene.tf:  # the medium (and its levels') ignores the lights: shared if built
                scene.adopt_medium(self.scene)
            else:  # a new transfer function: a new medium, and the depth it gives the denoisers
                self._denoisers.forget_medium()
            self.scene, self._scene_lights_version = scene, self._lights_version
        return self.scene.with_overrides(g=s.g, camera=s.view.camera(width, height))

    def next_frame(self) -> Frame | None:
        """Render (or only re-encode) the next frame of the newest state (module docstring). None when the frame
        was a refinement of a view that changed while it rendered: it is dropped before denoising and encoding
        (its samples still count for its own accumulation, which is then discarded), so the new view's first
        frame starts sooner. The first frame of every state is always shown, or a continuous drag of the
        camera or of a slider would show nothing."""
        t0 = time.perf_counter()
        with self.lock:
            s = replace(self.state)
            generation, cut, seq, reexpose = self.generation, self.cut, self.last_seq, self.reexpose
            full = (s.width, s.height)
            render = (generation != self._acc_generation or self._acc.samples < self.target_spp(s)
                      or self._acc_size != full or self._unrested)
            self.cut = self.redisplay = self.reexpose = False
            fresh = generation != self._acc_generation
            level = changing_level(self.interactive_level, s.renderer, self.base_scene.volume.dims) if fresh else 0
            if fresh:
                moved_only = not cut
                self._acc.clear()
                self._acc_generation = generation
            else:
                moved_only = False
            size = full
            scale = DRAG_LEVELS[self.drag_level] if s.drag_scale == "auto" else float(s.drag_scale)
            if moved_only and scale < 1.0:
                size = (max(MIN_SIDE, round(s.width * scale)), max(MIN_SIDE, round(s.height * scale)))
            # the resting frame of a view whose deterministic moving frame or coarser level is shown already: dropped,
            # as a refinement is, when the view changes while it renders (a new view's first frame never is)
            settling = render and self._unrested and not fresh
            if render and (self._acc_size != size or self._unrested):  # a moving frame before: rest starts anew
                self._acc.clear()
            self._acc_size = size
            self._unrested = render and ((moved_only and not progressive(s.renderer)) or level > 0)
            scene = self._scene_for(s, *size)
            source = self.scene  # replaced by this thread only
        # The medium, built (outside the lock: tens of ms and more) for this frame's copy, is kept on the session's
        # scene too, so that later frames and the next light edit share it (else each light edit rebuilt the medium,
        # the denoisers' depth and PVRT's kept samples when the scene's medium was not built before the first frame).
        # A coarser level's frame builds only its level's (kept in the scene's shared cache).
        if level == 0:
            source._cache.setdefault("medium", scene.medium())
        timings: dict[str, float] = {}
        warnings = self.field.warnings(s.renderer, s.transfer, s.lights, self.updater)
        # Frames without Monte Carlo noise (the preview, PVRT) are never denoised: no denoiser (nor its depth
        # estimator) is built for them; a switch back to a noisy renderer is a cut, which resets their history.
        denoise = s.denoise and noisy(s.renderer)
        denoiser = self._denoisers.for_frame(scene, size, full, cut) if denoise else None
        if reexpose:
            self._auto_stops = None
        refining = render and (self._acc.samples > 0 or settling)
        gather = render and not moved_only and self.gathers(s.renderer, self._acc.samples)
        if render:
            from photon_fields.runtime.wavefront.batches import RenderCancelledError  # loaded with the renderers

            t = time.perf_counter()
            # A refinement is thrown away if the view changes while it renders: it is given up between batches
            # then, so that the new view's first frame waits for a quarter of a frame at most, not a whole one.
            cancel = (lambda: self.generation != generation) if refining else None
            try:
                with render_turn():  # the sessions' renders take turns (render_turns.py)
                    layers = self._render(scene, s, self._acc.samples, gather, moved_only, cancel, level)
            except RenderCancelledError:
                with self.lock:
                    self.dropped += 1
                return None
            timings["render_ms"] = (time.perf_counter() - t) * 1e3
            with self.lock:
                if self._acc_generation == generation:
                    self._acc.add(layers, gathered=gather, replace=not progressive(s.renderer))
        with self.lock:
            if refining and self.generation != generation:
                self.dropped += 1
                return None
            mean = self._acc.mean(s.layer)
            n, gathered = self._acc.samples, self._acc.gathered
        if mean is None:  # nothing rendered yet for this state (only possible on a redisplay race): black
            mean = np.zeros((size[1], size[0], 3), np.float32)
        shown, denoised = mean, False
        if denoiser is not None and 0 < n <= self.denoise_frames:
            t = time.perf_counter()
            shown = denoiser.denoise(mean, camera=scene.camera)
            timings["denoise_ms"] = (time.perf_counter() - t) * 1e3
            denoised = True
        if self._auto_stops is None:
            from photon_fields.runtime.io.images import auto_exposure_stops

            self._auto_stops = auto_exposure_stops(shown)
        stops = self._auto_stops + s.exposure_offset
        t = time.perf_counter()
        data = encode(tonemap(shown, stops), s.format)
        timings["encode_ms"] = (time.perf_counter() - t) * 1e3
        timings["total_ms"] = (time.perf_counter() - t0) * 1e3
        if moved_only and s.drag_scale == "auto":
            self.drag_level = next_drag_level(self.drag_level, timings["total_ms"] * 1e-3)
        self.frames += 1
        header = {"type": "frame", "frame": self.frames, "seq": seq, "generation": generation, "spp": n,
                  "stale": self.field.stale_for(s.renderer, s.transfer, s.lights),
                  "renderer": s.renderer, "layer": s.layer, "g": s.g, "width": size[0], "height": size[1],
                  "view_size": list(s.view_size) if s.view_size else None, "format": s.format, "exposure": stops,
                  "denoised": denoised, "moving": moved_only, "gathered": gathered, "level": level, "rendered": render,
                  "warnings": warnings, **self.field.estimator_report(s.camera_estimator, s.renderer),
                  "pvrt": dict(self.field.pvrt.last) if s.renderer == "pvrt" and self.field.pvrt else None,
                  **{k: round(v, 2) for k, v in timings.items()}}
        self._last_header = header
        return Frame(data, header)

    def poll_updates(self) -> dict[str, Any] | None:
        """Between frames (render thread): advance background retraining (:class:`FieldUpdater`); load a finished
        job's field and map and swap them in. Returns a ``retrain`` status message for the page, or None."""
        status, finished = self.updater.poll()
        if finished is None:
            return status
        try:
            field = FieldInUse.from_job(finished, self.field_threads)
        except (InputError, OSError, ValueError) as exc:
            return self.updater.failed(f"the new field could not be loaded: {exc}")
        field.pvrt = self.field.pvrt  # a PVRT transfer is not retrained: it stays
        with self.lock:
            first = self.field.estimator is None
            self.field = field
            if first and self.state.renderer == "pt":  # no field until now: show the one just trained
                self.state.renderer = "neural"
            self.generation += 1
            self.cut = self.redisplay = True
            self.changed.notify_all()
            status = {**status, "renderers": list(self.available), "renderer": self.state.renderer,
                      "bundle": str(finished.bundle)}
            self.info["bundle"], self.info["map"] = str(finished.bundle), str(finished.photon_map)
        return self.updater.emit(status)

    def close(self) -> None:
        """The page went away: stop its background job."""
        self.updater.close()

    def hold(self) -> None:
        """After a frame failed: render nothing more until the state changes (the same state would fail
        again)."""
        with self.lock:
            self._acc_generation = self.generation
            self._acc.samples = max(self._acc.samples, self.state.max_spp)
            self.redisplay = self._unrested = False

    def _render(self, scene: Scene, s: ViewState, n: int, gather: bool, moving: bool,
                cancel: Callable[[], bool] | None = None, level: int = 0) -> dict[str, np.ndarray]:
        """Frame ``n`` of the accumulation of state ``s`` (module docstring for the seeds), with the final gather
        or not, of a moving camera or not; while a background job trains, with the cores it leaves. ``cancel`` and
        ``level``: as :meth:`FieldInUse.render`'s."""
        from photon_fields.runtime.threads import max_threads

        threads = max(1, max_threads() - self.updater.settings.threads) if self.updater.busy else None
        return self.field.render(scene, s.renderer, seed=self.seed, n=n, lights=s.lights, threads=threads,
                                 final_gather=gather, moving=moving, cancel=cancel, level=level,
                                 camera=s.camera_estimator)

    def gathers(self, renderer: str, n: int) -> bool:
        """Whether resting frame ``n`` of an accumulation with ``renderer`` takes the final gather (moving frames
        never do)."""
        return renderer == "neural" and self.gather_after is not None and n >= self.gather_after

    # ------------------------------------------------------------------------------------------------
    # state for the page, screenshots (either thread)

    def describe(self) -> dict[str, Any]:
        """The state the page builds its controls from (sent when it connects; :func:`state_message`)."""
        with self.lock:
            return state_message(self)

    def histogram(self) -> list[float]:
        """The volume's histogram for the page's transfer-function editor (computed once)."""
        if self._histogram is None:
            self._histogram = volume_histogram(self.base_scene.volume)
        return self._histogram

    def screenshot(self, name: str | None = None) -> list[Path]:
        """Write the current accumulation as a screenshot (:func:`photon_fields.runtime.viewer.screenshot.write`):
        ``NAME.exr`` (all layers, linear), ``NAME.png`` (the shown layer at the shown exposure, undenoised) and
        ``NAME.json`` (the view, renderer, lights, spp, seed) in the output folder; a free ``SCENE_0001`` style
        name when ``name`` is None."""
        with self._shot_lock:
            with self.lock:
                if self._acc.empty:
                    raise MessageError("screenshot: no frame has been rendered yet")
                samples, gathered = self._acc.samples, self._acc.gathered
                layers = self._acc.means()
                s = replace(self.state)
                header = dict(self._last_header)
                cam = s.view.camera(*self._acc_size)
            stem = name if name is not None else screenshot.free_stem(self.out_dir, self.base_scene.name)
            report = {"scene": self.base_scene.name, "renderer": s.renderer, "layer": s.layer, "g": s.g,
                      "spp": samples, "seed": self.seed, "exposure_stops": header.get("exposure"),
                      "camera": cam.to_dict(), "lights": [lt.light().to_dict() for lt in s.lights],
                      "transfer_function": (s.transfer or self.base_scene.tf).to_dict(),
                      "stale_indirect": self.field.stale_for(s.renderer, s.transfer, s.lights),
                      "final_gather_samples": gathered, "level": header.get("level", 0),
                      **self.field.estimator_report(s.camera_estimator, s.renderer),
                      "frame_timings_ms": {k: v for k, v in header.items() if k.endswith("_ms")}, **self.info}
            return screenshot.write(self.out_dir, stem, layers, report, png_layer=s.layer,
                                    exposure=header.get("exposure"))

