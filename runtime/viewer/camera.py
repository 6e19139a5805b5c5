"""The viewer's camera: orbit, pan and zoom about a target, as a person drags in the page.

The view is kept as spherical coordinates of the eye about the target (yaw about the up axis, pitch above the
plane normal to it, distance), so that orbiting any amount in any order never rolls the camera and never
flips over the pole (pitch is held inside +-89 degrees). :meth:`OrbitView.camera` turns it back into the
scene's look-at :class:`photon_fields.runtime.scene.camera.Camera` at the frame's size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from photon_fields.runtime.scene.camera import Camera

MAX_PITCH = 89.0
#: The distance to the target stays within these factors of the scene camera's (zoom cannot pass through the
#: target or lose the volume at infinity).
MIN_ZOOM, MAX_ZOOM = 0.05, 50.0


@dataclass(frozen=True)
class OrbitView:
    """Eye at ``target + distance * (cos(pitch) (cos(yaw) e1 + sin(yaw) e2) + sin(pitch) up)``."""

    target: np.ndarray
    up: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    yaw: float
    pitch: float
    distance: float
    base_distance: float
    fov: float
    fov_axis: str = "y"
    base_aspect: float = 1.0
    """Width over height of the scene camera's frame: the rectangle every frame of the view contains."""

    @classmethod
    def from_camera(cls, cam: Camera) -> OrbitView:
        """The orbit view that reproduces ``cam`` (up to roll: the orbit's up is ``cam.up``)."""
        up = cam.up / np.linalg.norm(cam.up)
        v = cam.eye - cam.target
        dist = float(np.linalg.norm(v))
        # e1: the eye's direction projected on the plane normal to up (any vector there if the eye is on the axis).
        flat = v - up * float(np.dot(v, up))
        if np.linalg.norm(flat) < 1e-9 * dist:
            flat = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 0.0, 1.0])
        e1 = flat / np.linalg.norm(flat)
        e2 = np.cross(up, e1)
        pitch = math.degrees(math.asin(max(-1.0, min(1.0, float(np.dot(v, up)) / dist))))
        return cls(cam.target.copy(), up, e1, e2, 0.0, max(-MAX_PITCH, min(MAX_PITCH, pitch)), dist, dist,
                   cam.fov, cam.fov_axis, cam.width / cam.height)

    def eye(self) -> np.ndarray:
        y, p = math.radians(self.yaw), math.radians(self.pitch)
        d = math.cos(p) * (math.cos(y) * self.e1 + math.sin(y) * self.e2) + math.sin(p) * self.up
        return self.target + self.distance * d

    def camera(self, width: int, height: int) -> Camera:
        """The look-at camera of this view at ``width`` x ``height`` pixels. Its frame contains the scene camera's
        (same centre, :attr:`base_aspect`) and is as small as that allows: at the scene's aspect it is the scene's
        field of view exactly, and a frame of another shape widens the field of view along one axis instead of
        cutting the scene's view off (a tall, narrow window shows the whole volume, narrower)."""
        fov, axis = self._fov_for(width / height)
        return Camera(self.eye(), self.target, self.up, fov, width, height, axis)

    def _fov_for(self, aspect: float) -> tuple[float, str]:
        """(field of view in degrees, its axis) of a frame of ``aspect`` (:meth:`camera`)."""
        half = math.tan(math.radians(self.fov) / 2.0)
        a0 = self.base_aspect
        half_h0, half_w0 = (half, half * a0) if self.fov_axis == "y" else (half / a0, half)
        if self.fov_axis == "y" and half_w0 <= half_h0 * aspect:  # as wide as the scene's frame, or wider
            return self.fov, "y"
        if self.fov_axis == "x" and half_h0 * aspect <= half_w0:  # as tall as the scene's frame, or taller
            return self.fov, "x"
        return math.degrees(2.0 * math.atan(max(half_h0, half_w0 / aspect))), "y"

    def orbit(self, dx_deg: float, dy_deg: float) -> OrbitView:
        """Turned by ``dx_deg`` about the up axis and ``dy_deg`` up (pitch clamped to +-:data:`MAX_PITCH`)."""
        yaw = math.remainder(self.yaw + dx_deg, 360.0)
        pitch = max(-MAX_PITCH, min(MAX_PITCH, self.pitch + dy_deg))
        return replace(self, yaw=yaw, pitch=pitch)

    def zoom(self, factor: float) -> OrbitView:
        """The distance to the target times ``factor`` (kept within :data:`MIN_ZOOM`..:data:`MAX_ZOOM` of the
        scene camera's)."""
        d = min(max(self.distance * factor, MIN_ZOOM * self.base_distance), MAX_ZOOM * self.base_distance)
        return replace(self, distance=d)

    def pan(self, dx: float, dy: float, aspect: float | None = None) -> OrbitView:
        """Target (and eye) moved right by ``dx`` and up by ``dy`` view heights at the target's distance, for a
        frame of width / height ``aspect`` (default: the scene camera's)."""
        right, true_up, _ = self.camera(2, 2).basis()
        aspect = self.base_aspect if aspect is None else aspect
        fov, axis = self._fov_for(aspect)
        half = math.tan(math.radians(fov) / 2.0)
        height = 2.0 * self.distance * (half if axis == "y" else half / aspect)
        target = self.target + height * (dx * right + dy * true_up)
        return replace(self, target=target)
