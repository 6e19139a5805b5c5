"""Scenes: a volume, a transfer function, lights, a camera and the phase coefficient g.

Build one in Python::

    from photon_fields.runtime.scene.scene import Scene, builtin_scene
    scene = builtin_scene("vortex")                       # an embedded procedural scene
    scene = Scene(volume, tf, [DirectionalLight(...)], camera, g=0.3)

or load a JSON scene file with :func:`load_scene` (relative paths resolve against the file)::

    {
      "name": "engine",
      "volume": {"path": "engine.raw", "dims": [256, 256, 128], "dtype": "uint8",
                 "spacing": [1, 1, 1], "window": [0, 255]},      # or {"builtin": "vortex", "resolution": 96}
      "transfer_function": {"preset": "grey_ramp", "density_scale": 40},   # or {"points": [...]}, "tf.json", "auto"
                                                     # or {"preset": "auto"} (from the volume's histogram)
                                                     # or, for a label volume, {"labels": {"3": {...}}} or
                                                     # {"preset": "labels", "visible": [3, 7]}
      "lights": [{"type": "directional", "direction": [-1, -1, -0.5], "color": [1, 1, 1], "power": 3}],
      "camera": {"eye": [1.2, 0.7, 1.5], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 40,
                 "width": 512, "height": 512},
      "phase": {"g": 0.0}
    }

The world box is centred at the origin with its longest side 1 (see :mod:`photon_fields.runtime.scene.volume`).
Every problem is reported as a one-line :class:`photon_fields.runtime.errors.InputError` naming the offending entry.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.models_spec import fingerprint_parts, scene_fingerprint
from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.lights import (
    ENVIRONMENT,
    ENVIRONMENT_MAP,
    DirectionalLight,
    EnvironmentLight,
    EnvironmentMap,
    Light,
    PointLight,
    light_from_dict,
    light_identity,
    pack_lights,
)
from photon_fields.runtime.scene.transfer import TransferFunction, preset
from photon_fields.runtime.scene.volume import Volume, make_volume
from photon_fields.runtime.transport.environment_map import NO_ENV_MAP, EnvMap, cached_env_map, rotation_matrix
from photon_fields.runtime.transport.medium import Medium, build_medium
from photon_fields.runtime.transport.phase import check_g

_SCENE_KEYS = {"name", "volume", "transfer_function", "lights", "camera", "phase"}


#: The dicts :meth:`Scene.shared_cache` keeps, carried over by :meth:`Scene.with_overrides`.
SHARED_CACHES = ("light_volumes", "depth_bounds", "occupied_macrocells", "step_units", "light_volumes_before", "levels",
                 "camera_estimator")
#: Those of :data:`SHARED_CACHES` that depend on the medium alone, not on the lights (:meth:`Scene.adopt_medium`).
MEDIUM_CACHES = ("depth_bounds", "occupied_macrocells", "step_units")


@dataclass(frozen=True, eq=False)
class Scene:
    volume: Volume
    tf: TransferFunction | LabelTransfer
    lights: tuple[Light, ...]
    camera: Camera
    g: float = 0.0
    name: str = "scene"
    #: How to rebuild the volume: a scene file's volume entry (``{"builtin", "resolution"}`` or ``{"path"``
    #: (absolute), reader options``}``), set by the loaders; None for a volume built from an array.
    volume_source: dict[str, Any] | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        lights = tuple(self.lights)
        if not lights:
            raise InputError(f"scene '{self.name}' lights", "at least one light is required")
        if not any(float(np.max(light.color)) * light.power > 0 for light in lights):
            raise InputError(f"scene '{self.name}' lights", "all lights have zero power")
        if sum(isinstance(light, EnvironmentMap) for light in lights) > 1:
            raise InputError(f"scene '{self.name}' lights", "at most one environment_map (constant environments "
                             "are added to it)")
        object.__setattr__(self, "lights", lights)
        object.__setattr__(self, "g", check_g(self.g, f"scene '{self.name}' phase g"))
        if isinstance(self.tf, LabelTransfer):  # refused here, in one line, not when the medium is first built
            self.tf.check(self.volume, f"scene '{self.name}' transfer_function")

    def _volume_fingerprint(self) -> str:
        """The volume's part of the fingerprint: with a label transfer function, whose keys are raw labels, it
        also covers the raw window (:meth:`Volume.label_fingerprint`)."""
        return self.volume.label_fingerprint() if isinstance(self.tf, LabelTransfer) else self.volume.fingerprint()

    def fingerprint(self) -> str:
        """Identifies the light distribution: volume data, transfer function and lights (not camera, not g)."""
        if "fingerprint" not in self._cache:
            self._cache["fingerprint"] = scene_fingerprint(
                self._volume_fingerprint(), self.tf.to_dict(), self.light_identities())
        return self._cache["fingerprint"]

    def light_identities(self) -> list[dict[str, Any]]:
        """The lights as the fingerprint hashes them (:func:`photon_fields.runtime.scene.lights.light_identity`):
        what a bundle's lights are compared with (:mod:`photon_fields.runtime.scene.light_rescale`)."""
        return [light_identity(light) for light in self.lights]

    def fingerprint_parts(self) -> dict[str, str]:
        """Per-part fingerprints (volume, transfer_function, lights): recorded beside :meth:`fingerprint` in
        photon maps and bundles, so that a mismatch can name what differs."""
        if "fingerprint_parts" not in self._cache:
            self._cache["fingerprint_parts"] = fingerprint_parts(
                self._volume_fingerprint(), self.tf.to_dict(), self.light_identities())
        return dict(self._cache["fingerprint_parts"])

    def medium(self) -> Medium:
        """The packed medium (built once per scene object)."""
        if "medium" not in self._cache:
            self._cache["medium"] = build_medium(self.volume, self.tf)
        return self._cache["medium"]

    def shared_cache(self, key: str) -> dict[Any, Any]:
        """A dict kept with the scene for what depends on its medium and lights, and on nothing else or on what
        its keys name (the ray marcher's light volumes, ``"light_volumes"``, and step grids, ``"step_units"``; the
        camera walks' depth bounds per camera, ``"depth_bounds"``, and the occupied macrocells they rasterize,
        ``"occupied_macrocells"``; the volume's coarser levels' scenes, ``"levels"``,
        :mod:`photon_fields.runtime.scene.levels`; the auto camera estimator's choices, ``"camera_estimator"``,
        :mod:`photon_fields.runtime.wavefront.camera_choice`): one of :data:`SHARED_CACHES`, carried over by
        :meth:`with_overrides`, which changes neither medium nor lights."""
        if key not in SHARED_CACHES:
            raise ValueError(f"unknown shared cache {key!r} (one of {SHARED_CACHES})")
        return self._cache.setdefault(key, {})

    def adopt_medium(self, other: Scene) -> None:
        """Share ``other``'s medium, if built, and the caches that depend on it alone (:data:`MEDIUM_CACHES`): for
        a scene of the same volume and transfer function with other lights (a viewer's light edit), whose camera
        walks' depth bounds and marches' step grids are ``other``'s (at 512^3 each grid is a second of work)."""
        if "medium" in other._cache:
            self._cache["medium"] = other._cache["medium"]
        for key in MEDIUM_CACHES:
            self._cache[key] = other.shared_cache(key)
        # ``other``'s light volumes and lights, from which the ray marcher takes the columns of the lights that did
        # not move (runtime/renderers/ray_marcher.py, scene_light_volume); not ``other``'s own predecessors.
        kind, vec, _ = other.packed_lights()
        before = self.shared_cache("light_volumes_before")
        before.clear()
        before.update(volumes=other.shared_cache("light_volumes"), kind=kind, vec=vec)
        # The coarser levels (runtime/scene/levels.py) under these lights, each adopting its own medium alike.
        levels = self.shared_cache("levels")
        for level, old in other.shared_cache("levels").items():
            levels[level] = replace(old, lights=self.lights, _cache={})
            levels[level].adopt_medium(old)

    def packed_lights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Lights in SoA form, with all environment lights merged into one (radiances add up): an
        ENVIRONMENT_MAP entry when the scene has a map (the constant ones are added to its radiance table,
        :meth:`packed_environment_map`), else one ENVIRONMENT entry."""
        if "lights" not in self._cache:
            kind, vec, rgb = pack_lights(self.lights)
            env = (kind == ENVIRONMENT) | (kind == ENVIRONMENT_MAP)
            if env.sum() > 1:
                merged_kind = ENVIRONMENT_MAP if np.any(kind == ENVIRONMENT_MAP) else ENVIRONMENT
                merged = np.ones(3) if merged_kind == ENVIRONMENT_MAP else rgb[env].sum(axis=0)
                keep = ~env
                kind = np.concatenate([kind[keep], [merged_kind]])
                vec = np.concatenate([vec[keep], np.zeros((1, 3))])
                rgb = np.concatenate([rgb[keep], merged[None]])
            self._cache["lights"] = (kind, vec, rgb)
        return self._cache["lights"]

    def packed_environment_map(self) -> EnvMap:
        """The environment map's tables for the kernels (:mod:`photon_fields.runtime.transport.environment_map`):
        its radiance (image x color x power) plus every constant environment's, rotated; :data:`NO_ENV_MAP`
        when the scene has no map. The tables are cached by radiance, so a rotated copy of a scene rebuilds
        nothing but the rotation matrix."""
        if "env_map" not in self._cache:
            maps = [lt for lt in self.lights if isinstance(lt, EnvironmentMap)]
            if not maps:
                self._cache["env_map"] = NO_ENV_MAP
            else:
                m = maps[0]
                constant = sum((lt.color * lt.power for lt in self.lights if isinstance(lt, EnvironmentLight)),
                               np.zeros(3))
                key = f"{m.sha256} {m.image.shape} {m.color.tolist()} {m.power!r} {constant.tolist()}"
                self._cache["env_map"] = cached_env_map(key, lambda: m.radiance() + constant,
                                                        rotation_matrix(*m.rotation))
        return self._cache["env_map"]

    def with_overrides(self, *, g: float | None = None, camera: Camera | None = None,
                       width: int | None = None, height: int | None = None) -> Scene:
        """A copy with a different g and/or camera/resolution (shares the volume, rebuilds nothing heavy)."""
        cam = camera or self.camera
        if width is not None or height is not None:
            # Only None means "keep": anything else, 0 included, goes to the camera's validation.
            cam = cam.with_resolution(cam.width if width is None else width,
                                      cam.height if height is None else height)
        new = replace(self, g=self.g if g is None else g, camera=cam, _cache={})
        for key in SHARED_CACHES:  # one dict each: what either scene adds later is shared too
            new._cache[key] = self.shared_cache(key)
        for key in ("medium", "fingerprint", "fingerprint_parts", "lights", "env_map"):  # none depend on g or camera
            if key in self._cache:
                new._cache[key] = self._cache[key]
        return new

    def spec(self) -> dict[str, Any] | None:
        """The scene as a scene file (what :func:`scene_from_dict` reads back to the same fingerprint,
        camera and g), or None when the volume was built from an array and cannot be referenced. Bundles
        record it so that ``pfn-render --method field`` can rebuild the scene a field was trained for."""
        if self.volume_source is None:
            return None
        return {"name": self.name, "volume": dict(self.volume_source), "transfer_function": self.tf.to_dict(),
                "lights": [lt.to_dict() for lt in self.lights], "camera": self.camera.to_dict(),
                "phase": {"g": self.g}}

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description (the volume is referenced by name and fingerprint, not embedded)."""
        return {"name": self.name, "volume": {"name": self.volume.name, "dims": list(self.volume.dims),
                                              "spacing": list(self.volume.spacing),
                                              "fingerprint": self.volume.fingerprint()},
                "transfer_function": self.tf.to_dict(), "lights": [lt.to_dict() for lt in self.lights],
                "camera": self.camera.to_dict(), "phase": {"g": self.g}}


