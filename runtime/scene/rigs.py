"""Named light rigs and a camera that frames a volume: what a scene needs besides its volume and transfer
function, chosen by name so that rendering a volume takes no scene file (``photon_fields.render``).

The rigs are written like the embedded scenes' lights (:data:`photon_fields.runtime.scene.scene.BUILTIN_SCENES`):
light dicts in the scene-file form, read by :func:`photon_fields.runtime.scene.lights.light_from_dict`. All light
the volume from the camera's side (the default camera looks from +x, +y, +z towards the origin), so that the
lit faces are the ones seen.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.scene.lights import Light, light_from_dict
from photon_fields.runtime.scene.volume import Volume

_WARM = [1.0, 0.95, 0.85]
_COOL = [0.6, 0.75, 1.0]

#: name -> lights in the scene-file form.
LIGHT_RIGS: dict[str, list[dict[str, Any]]] = {
    # A warm key light from above and a weak cool fill from the side (the head scene's lights).
    "studio": [{"type": "directional", "direction": [-0.6, -0.7, -0.4], "color": _WARM, "power": 4.0},
               {"type": "point", "position": [-0.9, 0.4, 0.9], "color": _COOL, "power": 0.5}],
    # One warm directional light (the vortex scene's).
    "sun": [{"type": "directional", "direction": [-0.6, -0.7, -0.4], "color": _WARM, "power": 4.0}],
    # A sun and a faint blue sky all around: softer shadows, nothing fully dark.
    "sky": [{"type": "directional", "direction": [-0.5, -0.8, -0.3], "color": _WARM, "power": 3.0},
            {"type": "environment", "color": _COOL, "power": 0.15}],
}

#: Direction from the target to the default camera (the embedded scenes' view) and its field of view.
VIEW_DIRECTION = (1.25, 0.75, 1.45)
FOV = 38.0
#: Distance beyond the tightest fit of the volume's bounding sphere (a margin around the volume).
MARGIN = 1.05


def light_rig(name: str, what: str = "lights") -> tuple[Light, ...]:
    """The lights of rig ``name`` (:data:`LIGHT_RIGS`)."""
    if name not in LIGHT_RIGS:
        raise InputError(what, f"unknown light rig {name!r} (available: {', '.join(LIGHT_RIGS)})")
    return tuple(light_from_dict(d, f"{what} {name}") for d in LIGHT_RIGS[name])


def framing_camera(volume: Volume, width: int = 256, height: int = 256) -> Camera:
    """A camera looking at the centre of ``volume``'s box from :data:`VIEW_DIRECTION`, at the distance where the
    box's bounding sphere fits the field of view (:data:`FOV` along the narrower image side; with
    :data:`MARGIN`), whatever the box's and the image's aspect ratios."""
    radius = 0.5 * float(np.linalg.norm(volume.extent))
    distance = MARGIN * radius / math.sin(math.radians(FOV / 2))
    direction = np.asarray(VIEW_DIRECTION) / np.linalg.norm(VIEW_DIRECTION)
    return Camera.from_dict({"eye": (direction * distance).tolist(), "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0],
                             "fov": FOV, "fov_axis": "y" if width >= height else "x", "width": width,
                             "height": height})
