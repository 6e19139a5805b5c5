"""Light sources.

Every light has an RGB ``color`` (each component >= 0) and a scalar ``power`` (>= 0); its emitted
quantity is ``color * power``:

- :class:`PointLight` (``position``): radiant intensity I [W/sr]; irradiance at distance d is I / d^2.
- :class:`DirectionalLight` (``direction``: the direction light *travels*): irradiance E [W/m^2] on a
  surface facing the light; at infinite distance, so no falloff.
- :class:`EnvironmentLight`: constant radiance L [W/(m^2 sr)] arriving from every direction (a uniform
  sky). It is a non-delta light: it can be hit by phase-sampled paths, so it is the case where
  the path tracer's multiple importance sampling matters, and it makes the white-furnace test possible.
- :class:`EnvironmentMap` (``path`` of an equirectangular ``.exr`` / ``.hdr`` image, ``rotation``): radiance
  ``image(w) * color * power`` arriving from direction w; the lat-long convention, the rotation and the
  importance sampling are in :mod:`photon_fields.runtime.transport.environment_map`. A scene has at most one;
  constant environments are merged into it (:meth:`photon_fields.runtime.scene.scene.Scene.packed_lights`).

Renderers and photon tracing consume :func:`pack_lights`, a structure-of-arrays form: ``kind (n,) int64``
(:data:`POINT`, :data:`DIRECTIONAL`, :data:`ENVIRONMENT`, :data:`ENVIRONMENT_MAP`, defined here only), ``vec (n,
3)`` (position or unit travel direction) and ``rgb (n, 3)`` (color * power; 1 for an environment map, whose
radiance table, :class:`photon_fields.runtime.transport.environment_map.EnvMap`, is packed by
:meth:`photon_fields.runtime.scene.scene.Scene.packed_environment_map` and passed to the kernels beside them).
What each kind does in transport (direct-light sampling, photon emission, the environment) is in
:mod:`photon_fields.runtime.transport.emitters`.

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
path tracer's ``add_escaped_radiance``): both go through
:class:`photon_fields.runtime.wavefront.batches.Environment`, which knows the constant environment and the map.
"""

from __future__ import annotations

import copy
import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError, unknown_keys_problem

POINT, DIRECTIONAL, ENVIRONMENT, ENVIRONMENT_MAP = 0, 1, 2, 3


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


