"""The field and photon map a viewer session renders L_i with, and the scene they were made for.

A field (or map) answers L_i for the transfer function and lights it was trained (traced) for. The page edits
both; :class:`FieldInUse` says what follows from an edit:

- a light's power or colour (a single light's, or all lights' by one factor; or any light's among several when the
  field keeps the lights apart, ``light_channels``, or the map records each photon's light): L_i is rescaled
  exactly (radiance is linear in a light's flux, :mod:`photon_fields.runtime.scene.light_rescale`), no retraining;
- anything else (another transfer function, a moved light, one light's power edit among several for a field of one
  output): L_i is *stale*.
  Frames say so, and the session's :class:`photon_fields.runtime.viewer.updater.FieldUpdater` retrains in the
  background; :meth:`FieldInUse.from_job` loads the result, which the session swaps in.

A PVRT transfer (:class:`photon_fields.runtime.viewer.pvrt_view.PvrtView`, ``pfn-view --transfer``) is another
source of L_i: it follows every edit of a distant light exactly (relighting is what it is for) and cannot follow
another transfer function or g at all, so those are refused while it renders (:meth:`FieldInUse.check`) rather
than shown stale. The path tracer, the preview (the ray marcher: single scattering, no L_i at all) and PVRT are
:data:`FOLLOWS_EDITS`: their frames are never stale.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.renderers.registry import CAMERA_OPTION, LIGHT_OPTION
from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.light_rescale import lights_rescale
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.viewer.light_control import LightControl
from photon_fields.runtime.viewer.messages import RENDERER_NAMES, MessageError
from photon_fields.runtime.viewer.pvrt_view import PvrtView
from photon_fields.runtime.viewer.retrain import RetrainJob
from photon_fields.runtime.viewer.transfer_edit import shows_something
from photon_fields.runtime.viewer.updater import FieldUpdater, same_transfer

#: Renderers (page names) whose L_i is computed for the scene as edited, so their frames are never stale.
FOLLOWS_EDITS = ("pt", "preview", "pvrt")


def progressive(renderer: str) -> bool:
    """Whether ``renderer``'s (a page name) frames are noisy samples to accumulate and denoise, or one
    deterministic image per view (the renderer table's ``progressive``)."""
    from photon_fields.runtime.renderers.registry import RENDERERS

    return RENDERERS[RENDERER_NAMES[renderer]].progressive


#: Frames a resting view of a renderer without noise (the preview) averages: its jittered marches differ only by
#: where each pixel's samples fall along its ray, which 16 of them average away.
PREVIEW_FRAMES = 16


def resting_frames(renderer: str, max_spp: int) -> int:
    """The frames (samples per pixel) a resting view of ``renderer`` (a page name) accumulates: ``max_spp`` of a
    noisy renderer, at most :data:`PREVIEW_FRAMES` of the preview's marches, 1 of a deterministic renderer."""
    if not progressive(renderer):
        return 1
    return max_spp if noisy(renderer) else min(max_spp, PREVIEW_FRAMES)


def renderers_with_inputs(estimator: Any, pmap: Any, pvrt: Any) -> dict[str, bool]:
    """Per renderer (a page name), whether its input is there: a field's estimator (the neural renderer and the
    preview with the field's L_i, "marched"), a photon map, a PVRT transfer; the path tracer and the preview need
    none."""
    return {"neural": estimator is not None, "pt": True, "preview": True, "marched": estimator is not None,
            "photonmap": pmap is not None, "pvrt": pvrt is not None}


def noisy(renderer: str) -> bool:
    """Whether ``renderer``'s (a page name) frames carry Monte Carlo noise for a denoiser (the renderer table's
    ``noisy``: not the preview's jittered march, not PVRT's)."""
    from photon_fields.runtime.renderers.registry import RENDERERS

    return RENDERERS[RENDERER_NAMES[renderer]].noisy


class FieldInUse:
    """``estimator``: a photon field's estimator (the neural renderer) or None; ``pmap``: a photon map (the
    photon-map renderer) or None; ``scene``: what both were made for (its transfer function and lights); ``pvrt``:
    a PVRT transfer's view (the pvrt renderer) or None, which a retrained field does not replace."""

    def __init__(self, scene: Scene, estimator: Any = None, pmap: Any = None, run_dir: Path | None = None,
                 pvrt: PvrtView | None = None) -> None:
        self.estimator, self.pmap, self.pvrt = estimator, pmap, pvrt
        self.run_dir = run_dir  # the field's run folder, when it has one: retraining then fine-tunes it
        self.tf: TransferFunction | LabelTransfer = scene.tf
        self.lights = [LightControl.from_light(lt) for lt in scene.lights]
        self._rescaled_map: tuple[bytes, Any] | None = None  # (the factors, the map rescaled by them)
        self.camera_used: str | None = None  # the camera estimator of the last neural frame ("auto" resolved)

    @classmethod
    def from_job(cls, job: RetrainJob, threads: int | None = None) -> FieldInUse:
        """The field and map a finished retrain wrote (each checked against the scene it was trained for; an
        :class:`photon_fields.runtime.errors.InputError` if either does not load)."""
        from photon_fields.runtime.field.field import PhotonField
        from photon_fields.runtime.photons.photon_map import PhotonMap

        scene = job.scene
        field = PhotonField.load(job.bundle, threads=threads, precision="fp32",
                                 expected_fingerprint=scene.fingerprint(), expected_parts=scene.fingerprint_parts())
        pmap = PhotonMap.load(job.photon_map, expected_fingerprint=scene.fingerprint(),
                              expected_parts=scene.fingerprint_parts())
        return cls(scene, field.estimator(), pmap, job.run_dir)

    @staticmethod
    def run_folder_of(bundle: str | Path | None) -> Path | None:
        """The run folder a bundle was exported into (``pfn-train all`` writes ``RUN/field.pfn`` beside the
        checkpoint and the log ``update`` starts from), or None."""
        if bundle is None:
            return None
        run = Path(bundle).resolve().parent
        return run if (run / "checkpoint.pt").is_file() and (run / "log.json").is_file() else None

    @property
    def exists(self) -> bool:
        return self.estimator is not None or self.pmap is not None

    def has(self, renderer: str) -> bool:
        """Whether ``renderer`` (a page name) has its input here (:func:`renderers_with_inputs`)."""
        return renderers_with_inputs(self.estimator, self.pmap, self.pvrt)[renderer]

    @property
    def available(self) -> list[str]:
        return [name for name in RENDERER_NAMES if self.has(name)]

    def check(self, renderer: str, g: float, transfer: TransferFunction | LabelTransfer | None) -> None:
        """Refuse (:class:`MessageError`, one line) rendering ``renderer`` at phase ``g`` with the transfer function
        ``transfer`` (None: the scene's) where its input cannot answer them: a photon map's g outside its phases, a
        PVRT transfer's other g or transfer function."""
        if renderer == "photonmap":
            from photon_fields.runtime.errors import InputError
            from photon_fields.runtime.photons.phase_window import answerable, map_window

            try:
                answerable(self.pmap.phases, g, map_window(self.pmap.phases), "g")
            except InputError as err:
                raise MessageError(f"the photon map cannot render this g: {err}") from None
        elif renderer == "pvrt" and self.pvrt is not None:
            self.pvrt.check(g, transfer)

    def render(self, scene: Scene, renderer: str, *, seed: int, n: int, lights: list[LightControl],
               threads: int | None = None, final_gather: bool = False, moving: bool = False,
               cancel: Callable[[], bool] | None = None, level: int = 0,
               camera: str | None = None) -> dict[str, np.ndarray]:
        """Frame ``n`` of a session's accumulation with ``renderer``: 1 sample per pixel; the neural renderer draws
        samples ``first_sample = n`` of ``seed``, the others use seed ``seed + n``. L_i follows the page's
        ``lights`` where it can (:meth:`indirect_scale`; L_d, from NEE with the edited lights, is right anyway).
        ``threads``: numba workers (None: as set). ``final_gather``: the neural renderer takes one real bounce
        before the field (:mod:`photon_fields.runtime.wavefront.final_gather`); its NEE at the bounce already sees
        the edited lights, so the field's part alone is rescaled, inside the estimator. ``moving``: the camera
        is moving (PVRT keeps no samples of a moving view, :class:`PvrtView`). ``cancel``: the neural renderer and
        the preview work in batches of :data:`photon_fields.runtime.wavefront.batches.CANCELLABLE_BATCH` and ask it
        before each, the preview also during its light volume's fill (True:
        :class:`photon_fields.runtime.wavefront.batches.RenderCancelledError`, the frame is given up).
        ``level``: the preview marches that level of the volume (:mod:`photon_fields.runtime.scene.levels`).
        ``camera``: the neural renderer's camera estimator (None: its default; ``pfn-view --camera-estimator``); with
        "auto", the first frame of an accumulation renders forced unless the scene's choice is made (an edit's first
        frame does not wait for the probe), and the frames after it what auto chooses (both estimate the same
        image)."""
        from photon_fields.runtime.threads import numba_threads

        if renderer == "pvrt":  # L_i from the transfer under the edited lights: nothing to rescale
            with numba_threads(threads):
                return self.pvrt.render(scene, seed=seed, moving=moving)
        scale = self.indirect_scale(lights, renderer)
        scale = None if scale is None or np.all(scale == 1.0) else scale.astype(np.float32)
        with numba_threads(threads):
            if renderer == "neural":
                from photon_fields.runtime.renderers.neural import render_neural
                from photon_fields.runtime.wavefront.batches import CANCELLABLE_BATCH, DEFAULT_BATCH
                from photon_fields.runtime.wavefront.camera_choice import AUTO, made_choice

                est = self.scaled_estimator(scale)
                camera = camera or CAMERA_OPTION.default
                if camera == AUTO and n == 0 and made_choice(scene, est, LIGHT_OPTION.default) is None:
                    camera = "forced"  # a scene's first frame does not wait for auto's probe; the next one probes
                result = render_neural(scene, est, spp=1, seed=seed, progress=False, first_sample=n,
                                       final_gather_after=0 if final_gather else None, cancel=cancel,
                                       batch_size=DEFAULT_BATCH if cancel is None else CANCELLABLE_BATCH,
                                       camera=camera)
                self.camera_used = str(result.stats["camera_estimator"])
                return result.layers
            if renderer == "pt":
                from photon_fields.runtime.renderers.path_tracer import render_path_traced

                return render_path_traced(scene, spp=1, seed=seed + n, progress=False).layers
            if renderer in ("preview", "marched"):  # the light volume is kept with the scene: camera moves reuse it
                from photon_fields.runtime.renderers.ray_marcher import MARCH_BATCH, render_ray_marched
                from photon_fields.runtime.wavefront.batches import CANCELLABLE_BATCH

                return render_ray_marched(scene, spp=1, seed=seed + n, progress=False, level=level, cancel=cancel,
                                          batch_size=MARCH_BATCH if cancel is None else CANCELLABLE_BATCH,
                                          estimator=self.scaled_estimator(scale) if renderer == "marched" else None
                                          ).layers
            from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped

            pmap = self.pmap
            if scale is not None and scale.ndim == 2:  # one factor per light: the map's powers, per photon
                pmap, scale = self.map_rescaled(scale, scene), None
            # force: after an edit the map is stale, which the frame's warnings say (stale)
            layers = render_photon_mapped(scene, pmap, spp=1, seed=seed + n, progress=False, force=True,
                                          final_gather_after=None).layers
        if scale is None:
            return layers
        li = (layers["L_i"] * scale).astype(np.float32)
        return {**layers, "L_i": li, "L": (layers["L_e"] + layers["L_d"]) + li}

    def estimator_report(self, camera: str, renderer: str) -> dict[str, str | None]:
        """What frame headers and screenshots record of the camera estimator: the one set (``camera``, e.g. "auto")
        and, for the neural renderer, the one its last frame used."""
        return {"camera_estimator": camera, "camera_estimator_used": self.camera_used if renderer == "neural" else None}

    def scaled_estimator(self, scale: np.ndarray | None) -> Any:
        """The field's estimator with L_i following the page's lights (``scale`` from :meth:`indirect_scale`, None:
        as trained)."""
        if scale is None:
            return self.estimator
        if scale.ndim == 2:  # one factor per light: the field sums its lights' parts with them
            return self.estimator.field.estimator(scale)
        return _Scaled(self.estimator, scale)

    def kept_apart(self, renderer: str | None = None) -> int:
        """How many lights the L_i of ``renderer`` (a page name; None: the field's, else the map's) keeps apart: a
        field's ``light_channels``, a map's lights when it records each photon's, else 1."""
        if renderer == "photonmap" or (renderer is None and self.estimator is None):
            return self.pmap.light_count if self.pmap is not None else 1
        return int(getattr(getattr(self.estimator, "field", None), "light_channels", 1))

    def indirect_scale(self, lights: list[LightControl], renderer: str | None = None) -> np.ndarray | None:
        """How L_i of ``renderer`` (:meth:`kept_apart`), made for the trained lights, follows the page's ``lights``
        (exact, :mod:`photon_fields.runtime.scene.light_rescale`; ones without edits): when every light keeps its
        kind and place, the RGB factor (3,) of a common change of their fluxes (a single light's power or colour, or
        all lights' alike), or for an L_i that keeps the lights apart one factor per light (L, 3); None otherwise
        (stale)."""
        return lights_rescale([_flux_dict(c) for c in self.lights], [_flux_dict(c) for c in lights],
                              self.kept_apart(renderer))

    def map_rescaled(self, scale: np.ndarray, scene: Scene) -> Any:
        """The photon map with each light's records times its factor (``scale`` (L, 3)), kept for the next frame."""
        key = np.asarray(scale, np.float32).tobytes()
        if self._rescaled_map is None or self._rescaled_map[0] != key:
            self._rescaled_map = (key, self.pmap.rescaled(scale, scene))
        return self._rescaled_map[1]

    def stale(self, transfer: TransferFunction | LabelTransfer | None, lights: list[LightControl],
              renderer: str | None = None) -> bool:
        """Whether L_i (of ``renderer``, :meth:`kept_apart`) is not the edited scene's: another transfer function,
        or a light edit :meth:`indirect_scale` cannot follow."""
        return not same_transfer(transfer, self.tf) or self.indirect_scale(lights, renderer) is None

    def stale_for(self, renderer: str, transfer: TransferFunction | LabelTransfer | None,
                  lights: list[LightControl]) -> bool:
        """Whether a frame of ``renderer`` shows a stale L_i (:meth:`stale`; never for :data:`FOLLOWS_EDITS`)."""
        return renderer not in FOLLOWS_EDITS and self.stale(transfer, lights, renderer)

    def warnings(self, renderer: str, transfer: TransferFunction | LabelTransfer | None, lights: list[LightControl],
                 updater: FieldUpdater) -> list[str]:
        """What a frame of ``renderer`` tells the page about its L_i (nothing when it is right)."""
        if not self.stale_for(renderer, transfer, lights):
            return []
        what = "field was trained" if renderer == "neural" else "photon map was traced"
        if not same_transfer(transfer, self.tf):
            warning = (f"stale L_i: the {what} for another transfer function (L_d and the path tracer follow the "
                       "edit at once)")
        else:
            apart = "" if self.kept_apart(renderer) > 1 or len(lights) == 1 else " by a field with the lights apart"
            warning = (f"stale L_i: the {what} for the scene's lights: L_i does not follow this light edit (L_d "
                       f"does; a light's power or colour alone would be followed exactly{apart})")
        if updater.busy:
            return [warning + "; retraining in the background"]
        if not shows_something(transfer):
            return [f"{warning}; every label is hidden (show one to retrain)"]
        return [f"{warning}; {'press retrain' if updater.available else updater.reason}"]


def _flux_dict(c: LightControl) -> dict[str, Any]:
    """A light control as :func:`photon_fields.runtime.scene.light_rescale.lights_rescale` compares lights: where it is
    (the controls themselves, so that the page's round trip through angles compares equal) and its flux."""
    return {"kind": c.kind, "azimuth": c.azimuth, "elevation": c.elevation, "distance": c.distance, "yaw": c.yaw,
            "image": None if c.source is None else c.source.sha256, "color": np.asarray(c.color).tolist(),
            "power": c.power}


class _Scaled:
    """An indirect-light estimator's output times the RGB ``scale`` (3,) (a light power or colour edit,
    :meth:`FieldInUse.render`)."""

    def __init__(self, inner: Any, scale: np.ndarray) -> None:
        self.inner, self.scale = inner, np.asarray(scale, dtype=np.float32).reshape(3, 1)

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        return self.scale * self.inner(x, d, g)
