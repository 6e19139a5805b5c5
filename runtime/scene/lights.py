"""Light sources.

Every light has an RGB ``color`` (each component >= 0) and a scalar ``power`` (>= 0); its emitted
quantity is ``color * power``:

- :class:`PointLight` (``position``): radiant intensity I [W/sr]; irradiance at distance d is I / d^2.
- :class:`DirectionalLight` (``direction``: the direction light *travels*): irradiance E [W/m^2] on a
  surface facing the light; at infinite distance, so no falloff.
- :class:`EnvironmentLight`: constant radiance L [W/(m^2 sr)] arriving from every direction (a uniform
  sky). It is the only non-delta light: it can be hit by phase-sampled paths, so it is the case where
  the path tracer's multiple importance sampling matters, and it makes the white-furnace test possible.

Renderers and photon tracing consume :func:`pack_lights`, a structure-of-arrays form: ``kind (n,) int64``
(:data:`POINT`, :data:`DIRECTIONAL`, :data:`ENVIRONMENT`, defined here only), ``vec (n, 3)`` (position or
unit travel direction) and ``rgb (n, 3)`` (color * power). What each kind does in transport (direct-light
sampling, photon emission, the environment) is in :mod:`photon_fields.runtime.transport.emitters`.

Adding a light kind touches exactly:

1. this module: the dataclass (validation in ``__post_init__``, ``to_dict``), the ``Light`` union, its JSON
   keys in ``_LIGHT_KEYS`` and ``light_from_dict``, a new kind constant and its ``pack_lights`` branch (the
   one gate: an unknown class is refused there); for the Python API, its name in ``runtime/scene/scene.py``'s
   ``__all__`` beside the others;
2. ``runtime/transport/emitters.py``: its branches for direct light (``delta_light_direction``: a delta
   light's direction and falloff, 0 for any other kind; ``sample_light_direction``: the sample of a
   non-delta light) and for photons (``emission_fluxes``, ``emit_photon``); each of these raises for a kind
   it does not know, so a missing branch fails loudly;
3. tests: its sampler distributions in ``tests/runtime/transport/test_emitters.py`` and photon map vs path
   tracer in ``tests/runtime/photons/test_light_kinds.py``.

A kind that, like the environment, is not a delta light and is seen by rays that leave the volume also
needs the renderers' escape handling (``environment_radiance`` in ``runtime/wavefront/batches.py``, the
path tracer's ``add_escaped_radiance``), which today knows the constant environment only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError, unknown_keys_problem

POINT, DIRECTIONAL, ENVIRONMENT = 0, 1, 2


def as_vec3(v: Any, what: str) -> np.ndarray:
    """``v`` as a finite float64 3-vector, or a one-line InputError naming ``what``."""
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(what, f"must be three numbers, got {v!r}") from None
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(what, f"must be three finite numbers, got {v!r}")
    return a


def _color_power(color: Any, power: Any, what: str) -> tuple[np.ndarray, float]:
    c = as_vec3(color, f"{what} color")
    if np.any(c < 0):
        raise InputError(f"{what} color", f"components must be >= 0, got {c.tolist()}")
    try:
        p = float(power)
    except (TypeError, ValueError):
        raise InputError(f"{what} power", f"must be a number, got {power!r}") from None
    if not np.isfinite(p) or p < 0:
        raise InputError(f"{what} power", f"must be a finite number >= 0, got {power!r}")
    return c, p


@dataclass(frozen=True, eq=False)
class PointLight:
    position: np.ndarray
    color: np.ndarray
    power: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", as_vec3(self.position, "point light position"))
        c, p = _color_power(self.color, self.power, "point light")
        object.__setattr__(self, "color", c)
        object.__setattr__(self, "power", p)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "point", "position": self.position.tolist(), "color": self.color.tolist(), "power": self.power}


@dataclass(frozen=True, eq=False)
class DirectionalLight:
    direction: np.ndarray
    color: np.ndarray
    power: float = 1.0

    def __post_init__(self) -> None:
        d = as_vec3(self.direction, "directional light direction")
        n = float(np.linalg.norm(d))
        if n < 1e-12:
            raise InputError("directional light direction", "must not be the zero vector")
        object.__setattr__(self, "direction", d / n)
        c, p = _color_power(self.color, self.power, "directional light")
        object.__setattr__(self, "color", c)
        object.__setattr__(self, "power", p)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "directional", "direction": self.direction.tolist(), "color": self.color.tolist(),
                "power": self.power}


@dataclass(frozen=True, eq=False)
class EnvironmentLight:
    color: np.ndarray
    power: float = 1.0

    def __post_init__(self) -> None:
        c, p = _color_power(self.color, self.power, "environment light")
        object.__setattr__(self, "color", c)
        object.__setattr__(self, "power", p)

    def to_dict(self) -> dict[str, Any]:
        return {"type": "environment", "color": self.color.tolist(), "power": self.power}


Light = PointLight | DirectionalLight | EnvironmentLight


#: Keys a light object may have, by type (besides 'type').
_LIGHT_KEYS = {"point": {"position", "color", "power"}, "directional": {"direction", "color", "power"},
               "environment": {"color", "power"}}


def light_from_dict(d: Any, what: str = "light") -> Light:
    if not isinstance(d, dict):
        raise InputError(what, "must be a JSON object")
    kind = d.get("type")
    if kind not in _LIGHT_KEYS:
        raise InputError(what, f"unknown light type {kind!r} (expected 'point', 'directional' or 'environment')")
    # Unknown keys are refused: a misspelt "power" would otherwise render silently with power 1.
    unknown = [k for k in d if k not in _LIGHT_KEYS[kind] | {"type"}]
    if unknown:
        raise InputError(what, f"{kind} light: {unknown_keys_problem(unknown, _LIGHT_KEYS[kind] | {'type'})}")
    color = d.get("color", [1.0, 1.0, 1.0])
    power = d.get("power", 1.0)
    if kind == "point" and "position" not in d:
        raise InputError(what, "a point light needs 'position'")
    if kind == "directional" and "direction" not in d:
        raise InputError(what, "a directional light needs 'direction' (the direction light travels)")
    try:
        if kind == "point":
            return PointLight(d["position"], color, power)
        if kind == "directional":
            return DirectionalLight(d["direction"], color, power)
        return EnvironmentLight(color, power)
    except InputError as err:
        # The constructors name the field ("point light power") but not the light entry: prefix the entry
        # ("s.json lights[1] power") so an error in a scene file says which file and which light.
        raise InputError(f"{what} {err.what.rsplit(' ', 1)[-1]}", err.problem) from None


def pack_lights(lights: list[Light] | tuple[Light, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Structure-of-arrays form for the kernels: (kind int64 (n,), vec float64 (n,3), rgb float64 (n,3))."""
    n = len(lights)
    kind = np.zeros(n, dtype=np.int64)
    vec = np.zeros((n, 3), dtype=np.float64)
    rgb = np.zeros((n, 3), dtype=np.float64)
    for i, light in enumerate(lights):
        rgb[i] = light.color * light.power
        if isinstance(light, PointLight):
            kind[i], vec[i] = POINT, light.position
        elif isinstance(light, DirectionalLight):
            kind[i], vec[i] = DIRECTIONAL, light.direction
        elif isinstance(light, EnvironmentLight):
            kind[i] = ENVIRONMENT
        else:  # the kernels branch on these three kinds only: another one must not pass as an environment
            raise TypeError(f"light {i}: {type(light).__name__} is not a light kind the kernels know "
                            "(PointLight, DirectionalLight, EnvironmentLight)")
    return kind, vec, rgb