def _rotation(rotation: Any, what: str) -> tuple[float, float, float]:
    """An environment map's rotation: one number (yaw, degrees about +y) or [yaw, pitch, roll] in degrees."""
    r = [rotation] if isinstance(rotation, (int, float)) and not isinstance(rotation, bool) else rotation
    try:
        a = np.asarray(r, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.ndim != 1 or a.size not in (1, 3) or not np.all(np.isfinite(a)) or isinstance(rotation, (str, bool)):
        raise InputError(what, f"must be a yaw angle in degrees or [yaw, pitch, roll] in degrees, got {rotation!r}")
    a = np.concatenate([a, np.zeros(3 - a.size)])
    return float(a[0]), float(a[1]), float(a[2])


@dataclass(frozen=True, eq=False)
class EnvironmentMap:
    """Radiance ``image(w) * color * power`` from an equirectangular HDR image (``.exr`` or ``.hdr``, W = 2 H,
    finite, >= 0), rotated by ``rotation`` = (yaw, pitch, roll) degrees (see
    :mod:`photon_fields.runtime.transport.environment_map` for the axes). Give ``path`` (the file is read and
    validated here: one-line InputError) or ``image`` (an (H, 2H, 3) array, validated the same way; ``path``
    then only names it). :meth:`rotated` gives the same map turned, sharing the image (PVRT rotates the
    environment: no file is read again and the sampling tables are reused)."""

    path: str | None = None
    color: np.ndarray = field(default_factory=lambda: np.ones(3))
    power: float = 1.0
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    image: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        c, p = _color_power(self.color, self.power, "environment map")
        object.__setattr__(self, "color", c)
        object.__setattr__(self, "power", p)
        object.__setattr__(self, "rotation", _rotation(self.rotation, "environment map rotation"))
        if self.image is None:
            if self.path is None:
                raise InputError("environment map", "needs 'path' (an .exr or .hdr image)")
            from photon_fields.runtime.io.hdr_images import read_environment_image

            object.__setattr__(self, "image", read_environment_image(self.path))
        else:
            object.__setattr__(self, "image", _check_image(self.image, self.path or "environment map image"))
        self.image.setflags(write=False)
        object.__setattr__(self, "_sha256", hashlib.sha256(self.image.tobytes()).hexdigest())

    @property
    def sha256(self) -> str:
        """Hash of the pixels: the lights' fingerprint changes when the image does, whatever its path."""
        return self._sha256  # type: ignore[attr-defined]

    def rotated(self, yaw: float, pitch: float = 0.0, roll: float = 0.0) -> EnvironmentMap:
        """The same map with another rotation (degrees), sharing the image: nothing is validated or hashed again,
        and a scene with it reuses the sampling tables (``Scene.packed_environment_map``)."""
        return self.adjusted(rotation=(yaw, pitch, roll))

    def adjusted(self, *, rotation: Any = None, color: Any = None, power: float | None = None) -> EnvironmentMap:
        """The same image with another rotation, colour or power (each validated as in the constructor; None keeps
        it): the image is neither checked nor hashed again (the viewer's light edits, every frame of a drag)."""
        new = copy.copy(self)
        if rotation is not None:
            object.__setattr__(new, "rotation", _rotation(rotation, "environment map rotation"))
        if color is not None or power is not None:
            c, p = _color_power(self.color if color is None else color, self.power if power is None else power,
                                "environment map")
            object.__setattr__(new, "color", c)
            object.__setattr__(new, "power", p)
        return new

    def radiance(self) -> np.ndarray:
        """The emitted radiance table (H, W, 3) float64: image * color * power."""
        return self.image.astype(np.float64) * (self.color * self.power)

    def identity(self) -> dict[str, Any]:
        """What the lights' fingerprint hashes: :meth:`to_dict` without the path (the pixels' hash stands for
        the image, so moving the file keeps photon maps and fields valid)."""
        return {k: v for k, v in self.to_dict().items() if k != "path"}

    def to_dict(self) -> dict[str, Any]:
        return {"type": "environment_map", "path": self.path, "color": self.color.tolist(), "power": self.power,
                "rotation": list(self.rotation), "sha256": self.sha256}


def _check_image(image: Any, what: str) -> np.ndarray:
    """An in-memory environment image as (H, 2H, 3) float32, with the file reader's checks."""
    a = np.asarray(image)
    if not np.issubdtype(a.dtype, np.floating):
        raise InputError(what, f"not a float image (dtype {a.dtype})")
    if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] != 2 * a.shape[0]:
        raise InputError(what, f"an equirectangular environment map must be (H, 2H, 3), got {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise InputError(what, "pixels must be finite and >= 0")
    return np.ascontiguousarray(a, dtype=np.float32)


Light = PointLight | DirectionalLight | EnvironmentLight | EnvironmentMap


#: Keys a light object may have, by type (besides 'type'). An environment map's optional 'sha256' (written by
#: ``to_dict``) must match the image: a scene spec recorded with a bundle refuses a changed file.
_LIGHT_KEYS = {"point": {"position", "color", "power"}, "directional": {"direction", "color", "power"},
               "environment": {"color", "power"}, "environment_map": {"path", "color", "power", "rotation", "sha256"}}


def light_from_dict(d: Any, what: str = "light", base_dir: Path | None = None) -> Light:
    """A light from its JSON object; an environment map's relative ``path`` resolves against ``base_dir`` (the
    scene file's folder; default the working directory)."""
    if not isinstance(d, dict):
        raise InputError(what, "must be a JSON object")
    kind = d.get("type")
    if kind not in _LIGHT_KEYS:
        raise InputError(what, f"unknown light type {kind!r} (expected 'point', 'directional', 'environment' or "
                         "'environment_map')")
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
    if kind == "environment_map":
        return _environment_map_from_dict(d, what, base_dir)
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


def _environment_map_from_dict(d: dict[str, Any], what: str, base_dir: Path | None) -> EnvironmentMap:
    path = d.get("path")
    if not isinstance(path, str) or not path:
        raise InputError(what, "an environment map needs 'path' (an .exr or .hdr image, relative to the scene file)")
    p = Path(path).expanduser()
    if not p.is_absolute():
        p = ((base_dir if base_dir is not None else Path.cwd()) / p).absolute()
    try:
        light = EnvironmentMap(str(p), d.get("color", [1.0, 1.0, 1.0]), d.get("power", 1.0),
                               d.get("rotation", 0.0))
    except InputError as err:
        if err.what == str(p):  # the image's own problem: name the file and the entry
            raise InputError(f"{what} path {p}", err.problem) from None
        raise InputError(f"{what} {err.what.rsplit(' ', 1)[-1]}", err.problem) from None
    if "sha256" in d and d["sha256"] != light.sha256:
        raise InputError(f"{what} path {p}", "the image has changed since this scene was recorded (sha256 differs)")
    return light


def light_identity(light: Light) -> dict[str, Any]:
    """The dict a scene's fingerprint hashes for ``light``: its ``to_dict`` (an environment map's without its path)."""
    return light.identity() if isinstance(light, EnvironmentMap) else light.to_dict()


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
        elif isinstance(light, EnvironmentMap):  # its radiance is the map's (Scene.packed_environment_map)
            kind[i], rgb[i] = ENVIRONMENT_MAP, 1.0
        else:  # the kernels branch on these four kinds only: another one must not pass as an environment
            raise TypeError(f"light {i}: {type(light).__name__} is not a light kind the kernels know "
                            "(PointLight, DirectionalLight, EnvironmentLight, EnvironmentMap)")
    return kind, vec, rgb