# --- embedded procedural scenes ----------------------------------------------------------------------

DEFAULT_SCENE = "vortex"
_DEFAULT_CAMERA = {"eye": [1.25, 0.75, 1.45], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0], "fov": 38.0,
                   "width": 256, "height": 256}
_WARM_SUN = [1.0, 0.95, 0.85]

#: name -> (generator name, TF preset, lights, description). Resolution is ``BUILTIN_RESOLUTION``.
BUILTIN_SCENES: dict[str, dict[str, Any]] = {
    "vortex": {"volume": "vortex", "tf": "vortex", "g": 0.0,
               "lights": [{"type": "directional", "direction": [-0.6, -0.7, -0.4], "color": _WARM_SUN, "power": 4.0}],
               "about": "vorticity magnitude of interacting vortex tubes: wispy, lots of empty space"},
    "blobs": {"volume": "blobs", "tf": "cloud", "g": 0.3,
              "lights": [{"type": "directional", "direction": [-0.5, -0.8, 0.3], "color": _WARM_SUN, "power": 3.0},
                         {"type": "point", "position": [0.9, 0.2, 0.9], "color": [0.6, 0.75, 1.0], "power": 0.6}],
              "about": "a cloud of soft Gaussian blobs lit by a sun and a blue fill light"},
    "shell": {"volume": "shell", "tf": "shell", "g": -0.2,
              "lights": [{"type": "point", "position": [0.8, 0.9, 0.8], "color": _WARM_SUN, "power": 3.0}],
              "about": "a perforated shell with sharp boundaries around a dense core"},
    "head": {"volume": "head", "tf": "ct", "g": 0.4,
             "lights": [{"type": "directional", "direction": [-0.6, -0.7, -0.4], "color": _WARM_SUN, "power": 4.0},
                        {"type": "point", "position": [-0.9, 0.4, 0.9], "color": [0.6, 0.75, 1.0], "power": 0.5}],
             "about": "a CT-like head phantom: skull, folded brain, vessels, a sparse medical transfer function"},
}
BUILTIN_RESOLUTION = 96


