"""PVRT frames in the viewer (``pfn-view SCENE --transfer NAME.pvrt``): the transfer and one view's kept samples.

A PVRT frame is a deterministic march of the camera rays through the medium, summing the radiance volume the
lighting gives (:mod:`photon_fields.runtime.renderers.pvrt`). Its camera samples depend on the medium, the camera
and g only, so while the camera rests a light change needs no march: :class:`PvrtView` keeps a
:class:`photon_fields.runtime.renderers.pvrt.Relighting` of the resting view and relights it. A moving frame is
one plain :func:`photon_fields.runtime.renderers.pvrt.render_pvrt` (one march; keeping samples costs two, and the
next frame has another camera anyway); the resting frame of a view keeps its samples (the session renders one
after a moving frame of a deterministic renderer, :class:`photon_fields.runtime.viewer.session.ViewerSession`).

The transfer answers one medium and one g only (:meth:`photon_fields.runtime.pvrt.transfer.Transfer.check_scene`):
:meth:`PvrtView.check` refuses, as one message line, a g or a transfer-function edit it cannot render.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from photon_fields.runtime.pvrt.constants import DEFAULT_LIGHT_GRID
from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.viewer.messages import MessageError
from photon_fields.runtime.viewer.updater import same_transfer

#: ``pfn-view --light-grid``'s range (``pfn-render --method pvrt``'s).
LIGHT_GRID_RANGE = (4, 512)


@dataclass(frozen=True)
class PvrtOptions:
    """How the viewer makes PVRT frames (``pfn-view --direct``, ``--light-grid``; as ``pfn-render --method pvrt``)."""

    direct: str = "nee"  #: directional lights' direct term: "nee" (a light volume, sharp shadows) or "transfer"
    light_grid: int = DEFAULT_LIGHT_GRID  #: "nee": light-volume cells along the box's longest side


class PvrtView:
    """A session's PVRT transfer and the kept samples of its resting view (module docstring). Used by the render
    thread only; :attr:`last` says how the last frame was made (relit from kept samples or marched)."""

    def __init__(self, transfer: Any, tf: TransferFunction | LabelTransfer, options: PvrtOptions | None = None) -> None:
        self.transfer, self.tf = transfer, tf  # tf: the scene's transfer function, which the transfer was made for
        self.options = options or PvrtOptions()
        self._relighting: Any = None  # Relighting of the resting view, or None
        self.last: dict[str, Any] = {}  # how the last frame was made, for its header

    @property
    def g(self) -> float:
        """The phase g the transfer's photons scattered with: the only g it renders."""
        return self.transfer.g

    def check(self, g: float, tf: TransferFunction | LabelTransfer | None) -> None:
        """Refuse (:class:`MessageError`, one line) a state the transfer cannot render: another g, or a transfer
        function ``tf`` (None: the scene's) edited away from the one it was precomputed for."""
        if abs(g - self.g) > 1e-6:
            raise MessageError(f"pvrt: the transfer was precomputed for g = {self.g:g}, not {g:g} (its photons "
                               "scattered with that g): set g back, or precompute a transfer for this g")
        if tf is not None and not same_transfer(tf, self.tf):
            raise MessageError("pvrt: the transfer was precomputed for the scene's transfer function, not an edited "
                               "one: undo the edit, or render it with another renderer")

    def render(self, scene: Scene, *, seed: int, moving: bool) -> dict[str, np.ndarray]:
        """The layers of ``scene``'s frame (its lights, camera and g): marched when ``moving`` or when the view is
        not the kept one, else relit from the kept samples."""
        from photon_fields.runtime.renderers.pvrt import Relighting, render_pvrt

        if scene.tf is not self.tf:  # an edit undone (check() passed it): the scene's medium, named otherwise
            # (a label panel's function names every label present, the scene's only some: another fingerprint, which
            # the transfer's scene check would refuse); rendered as the scene's function, on the same medium
            scene = replace(scene, tf=self.tf, _cache={"medium": scene.medium()})
        kept = self._relighting
        if moving:
            self._relighting = None  # the view is on its way elsewhere: its samples would not be read again
            self.last = {"relit": False, "kept_samples": 0}
            return render_pvrt(scene, transfer=self.transfer, seed=seed, progress=False, direct=self.options.direct,
                               light_grid=self.options.light_grid).layers
        if kept is None or not _same_view(kept.scene, scene):
            kept = self._relighting = Relighting(scene, self.transfer, seed=seed, light_grid=self.options.light_grid)
            fresh = True
        else:
            fresh = False
        marched = fresh or not kept.kept  # a view with too many samples to keep marches every frame
        self.last = {"relit": not marched, "kept_samples": kept.samples}
        return kept.render(scene.lights, direct=self.options.direct).layers


def _same_view(a: Scene, b: Scene) -> bool:
    """Whether kept samples of ``a`` are those of ``b``: the same medium object (an edited transfer function builds
    another), camera and g."""
    return a.medium() is b.medium() and a.g == b.g and a.camera.to_dict() == b.camera.to_dict()
