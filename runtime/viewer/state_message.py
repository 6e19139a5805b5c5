"""The ``state`` message: what the page builds its controls from when it connects (docs/viewer.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from photon_fields.runtime.viewer.messages import MAX_PIXELS, MAX_SIDE, MIN_SIDE
from photon_fields.runtime.viewer.transfer_edit import transfer_message

if TYPE_CHECKING:
    from photon_fields.runtime.viewer.session import ViewerSession


def state_message(session: ViewerSession) -> dict[str, Any]:
    """The session's state for the page (call with ``session.lock`` held): scene, renderers, view controls,
    lights, the transfer-function editor's input and the background retrain's status."""
    s = session.state
    return {"type": "state", "scene": session.base_scene.name, "renderers": session.available,
            "renderer": s.renderer, "layer": s.layer, "g": s.g, "exposure_offset": s.exposure_offset,
            "format": s.format, "denoise": s.denoise, "max_spp": s.max_spp, "width": s.width,
            "height": s.height, "max_size": list(session.max_size),
            "view_limits": {"min_side": MIN_SIDE, "max_side": MAX_SIDE, "max_pixels": MAX_PIXELS},
            "drag_scale": s.drag_scale, "camera_estimator": s.camera_estimator,
            "lights": [lt.to_dict() for lt in s.lights],
            "out_dir": str(session.out_dir),
            # a PVRT transfer renders the g it was precomputed for only: the page fixes its g slider
            "pvrt": {"g": session.field.pvrt.g} if session.field.pvrt else None,
            # the editor the page shows: control points over the histogram, or a label scene's panel
            "transfer": None if s.labels else transfer_message(s.transfer or session.base_scene.tf),
            "histogram": None if s.labels else session.histogram(),
            "labels": s.labels.message() if s.labels else None,
            "retrain": {"available": session.updater.available, "why": session.updater.reason,
                        "auto": session.updater.settings.auto, "status": session.updater.status()}}