def builtin_volume(name: str, resolution: int = BUILTIN_RESOLUTION, what: str = "volume") -> Volume:
    """The procedural volume ``name`` at ``resolution``^3 (cached); ``what`` labels errors."""
    from photon_fields.runtime.scene.procedural import GENERATORS

    if name not in GENERATORS:
        raise InputError(f"{what} builtin", f"unknown builtin volume '{name}' (available: {', '.join(GENERATORS)})")
    # Validated before the cache lookup, which would raise a TypeError traceback on an unhashable resolution
    # (e.g. [32] from a scene file). bool is an int subclass: refuse it explicitly.
    if isinstance(resolution, bool) or not isinstance(resolution, int) or not 8 <= resolution <= 512:
        raise InputError(f"{what} resolution", f"must be an integer in [8, 512], got {resolution!r}")
    return _cached_builtin_volume(name, resolution)


@lru_cache(maxsize=8)
def _cached_builtin_volume(name: str, resolution: int) -> Volume:
    from photon_fields.runtime.scene.procedural import GENERATORS

    return make_volume(GENERATORS[name](resolution), name=name, window=(0.0, 1.0))


def builtin_scene(name: str, resolution: int = BUILTIN_RESOLUTION) -> Scene:
    if name not in BUILTIN_SCENES:
        raise InputError("scene", f"unknown scene '{name}': not a file and not a builtin "
                         f"({', '.join(BUILTIN_SCENES)})")
    spec = BUILTIN_SCENES[name]
    return Scene(builtin_volume(spec["volume"], resolution), preset(spec["tf"]),
                 tuple(light_from_dict(d) for d in spec["lights"]), Camera.from_dict(_DEFAULT_CAMERA),
                 spec["g"], name, {"builtin": spec["volume"], "resolution": resolution})


