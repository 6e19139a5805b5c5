"""A lighting for PVRT: the scene's lights, and optionally a sky function, as basis coefficients (Sec. 7.1).

PVRT precomputes the response to distant basis lights, so it renders distant lights only:

- a :class:`~photon_fields.runtime.scene.lights.DirectionalLight` (a delta in direction): projected for its
  multiple scattering (:meth:`LightingBasis.project_directional`). No finite basis represents a delta's sharp
  direct shadows, so by default its direct term falls back to next-event estimation (a light volume of its
  transmittance, ``runtime/pvrt/radiance.py``) and :attr:`Lighting.notes` says so;
- an :class:`~photon_fields.runtime.scene.lights.EnvironmentLight` (a constant sky), an
  :class:`~photon_fields.runtime.scene.lights.EnvironmentMap` (an HDR image, looked up with its rotation by
  :func:`~photon_fields.runtime.transport.environment_map.env_map_eval_batch`) and any sky function ``L(w)``:
  projected whole (multiple scattering from the transfer, the direct term from the optical-depth volumes of
  ``runtime/pvrt/direct.py``), and seen by rays that leave the volume;
- a point light is local, not distant: refused in one line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.pvrt.basis import LightingBasis, SkyFunction
from photon_fields.runtime.pvrt.suns import cached_suns
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, EnvironmentMap, PointLight
from photon_fields.runtime.transport.environment_map import (
    EnvMap,
    cached_env_map,
    env_map_eval_batch,
    rotation_matrix,
)

#: How a directional light's direct term is rendered: "nee" (light volume, sharp) or "transfer" (from the basis).
DIRECT_MODES = ("nee", "transfer")


@dataclass
class Lighting:
    """Basis coefficients of every distant light, and the directional lights whose direct term is NEE."""

    coeffs: np.ndarray  # (m, 3): everything the transfer renders the multiple scattering of
    direct_coeffs: np.ndarray  # (m, 3): what the transfer renders the direct term of (lights not done by NEE)
    nee_directions: np.ndarray  # (k, 3) travel directions of the directional lights done by NEE
    nee_rgb: np.ndarray  # (k, 3) their irradiance
    sky: SkyFunction | None = None  # what rays that leave the volume see (None: nothing, or the constant below)
    constant_sky: np.ndarray = field(default_factory=lambda: np.zeros(3))
    notes: list[str] = field(default_factory=list)


def scene_lighting(lights: tuple, basis: LightingBasis, *, sky: SkyFunction | None = None,
                   direct: str = "nee", rotation: np.ndarray | None = None) -> Lighting:
    """Project ``lights`` (a scene's) and ``sky`` into ``basis``; ``rotation`` (3x3) turns the whole lighting
    (the relighting the paper's viewer does). ``direct``: how directional lights' direct term is rendered."""
    if direct not in DIRECT_MODES:
        raise InputError("direct", f"must be one of {', '.join(DIRECT_MODES)}, got {direct!r}")
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise InputError("rotation", "must be a 3x3 rotation matrix")
    m = basis.size
    coeffs = np.zeros((m, 3))
    direct_coeffs = np.zeros((m, 3))
    nee_dirs, nee_rgb, notes = [], [], []
    constant = np.zeros(3)
    maps, projected = [], []  # what rays that leave see; what the basis gets (the maps without their suns)
    directional = suns_found = 0
    for i, light in enumerate(lights):
        if isinstance(light, PointLight):
            raise InputError(f"light {i}", "a point light is local, and PVRT's basis lights are distant: "
                             "use directional or environment lights (or another --method)")
        rgb = light.color * light.power
        if isinstance(light, DirectionalLight):
            travel = r @ light.direction
            c = basis.project_directional(-travel, rgb)
            coeffs += c
            if direct == "nee":
                directional += 1
                nee_dirs.append(travel)
                nee_rgb.append(rgb)
            else:
                direct_coeffs += c
        elif isinstance(light, EnvironmentLight):
            constant += rgb
        elif isinstance(light, EnvironmentMap):
            key = f"{light.sha256} {light.image.shape} {light.color.tolist()} {light.power!r}"
            to_world = rotation_matrix(*light.rotation)
            maps.append(cached_env_map(key, light.radiance, to_world))
            suns, rest = cached_suns(key, light.radiance, basis.resolution) if direct == "nee" else ([], None)
            for towards, irradiance in suns:  # sun: a directional light (NEE), the rest of the map projected
                travel = -(r @ (to_world @ towards))
                coeffs += basis.project_directional(-travel, irradiance)
                nee_dirs.append(travel)
                nee_rgb.append(irradiance)
            projected.append(cached_env_map(f"{key} without suns", lambda rest=rest: rest, to_world) if suns
                             else maps[-1])
            suns_found += len(suns)
            if suns:
                notes.append(f"light {i} (environment map {light.path or ''}): {len(suns)} "
                             f"sun{'s' if len(suns) > 1 else ''} narrower than the {basis.kind} basis resolves "
                             f"({math.degrees(basis.resolution):.0f} degrees): "
                             "direct term by NEE (light volume), multiple scattering from the transfer")
        else:
            raise InputError(f"light {i}", f"{type(light).__name__} is not a light PVRT can project")
    if directional:
        notes.append(f"{directional} directional light{'s' if directional > 1 else ''}: a delta the "
                     f"{basis.kind} basis cannot represent sharply; direct term by NEE (light volume), multiple "
                     "scattering from the transfer")
    sky_fn = _sky_function(constant, maps, sky, r)
    if sky_fn is not None:
        c = basis.project_sky(_sky_function(constant, projected, sky, r) if suns_found else sky_fn)
        coeffs += c
        direct_coeffs += c
    return Lighting(coeffs, direct_coeffs, np.array(nee_dirs).reshape(-1, 3), np.array(nee_rgb).reshape(-1, 3),
                    sky_fn if sky is not None or maps else None, constant, notes)


def _sky_function(constant: np.ndarray, maps: list[EnvMap], user: SkyFunction | None,
                  r: np.ndarray) -> SkyFunction | None:
    """The radiance arriving from each direction ``w`` (n, 3) -> (n, 3): the constant sky, the environment maps
    (their own rotations inside) and a user's sky function, all turned by ``r``; None where there is nothing."""
    if not (np.any(constant > 0) or user is not None or maps):
        return None

    def sky_fn(w: np.ndarray) -> np.ndarray:
        v = np.broadcast_to(constant, (len(w), 3)).astype(np.float64)
        turned = np.ascontiguousarray(w @ r)
        for env in maps:  # radiance arriving from each direction w (the map's own rotation inside)
            v = v + env_map_eval_batch(env, np.ascontiguousarray(turned.T))[0].T
        return v + (np.asarray(user(turned), dtype=np.float64) if user is not None else 0.0)

    return sky_fn
