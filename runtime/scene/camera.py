"""Look-at pinhole camera.

Parameters
----------
eye, target, up : 3-vectors
    Camera position, the point it looks at, and the approximate up direction (must not be parallel
    to ``target - eye``).
fov : float in (0, 180)
    Field of view in degrees, measured along ``fov_axis``.
fov_axis : "y" | "x"
    Whether ``fov`` is the vertical or the horizontal field of view.
width, height : int >= 1
    Resolution in pixels.

Pixel ``(px, py)`` with ``py = 0`` at the top of the image; a sample at sub-pixel offset ``(u, v)`` in
[0, 1)^2 shoots through image-plane point ``(px + u, py + v)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.scene.lights import as_vec3


@dataclass(frozen=True, eq=False)
class Camera:
    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov: float = 40.0
    width: int = 256
    height: int = 256
    fov_axis: str = "y"

    def __post_init__(self) -> None:
        eye = as_vec3(self.eye, "camera eye")
        target = as_vec3(self.target, "camera target")
        up = as_vec3(self.up, "camera up")
        fwd = target - eye
        if np.linalg.norm(fwd) < 1e-12:
            raise InputError("camera", "eye and target are the same point")
        if np.linalg.norm(up) < 1e-12:
            raise InputError("camera up", "must not be the zero vector")
        fwd = fwd / np.linalg.norm(fwd)
        if np.linalg.norm(np.cross(fwd, up / np.linalg.norm(up))) < 1e-6:
            raise InputError("camera up", "is parallel to the view direction (target - eye)")
        try:
            fov = float(self.fov)
        except (TypeError, ValueError):
            raise InputError("camera fov", f"must be a number of degrees, got {self.fov!r}") from None
        if not (0.0 < fov < 180.0):
            raise InputError("camera fov", f"must be in (0, 180) degrees, got {self.fov}")
        if self.fov_axis not in ("x", "y"):
            raise InputError("camera fov_axis", f"must be 'x' or 'y', got {self.fov_axis!r}")
        for label, v in (("width", self.width), ("height", self.height)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1 or v > 16384:
                raise InputError(f"camera {label}", f"must be an integer in [1, 16384], got {v!r}")
        object.__setattr__(self, "eye", eye)
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "up", up)
        object.__setattr__(self, "fov", fov)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Orthonormal (right, true_up, forward)."""
        fwd = self.target - self.eye
        fwd = fwd / np.linalg.norm(fwd)
        right = np.cross(fwd, self.up)
        right /= np.linalg.norm(right)
        true_up = np.cross(right, fwd)
        return right, true_up, fwd

    def image_plane(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(origin, du, dv) in world space at unit distance: ray dir for pixel coords (x, y) is
        ``origin + x * du + y * dv`` (before normalization); x, y in pixel units, y down."""
        right, up, fwd = self.basis()
        aspect = self.width / self.height
        half = math.tan(math.radians(self.fov) * 0.5)
        half_h, half_w = (half, half * aspect) if self.fov_axis == "y" else (half / aspect, half)
        du = right * (2.0 * half_w / self.width)
        dv = -up * (2.0 * half_h / self.height)
        origin = fwd - right * half_w + up * half_h
        return origin, du, dv

    def with_resolution(self, width: int, height: int) -> Camera:
        return replace(self, width=width, height=height)

    def to_dict(self) -> dict[str, Any]:
        return {"eye": self.eye.tolist(), "target": self.target.tolist(), "up": self.up.tolist(), "fov": self.fov,
                "fov_axis": self.fov_axis, "width": self.width, "height": self.height}

    @classmethod
    def from_dict(cls, d: Any, what: str = "camera") -> Camera:
        if not isinstance(d, dict):
            raise InputError(what, "must be a JSON object")
        # Unknown keys first: a misspelt "eye" should be named as a typo, not as a missing key.
        check_keys(d, ("eye", "target", "up", "fov", "fov_axis", "width", "height"), what)
        for key in ("eye", "target"):
            if key not in d:
                raise InputError(what, f"missing '{key}'")
        try:
            return cls(d["eye"], d["target"], d.get("up", [0.0, 1.0, 0.0]), d.get("fov", 40.0),
                       d.get("width", 256), d.get("height", 256), d.get("fov_axis", "y"))
        except InputError as err:
            # The constructor labels errors "camera fov", "camera up", ... without the scene file: replace the
            # leading "camera" by ``what`` ("scene.json camera fov") so the error names where it came from.
            field = err.what[len("camera"):] if err.what.startswith("camera") else f" {err.what}"
            raise InputError(f"{what}{field}", err.problem) from None


def orbit_camera(base: Camera, angle_deg: float) -> Camera:
    """``base`` rotated by ``angle_deg`` about the vertical axis (up) through its target."""
    a = math.radians(angle_deg)
    k = base.up / np.linalg.norm(base.up)
    v = base.eye - base.target
    # Rodrigues' rotation of v about k.
    v_rot = v * math.cos(a) + np.cross(k, v) * math.sin(a) + k * np.dot(k, v) * (1 - math.cos(a))
    return replace(base, eye=base.target + v_rot)