# --- scene files ---------------------------------------------------------------------------------------


def load_scene(source: str | Path) -> Scene:
    """A builtin scene name or the path of a JSON scene file."""
    p = Path(source)
    if not p.suffix and str(source) in BUILTIN_SCENES:
        return builtin_scene(str(source))
    if not p.exists():
        if str(source) in BUILTIN_SCENES:
            return builtin_scene(str(source))
        raise InputError(str(source), "scene file not found (and not a builtin scene: "
                         f"{', '.join(BUILTIN_SCENES)})")
    # A directory (or an unreadable file) is one line here, not an OSError traceback from read_text.
    if not p.is_file():
        raise InputError(str(p), "is not a regular file (expected a JSON scene file)")
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(str(p), f"not valid JSON ({exc.__class__.__name__}: {exc})") from None
    except OSError as exc:
        raise InputError(str(p), f"cannot read scene file ({exc.strerror or exc})") from None
    return scene_from_dict(d, base_dir=p.parent, what=str(p))


def scene_from_dict(d: Any, base_dir: Path | None = None, what: str = "scene") -> Scene:
    base_dir = base_dir or Path.cwd()
    if not isinstance(d, dict):
        raise InputError(what, "a scene must be a JSON object")
    check_keys(d, _SCENE_KEYS, what)
    for key in ("volume", "transfer_function", "lights", "camera"):
        if key not in d:
            raise InputError(what, f"missing '{key}'")
    name = str(d.get("name", Path(what).stem))
    volume, volume_source = _volume_from_dict(d["volume"], base_dir, f"{what} volume")
    tf_spec = d["transfer_function"]
    # Resolved here, where the volume is known: {"preset": "auto"} becomes concrete points, and the scene's
    # fingerprint and spec() are those of the concrete function.
    if isinstance(tf_spec, str) and not _resolve(tf_spec, base_dir).exists() and Path(tf_spec).suffix == "":
        # a bare name that is no file: a preset ("auto", "labels", "grey_ramp", ...), as in the Python API
        tf = TransferFunction.from_dict({"preset": tf_spec}, what=f"{what} transfer_function", volume=volume)
    elif isinstance(tf_spec, str):
        tf = TransferFunction.load(_resolve(tf_spec, base_dir), volume=volume)
    else:
        tf = TransferFunction.from_dict(tf_spec, what=f"{what} transfer_function", volume=volume)
    if not isinstance(d["lights"], list):
        raise InputError(f"{what} lights", "must be a list of light objects")
    lights = tuple(light_from_dict(x, f"{what} lights[{i}]", base_dir) for i, x in enumerate(d["lights"]))
    camera = Camera.from_dict(d["camera"], f"{what} camera")
    phase = d.get("phase", {})
    if not isinstance(phase, dict):
        raise InputError(f"{what} phase", "must be an object like {\"g\": 0.0}")
    # A misspelt phase key (e.g. "gg") would otherwise render silently with g = 0.
    check_keys(phase, ("g",), f"{what} phase")
    # Scene's own checks label errors "scene '<name>' ...", which does not name the file: validate g here and
    # re-label the Scene's errors with ``what``.
    g = check_g(phase.get("g", 0.0), f"{what} phase g")
    try:
        return Scene(volume, tf, lights, camera, g, name, volume_source)
    except InputError as err:
        prefix = f"scene '{name}'"
        label = what + err.what[len(prefix):] if err.what.startswith(prefix) else f"{what} {err.what}"
        raise InputError(label, err.problem) from None


