"""The page's ``set`` message: the view controls it sets on a :class:`ViewState` and what each change then
requires of the session (restart the accumulation, cut the denoiser's history, redisplay, measure the exposure
again)."""

from __future__ import annotations

from typing import Any

from photon_fields.runtime.viewer.field_in_use import FieldInUse
from photon_fields.runtime.viewer.messages import MessageError
from photon_fields.runtime.viewer.view_state import ViewState

#: ``set`` controls that only set the :class:`ViewState` field of their name, and what each then does:
#: (restart the accumulation, cut the denoiser's history, redisplay, measure the exposure again).
_FIELD_CONTROLS: dict[str, tuple[bool, bool, bool, bool]] = {
    "layer": (False, True, True, True),
    "format": (False, False, True, False),
    "denoise": (False, True, True, False),
    "max_spp": (False, False, True, False),
    "drag_scale": (False, False, False, False),
    "camera_estimator": (True, True, True, False),  # another estimator of the same image: its samples anew
}


def apply_set(s: ViewState, field: FieldInUse, control: str, value: Any) -> tuple[bool, bool, bool, bool]:
    """Set ``control`` to ``value`` on ``s`` (a :class:`MessageError` if ``field`` cannot render the result).
    Returns (restart the accumulation, cut the denoiser, redisplay, measure the exposure again). The exposure is
    measured again when what is shown changes kind (renderer, layer), not when g moves: the page should show g's
    effect, not have it normalized away."""
    if control == "renderer":
        if not field.has(value):
            raise MessageError(f"renderer '{value}' is not available here (neural and marched need --bundle, "
                               f"photonmap --map, pvrt --transfer); available: {', '.join(field.available)}")
        field.check(value, s.g, s.transfer)
        s.renderer = value
        return True, True, True, True
    if control == "g":
        field.check(s.renderer, value, s.transfer)
        s.g = value
        return True, True, True, False
    if control == "exposure":
        if value is None:
            s.exposure_offset = 0.0
            return False, False, True, True
        s.exposure_offset = value
        return False, False, True, False
    if control in _FIELD_CONTROLS:
        setattr(s, control, value)
        return _FIELD_CONTROLS[control]
    raise MessageError(f"set: control {control!r} is not handled")
