"""Next-event estimation: light arriving at a scattering vertex directly from every light source.

For a vertex at ``p`` reached by a path travelling along ``d``, :func:`direct_light` returns

    sum over lights  f_g(d . l) * Le * Tr(p -> light)        (point: Le = I / r^2; directional: Le = E)
    + for the environment: f_g(d . l) * L_env * Tr / pdf_l * w_nee,   l ~ uniform sphere, pdf_l = 1/(4 pi)

without the path throughput. Transmittance is estimated by ratio tracking. Delta lights (point and
directional) can only be reached by NEE, so their weight is 1. The environment can also be reached by
phase sampling; both strategies are combined with the power heuristic (Veach 1997):
``w_nee = pdf_l^2 / (pdf_l^2 + pdf_phase^2)``, and the phase-sampled escape gets the complement
(:func:`mis_weight_phase`). Used by the reference path tracer and, at the first vertex, by the neural
renderer (paper Sec. 3.6, "Direct Illumination").
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.scene.lights import DIRECTIONAL, ENVIRONMENT, POINT
from photon_fields.runtime.transport.medium import Medium, intersect_box
from photon_fields.runtime.transport.phase import INV_4PI, hg_eval
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import ratio_track


@njit(cache=True, inline="always")
def mis_weight_phase(pdf_phase: float, pdf_light: float) -> float:
    """Power-heuristic weight of a phase-sampled direction that escapes to the environment."""
    if math.isinf(pdf_phase):
        return 1.0
    a = pdf_phase * pdf_phase
    return a / (a + pdf_light * pdf_light)


@njit(cache=True, inline="always")
def delta_light_direction(kind: int, pos_or_dir: np.ndarray, px: float, py: float,
                          pz: float) -> tuple[float, float, float, float, float]:
    """Towards a delta light from p: (lx, ly, lz, falloff, distance). Point: falloff 1/r^2 and the
    distance to the light; directional: falloff 1 and inf. Falloff 0 means 'no contribution' (p on
    the light, or not a delta light)."""
    if kind == POINT:
        lx, ly, lz = pos_or_dir[0] - px, pos_or_dir[1] - py, pos_or_dir[2] - pz
        dist2 = lx * lx + ly * ly + lz * lz
        if dist2 <= 0.0:
            return 0.0, 0.0, 1.0, 0.0, 0.0
        dist = math.sqrt(dist2)
        return lx / dist, ly / dist, lz / dist, 1.0 / dist2, dist
    if kind == DIRECTIONAL:
        return -pos_or_dir[0], -pos_or_dir[1], -pos_or_dir[2], 1.0, math.inf
    return 0.0, 0.0, 1.0, 0.0, 0.0


@njit(cache=True)
def direct_light(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, px: float, py: float,
                 pz: float, dx: float, dy: float, dz: float, state: np.uint64,
                 env_mis: bool) -> tuple[float, float, float, np.uint64]:
    r = 0.0
    gr = 0.0
    b = 0.0
    for k in range(kind.shape[0]):
        if kind[k] != ENVIRONMENT:
            lx, ly, lz, scale, tend = delta_light_direction(kind[k], vec[k], px, py, pz)
        else:  # ENVIRONMENT: uniform direction, MIS against phase sampling
            state, u1 = next_float(state)
            state, u2 = next_float(state)
            lz = 1.0 - 2.0 * u1
            s = math.sqrt(max(0.0, 1.0 - lz * lz))
            lx, ly = s * math.cos(2.0 * math.pi * u2), s * math.sin(2.0 * math.pi * u2)
            pdf_l = INV_4PI
            w = 1.0
            if env_mis:
                w = 1.0 - mis_weight_phase(hg_eval(g, dx * lx + dy * ly + dz * lz), pdf_l)
            scale = w / pdf_l
            tend = math.inf
        f = hg_eval(g, dx * lx + dy * ly + dz * lz)
        if f * scale <= 0.0 or (rgb[k, 0] + rgb[k, 1] + rgb[k, 2]) <= 0.0:
            continue
        t0, t1 = intersect_box(m, px, py, pz, lx, ly, lz)
        tr = 1.0
        if t0 < t1:
            tr, state = ratio_track(m, px, py, pz, lx, ly, lz, t0, min(t1, tend), state)
        c = f * scale * tr
        r += c * rgb[k, 0]
        gr += c * rgb[k, 1]
        b += c * rgb[k, 2]
    return r, gr, b, state


@njit(cache=True, parallel=True)
def direct_light_batch(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, o: np.ndarray,
                       d: np.ndarray, states: np.ndarray, env_mis: bool = True) -> np.ndarray:
    """Stage: NEE at every vertex of a SoA batch; returns radiance (3, n) (times throughput later).
    ``env_mis=False`` gives the environment's NEE full weight, for estimators that never reach the
    environment by phase sampling (the first-interaction renderers)."""
    n = o.shape[1]
    out = np.empty((3, n))
    for i in prange(n):
        out[0, i], out[1, i], out[2, i], states[i] = direct_light(
            m, kind, vec, rgb, g, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i], states[i], env_mis)
    return out


def environment_index(kind: np.ndarray) -> int:
    """Index of the (single) environment light, -1 if none. Several are merged by ``pack_scene_lights``."""
    idx = np.flatnonzero(kind == ENVIRONMENT)
    return int(idx[0]) if idx.size else -1