def _resolve(path: str, base_dir: Path) -> Path:
    p = Path(path).expanduser()
    return p if p.is_absolute() else base_dir / p


def _volume_from_dict(v: Any, base_dir: Path, what: str) -> tuple[Volume, dict[str, Any]]:
    """The volume of a scene entry, and the entry that rebuilds it from anywhere (path made absolute)."""
    if not isinstance(v, dict):
        raise InputError(what, "must be an object with 'path' or 'builtin'")
    if "builtin" in v:
        # Unknown keys are refused, as for file volumes, and errors name the entry.
        check_keys(v, ("builtin", "resolution"), what)
        resolution = v.get("resolution", BUILTIN_RESOLUTION)
        volume = builtin_volume(str(v["builtin"]), resolution, what=what)
        return volume, {"builtin": str(v["builtin"]), "resolution": resolution}
    if "path" not in v:
        raise InputError(what, "needs 'path' (a volume file) or 'builtin' (a procedural volume name)")
    from photon_fields.runtime.scene.volume_io import load_volume

    # load_volume's reader options
    options = ("dims", "dtype", "endian", "spacing", "window", "axes", "array", "level", "series")
    check_keys(v, ("path", *options), what)
    kwargs = {k: v[k] for k in options if k in v}
    path = _resolve(str(v["path"]), base_dir)
    return load_volume(path, **kwargs), {"path": str(path.absolute()), **kwargs}


__all__ = ["Scene", "builtin_scene", "load_scene", "scene_from_dict", "BUILTIN_SCENES", "DEFAULT_SCENE",
           "PointLight", "DirectionalLight", "EnvironmentLight", "EnvironmentMap"]
