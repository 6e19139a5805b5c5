"""Henyey-Greenstein phase function (Henyey & Greenstein 1941), the phase model of the paper (Sec. 3.2).

Convention: ``cos_theta = dot(w_travel_in, w_travel_out)`` between the direction the light travelled
before and after scattering, so g > 0 is forward scattering. In a camera path the same formula is used
with the path's travel direction and the sampled continuation (HG is reciprocal).

    p_g(cos) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos)^(3/2))

Valid for g in [-1, 1]. At |g| = 1 the distribution is a Dirac delta (cos = g): ``hg_eval`` returns 0
(a delta has no density off its support) and ``sample_hg`` returns the delta direction with pdf
``inf``, which makes MIS weights degenerate to "phase sampling only", as they must.
For |g| < 1e-4 the isotropic formulas are used (the general sampling formula divides by g).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.numba_inlining import install

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

INV_4PI = 1.0 / (4.0 * math.pi)
_ISOTROPIC_EPS = 1e-4


def check_g(g: float, what: str = "g") -> float:
    """Validate a phase coefficient from user input."""
    try:
        gf = float(g)
    except (TypeError, ValueError):
        raise InputError(what, f"must be a number in [-1, 1], got {g!r}") from None
    if not (-1.0 <= gf <= 1.0):
        raise InputError(what, f"must lie in [-1, 1], got {g!r}")
    return gf


@njit(cache=True, inline="always")
def hg_eval(g: float, cos_theta: float) -> float:
    """Phase function value (= pdf of ``sample_hg``) for the given scattering cosine."""
    one_minus_g2 = 1.0 - g * g
    if one_minus_g2 <= 0.0:
        return 0.0
    denom = 1.0 + g * g - 2.0 * g * cos_theta
    return INV_4PI * one_minus_g2 / (denom * math.sqrt(denom))


@njit(cache=True, inline="always")
def hg_sample_cos(g: float, u: float) -> float:
    """Inverse-CDF sample of the scattering cosine, u uniform in [0, 1)."""
    if abs(g) < _ISOTROPIC_EPS:
        return 1.0 - 2.0 * u
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    c = (1.0 + g * g - s * s) / (2.0 * g)
    return min(1.0, max(-1.0, c))


@njit(cache=True, inline="always")
def orthonormal_basis(nx: float, ny: float, nz: float) -> tuple[float, float, float, float, float, float]:
    """Two unit vectors t, b completing n to an orthonormal frame (Duff et al. 2017, branchless)."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return 1.0 + sign * nx * nx * a, sign * b, -sign * nx, b, sign + ny * ny * a, -ny


@njit(cache=True, inline="always")
def sample_hg(g: float, dx: float, dy: float, dz: float, u1: float, u2: float) -> tuple[float, float, float, float]:
    """Sample a new travel direction around travel direction d; returns (wx, wy, wz, pdf)."""
    c = hg_sample_cos(g, u1)
    s = math.sqrt(max(0.0, 1.0 - c * c))
    phi = 2.0 * math.pi * u2
    tx, ty, tz, bx, by, bz = orthonormal_basis(dx, dy, dz)
    cp, sp = math.cos(phi) * s, math.sin(phi) * s
    wx = cp * tx + sp * bx + c * dx
    wy = cp * ty + sp * by + c * dy
    wz = cp * tz + sp * bz + c * dz
    inv = 1.0 / math.sqrt(wx * wx + wy * wy + wz * wz)
    pdf = hg_eval(g, c) if 1.0 - g * g > 0.0 else math.inf
    return wx * inv, wy * inv, wz * inv, pdf


@njit(cache=True)
def hg_eval_batch(g: float, cos_theta: np.ndarray) -> np.ndarray:
    out = np.empty(cos_theta.shape[0])
    for i in range(cos_theta.shape[0]):
        out[i] = hg_eval(g, cos_theta[i])
    return out


@njit(cache=True)
def sample_hg_batch(g: float, d: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Batch form for tests and tools: d (3, n) travel directions, u (n, 2) uniforms -> (4, n) [w; pdf]."""
    n = d.shape[1]
    out = np.empty((4, n))
    for i in range(n):
        out[0, i], out[1, i], out[2, i], out[3, i] = sample_hg(g, d[0, i], d[1, i], d[2, i], u[i, 0], u[i, 1])
    return out
