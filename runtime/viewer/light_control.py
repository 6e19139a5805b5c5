"""A light as the viewer's page edits it (:class:`LightControl`): where it comes from, as azimuth and elevation
about the scene's vertical axis, and its power; converted from and to the scene's lights. :func:`edited_lights`
applies the page's ``light`` message to them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, EnvironmentMap, PointLight
from photon_fields.runtime.viewer.messages import MessageError


@dataclass
class LightControl:
    """A light as the page edits it: where it comes from (azimuth, elevation in degrees about the scene's
    vertical axis, y) and its power. Point lights keep their distance from the origin; an environment light
    has a power only. An environment map is shown as an environment (a power) with a ``yaw`` (its rotation about
    the vertical axis, degrees) and keeps its image and the rest of its rotation in ``source``, so that editing it
    never turns it into a constant environment."""

    kind: str
    azimuth: float
    elevation: float
    power: float
    distance: float
    color: np.ndarray
    source: EnvironmentMap | None = field(default=None, repr=False)
    yaw: float = 0.0

    @classmethod
    def from_light(cls, light: Any) -> LightControl:
        if isinstance(light, DirectionalLight):
            toward = -light.direction
            dist = 1.0
        elif isinstance(light, PointLight):
            dist = float(np.linalg.norm(light.position))
            toward = light.position / dist if dist > 0 else np.array([0.0, 1.0, 0.0])
        else:
            source = light if isinstance(light, EnvironmentMap) else None
            yaw = float(source.rotation[0]) if source is not None else 0.0
            return cls("environment", 0.0, 90.0, float(light.power), 0.0, light.color, source, yaw)
        az = math.degrees(math.atan2(float(toward[2]), float(toward[0])))
        el = math.degrees(math.asin(max(-1.0, min(1.0, float(toward[1])))))
        kind = "directional" if isinstance(light, DirectionalLight) else "point"
        return cls(kind, az, el, float(light.power), dist, light.color)

    def toward(self) -> np.ndarray:
        a, e = math.radians(self.azimuth), math.radians(self.elevation)
        return np.array([math.cos(e) * math.cos(a), math.sin(e), math.cos(e) * math.sin(a)])

    def light(self) -> Any:
        if self.kind == "directional":
            return DirectionalLight(-self.toward(), self.color, self.power)
        if self.kind == "point":
            return PointLight(self.toward() * self.distance, self.color, self.power)
        if self.source is not None:
            return self.source.adjusted(rotation=(self.yaw, *self.source.rotation[1:]), color=self.color,
                                        power=self.power)
        return EnvironmentLight(self.color, self.power)

    def to_dict(self) -> dict[str, Any]:
        """What the page builds the light's controls from (``yaw``: an environment map's, else None)."""
        return {"kind": self.kind, "azimuth": round(self.azimuth, 4), "elevation": round(self.elevation, 4),
                "power": self.power, "yaw": round(self.yaw, 4) if self.source is not None else None}


def edited_lights(lights: list[LightControl], f: dict[str, Any]) -> list[LightControl]:
    """The lights after a validated ``light`` message's fields ``f`` (the light ``index``, and any of azimuth,
    elevation, power, yaw); a :class:`MessageError` for a light that does not exist, a direction or yaw it does not
    have, or all lights off. ``lights`` is left as it is."""
    i = f["index"]
    if i >= len(lights):
        raise MessageError(f"light: index {i} but the scene has {len(lights)} light(s)")
    light = replace(lights[i])
    if light.kind == "environment" and ("azimuth" in f or "elevation" in f):
        raise MessageError(f"light: light {i} is an environment light: it has a power but no direction")
    if "yaw" in f and light.source is None:
        raise MessageError(f"light: light {i} is not an environment map: it has no yaw (an image to turn)")
    for key in ("azimuth", "elevation", "power", "yaw"):
        if key in f:
            setattr(light, key, f[key])
    edited = [*lights[:i], light, *lights[i + 1:]]
    if not any(float(np.max(lt.color)) * lt.power > 0 for lt in edited):
        raise MessageError("light: at least one light must keep a power above 0")
    return edited
