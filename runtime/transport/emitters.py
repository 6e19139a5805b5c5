"""Emitters: the transport code of every light kind, in one place.

As in Mitsuba 3, where one emitter type carries both its emission sampling and its direct-light sampling,
everything a light kind does in transport lives here, one branch per kind (the kinds and their packed
``kind``/``vec``/``rgb`` arrays are defined in :mod:`photon_fields.runtime.scene.lights`):

- **direct-light sampling** towards a point ``p`` (next-event estimation), :func:`sample_light_direction`:
  the direction ``l`` towards the light, the light's RGB value along it (``value * rgb``), the solid-angle pdf
  of the sample and the distance to the light. Delta lights (point, directional) alone are
  :func:`delta_light_direction` (the ray marcher's shadow rays use only these).

  ===============  =========================================  ============  ===========  ===============
  kind             l                                          value         pdf          distance
  ===============  =========================================  ============  ===========  ===============
  point            towards ``vec`` (the position)             1 / r^2       inf (delta)  r
  directional      ``-vec`` (``vec`` is the travel direction)  1             inf (delta)  inf
  environment      uniform on the sphere (two random numbers)  1             1 / (4 pi)   inf
  environment map  from the map's density (two random numbers) L(l) (table)  p_w(l)       inf
  ===============  =========================================  ============  ===========  ===============

  (the environment map's density p_w, proportional to luminance x sin(theta) per pixel, is derived in
  :mod:`photon_fields.runtime.transport.environment_map`; the map's packed ``rgb`` is 1, its radiance is in the
  :class:`~photon_fields.runtime.transport.environment_map.EnvMap` ``env`` every kernel here takes).

  :func:`photon_fields.runtime.transport.direct_light.direct_light` turns a sample into
  ``f_g(d . l) * value * w / pdf * rgb * Tr`` (``w`` = 1 and no division for delta lights; the MIS weight
  against phase sampling otherwise).
- **photon emission** (paper Alg. 1, used by ``train/photons/tracing.py``): :func:`emission_fluxes` (per
  light, the flux of the part that can reach the volume's bounding sphere, centre ``c`` radius ``R``, and
  the cone of directions emitted) and :func:`emit_photon` (the origin and travel direction of one photon):

  - point light, intensity I: flux 4 pi I (1 - cos_max) / 2; directions uniform inside the cone that
    subtends the bounding sphere (``cos_max``; -1, the whole sphere, when the light is inside it), so no
    photon is wasted on directions that cannot reach the volume;
  - directional light, irradiance E: flux E pi R^2; parallel rays from a disk of radius R perpendicular to
    the direction, 1.01 R behind the centre;
  - environment, radiance L: flux 4 pi^2 R^2 L (uniform radiance through a sphere of radius R); a uniform
    direction, then a disk as for the directional light.
  - environment map, radiance L(w) arriving from w: flux pi R^2 int L(w) dw (per channel; 4 pi^2 R^2 L for a
    constant map); the direction w from the map's density p_w, the photon travels along -w from a disk as
    for the directional light, and its power is scaled by ``L(w) / (p_w(w) int L dw)`` per channel (1 on
    average: the one-sample estimate of the flux through the disk from w, relative to the light's flux).
    :func:`emit_photon` returns that per-channel scale (1 for the other kinds).

- **the environment** (the non-delta kinds, reached by escaping rays too): :func:`environment_index`,
  :data:`ENVIRONMENT_PDF` (the pdf of the constant environment's direct-light samples, which the path tracer's
  MIS weight of an escaping ray needs; a map's is ``env_map_eval``'s).

Every per-kind branch raises for a kind it does not know (``pack_lights`` refuses unknown light classes
before that). The kernels called inside other modules' ``prange`` loops (:func:`emit_photon` by photon
tracing, :func:`delta_light_direction` by the ray marcher) are therefore not ``inline="always"``: a
``raise`` inlined into a ``prange`` body makes numba run the loop serially. Adding a kind: its class in
``runtime/scene/lights.py`` (and ``pack_lights``), its branch in each function here, tests (the list is in
``runtime/scene/lights.py``'s docstring and ``docs/architecture.md``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from photon_fields.runtime.scene.lights import DIRECTIONAL, ENVIRONMENT, ENVIRONMENT_MAP, POINT
from photon_fields.runtime.transport.environment_map import NO_ENV_MAP, EnvMap, env_map_sample
from photon_fields.runtime.transport.medium import Medium
from photon_fields.runtime.transport.phase import INV_4PI, orthonormal_basis
from photon_fields.runtime.transport.rng import next_float

#: Solid-angle pdf of the environment's direct-light samples (uniform on the sphere).
ENVIRONMENT_PDF = INV_4PI


@njit(cache=True, inline="always")
def sample_uniform_sphere(u1: float, u2: float) -> tuple[float, float, float]:
    """A direction uniform on the unit sphere (pdf 1 / (4 pi)) from two uniforms in [0, 1)."""
    z = 1.0 - 2.0 * u1
    s = math.sqrt(max(0.0, 1.0 - z * z))
    return s * math.cos(2.0 * math.pi * u2), s * math.sin(2.0 * math.pi * u2), z


# --- direct-light sampling (next-event estimation) -------------------------------------------------------


@njit(cache=True)
def check_light_kinds(kind: np.ndarray) -> None:
    """Raise for a light kind number no emitter knows. A parallel kernel calls it before its ``prange``: an
    exception raised inside a parallel region reaches the caller or not depending on what ran before in the
    process (numba), so a kernel there would return garbage for an unknown kind instead of refusing it."""
    for k in range(kind.shape[0]):
        if kind[k] != POINT and kind[k] != DIRECTIONAL and kind[k] != ENVIRONMENT and kind[k] != ENVIRONMENT_MAP:
            raise ValueError("unknown light kind")


@njit(cache=True)
def delta_light_direction(kind: int, pos_or_dir: np.ndarray, px: float, py: float,
                          pz: float) -> tuple[float, float, float, float, float]:
    """Towards a delta light from p: (lx, ly, lz, falloff, distance). Point: falloff 1/r^2 and the
    distance to the light; directional: falloff 1 and inf. Falloff 0 means 'no contribution' (p on
    the light, or the environment, which is not a delta light). Raises for an unknown kind."""
    if kind == POINT:
        lx, ly, lz = pos_or_dir[0] - px, pos_or_dir[1] - py, pos_or_dir[2] - pz
        dist2 = lx * lx + ly * ly + lz * lz
        if dist2 <= 0.0:
            return 0.0, 0.0, 1.0, 0.0, 0.0
        dist = math.sqrt(dist2)
        return lx / dist, ly / dist, lz / dist, 1.0 / dist2, dist
    if kind == DIRECTIONAL:
        return -pos_or_dir[0], -pos_or_dir[1], -pos_or_dir[2], 1.0, math.inf
    if kind == ENVIRONMENT:
        return 0.0, 0.0, 1.0, 0.0, 0.0
    if kind == ENVIRONMENT_MAP:
        return 0.0, 0.0, 1.0, 0.0, 0.0
    raise ValueError("unknown light kind")


@njit(cache=True, inline="always")
def sample_light_direction(kind: int, pos_or_dir: np.ndarray, rgb: np.ndarray, env: EnvMap, px: float, py: float,
                           pz: float, state: np.uint64
                           ) -> tuple[float, float, float, float, float, float, float, float, np.uint64]:
    """A direct-light sample from p: (lx, ly, lz, r, g, b, pdf, distance, state) with (r, g, b) = value * rgb, see
    the module docstring. ``pdf`` is inf for a delta light (no other strategy can reach it); only the
    environments draw random numbers. Raises for an unknown kind."""
    if kind == ENVIRONMENT:
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        lx, ly, lz = sample_uniform_sphere(u1, u2)
        return lx, ly, lz, rgb[0], rgb[1], rgb[2], ENVIRONMENT_PDF, math.inf, state
    if kind == ENVIRONMENT_MAP:
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        lx, ly, lz, lr, lg, lb, pdf = env_map_sample(env, u1, u2)
        return lx, ly, lz, lr * rgb[0], lg * rgb[1], lb * rgb[2], pdf, math.inf, state
    lx, ly, lz, falloff, dist = delta_light_direction(kind, pos_or_dir, px, py, pz)
    return lx, ly, lz, falloff * rgb[0], falloff * rgb[1], falloff * rgb[2], math.inf, dist, state


# --- photon emission ----------------------------------------------------------------------------------


def emission_fluxes(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray,
                    env: EnvMap = NO_ENV_MAP) -> tuple[np.ndarray, np.ndarray]:
    """(flux (n, 3) of the part of each light that can reach the volume's bounding sphere, emission cone
    cos_max (n,): -1 = all directions) for packed lights (``env``: the scene's environment map); see the module
    docstring. Raises ValueError for an unknown kind."""
    center = m.bmin + 0.5 * m.bsize
    radius = 0.5 * float(np.linalg.norm(m.bsize))
    flux = np.zeros_like(rgb)
    cos_max = np.full(len(kind), -1.0)
    for i in range(len(kind)):
        if kind[i] == POINT:
            dist = float(np.linalg.norm(vec[i] - center))
            if dist > radius:
                cos_max[i] = math.sqrt(max(0.0, 1.0 - (radius / dist) ** 2))
            flux[i] = 4 * math.pi * rgb[i] * (1.0 - cos_max[i]) / 2.0
        elif kind[i] == DIRECTIONAL:
            flux[i] = rgb[i] * math.pi * radius**2
        elif kind[i] == ENVIRONMENT:
            flux[i] = rgb[i] * 4 * math.pi**2 * radius**2
        elif kind[i] == ENVIRONMENT_MAP:
            flux[i] = rgb[i] * math.pi * radius**2 * env.integral
        else:
            raise ValueError(f"light {i}: unknown light kind {int(kind[i])}")
    return flux, cos_max


@njit(cache=True)
def emit_photon(kind: int, vec: np.ndarray, env: EnvMap, cos_max: float, cx: float, cy: float, cz: float,
                radius: float, u1: float, u2: float, u3: float, u4: float
                ) -> tuple[float, float, float, float, float, float, float, float, float]:
    """Origin, travel direction and per-channel power scale (ox, oy, oz, dx, dy, dz, sr, sg, sb) of a photon
    emitted by a light whose cone is ``cos_max`` (:func:`emission_fluxes`), towards the bounding sphere (centre
    c, ``radius``), from four uniforms in [0, 1). The scale multiplies the light's flux / P(light); it is 1
    except for an environment map (module docstring). Raises for an unknown kind."""
    if kind == POINT:
        ax, ay, az = cx - vec[0], cy - vec[1], cz - vec[2]
        n = math.sqrt(ax * ax + ay * ay + az * az)
        if cos_max > -1.0 and n > 0.0:
            ax, ay, az = ax / n, ay / n, az / n
        else:  # light inside the bounding sphere: the whole sphere of directions
            ax, ay, az = 0.0, 0.0, 1.0
        c = 1.0 - u1 * (1.0 - cos_max)
        s = math.sqrt(max(0.0, 1.0 - c * c))
        tx, ty, tz, bx, by, bz = orthonormal_basis(ax, ay, az)
        cp, sp = s * math.cos(2 * math.pi * u2), s * math.sin(2 * math.pi * u2)
        wx, wy, wz = cp * tx + sp * bx + c * ax, cp * ty + sp * by + c * ay, cp * tz + sp * bz + c * az
        return vec[0], vec[1], vec[2], wx, wy, wz, 1.0, 1.0, 1.0
    sr, sg, sb = 1.0, 1.0, 1.0
    if kind == DIRECTIONAL:
        dx, dy, dz = vec[0], vec[1], vec[2]
    elif kind == ENVIRONMENT:  # uniform travel direction
        dx, dy, dz = sample_uniform_sphere(u3, u4)
    elif kind == ENVIRONMENT_MAP:  # light from w travels along -w
        wx, wy, wz, lr, lg, lb, pdf = env_map_sample(env, u3, u4)
        dx, dy, dz = -wx, -wy, -wz
        if pdf > 0.0:
            sr = lr / (pdf * env.integral[0]) if env.integral[0] > 0.0 else 0.0
            sg = lg / (pdf * env.integral[1]) if env.integral[1] > 0.0 else 0.0
            sb = lb / (pdf * env.integral[2]) if env.integral[2] > 0.0 else 0.0
        else:
            sr, sg, sb = 0.0, 0.0, 0.0
    else:
        raise ValueError("unknown light kind")
    # Parallel rays through a disk of radius R perpendicular to d, 1.01 R behind the centre.
    tx, ty, tz, bx, by, bz = orthonormal_basis(dx, dy, dz)
    r = radius * math.sqrt(u1)
    px, py = r * math.cos(2 * math.pi * u2), r * math.sin(2 * math.pi * u2)
    back = 1.01 * radius
    return (cx - back * dx + px * tx + py * bx, cy - back * dy + px * ty + py * by,
            cz - back * dz + px * tz + py * bz, dx, dy, dz, sr, sg, sb)


# --- the environment ------------------------------------------------------------------------------------


def environment_index(kind: np.ndarray) -> int:
    """Index of the (single) environment light, constant or map, -1 if none. Several are merged by
    ``Scene.packed_lights``."""
    idx = np.flatnonzero((kind == ENVIRONMENT) | (kind == ENVIRONMENT_MAP))
    return int(idx[0]) if idx.size else -1
