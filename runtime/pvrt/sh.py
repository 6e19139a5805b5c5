"""Real spherical harmonics (paper Sec. 6.1, Eq. 9), orthonormal on the unit sphere.

``Y_j`` with ``j = l (l + 1) + m`` for ``l = 0 .. l_max``, ``m = -l .. l``:

    Y_l^m = sqrt(2) K_l^m cos(m phi) P_l^m(cos theta)     (m > 0)
    Y_l^0 = K_l^0 P_l^0(cos theta)
    Y_l^m = sqrt(2) K_l^|m| sin(|m| phi) P_l^|m|(cos theta)   (m < 0)

with ``K_l^m = sqrt((2l + 1) / (4 pi) (l - m)! / (l + m)!)`` and ``P_l^m`` the associated Legendre functions
(by the stable three-term recurrence). They are the radiant-exitance basis (Sec. 6.1: "we choose the SH basis to
approximate the 2D spherical function of the radiant exitance") and the lighting basis the paper compares DSF with.

The Henyey-Greenstein phase function is a zonal kernel whose SH coefficients are ``g^l`` (Funk-Hecke), so the
exitance of incident radiance ``L_lm`` is ``g^l L_lm``: :func:`hg_band_factors`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from photon_fields.runtime.pvrt.constants import EXITANCE_ORDERS


def sh_count(lmax: int) -> int:
    """Number of coefficients up to band ``lmax``: (lmax + 1)^2."""
    return (lmax + 1) ** 2


@njit(cache=True)
def sh_eval(lmax: int, x: float, y: float, z: float, out: np.ndarray) -> None:
    """Write Y_0 .. Y_{(lmax+1)^2 - 1} at the unit direction (x, y, z) into ``out``."""
    ct = min(1.0, max(-1.0, z))
    st = math.sqrt(max(0.0, 1.0 - ct * ct))
    phi = math.atan2(y, x)
    # P_m^m, then up in l for each m (Numerical Recipes' plgndr recurrence, with the Condon-Shortley phase).
    pmm = 1.0
    for m in range(lmax + 1):
        if m > 0:
            pmm *= -(2.0 * m - 1.0) * st
        p_prev2 = 0.0
        p_prev = pmm
        for l in range(m, lmax + 1):  # noqa: E741  (l is the band, as in every SH text)
            if l == m:
                p = pmm
            elif l == m + 1:
                p = ct * (2.0 * m + 1.0) * pmm
            else:
                p = (ct * (2.0 * l - 1.0) * p_prev - (l + m - 1.0) * p_prev2) / (l - m)
            if l > m:
                p_prev2 = p_prev
                p_prev = p
            ratio = math.exp(math.lgamma(l - m + 1.0) - math.lgamma(l + m + 1.0))
            k = math.sqrt((2.0 * l + 1.0) / (4.0 * math.pi) * ratio)
            base = l * (l + 1)
            if m == 0:
                out[base] = k * p
            else:
                out[base + m] = math.sqrt(2.0) * k * math.cos(m * phi) * p
                out[base - m] = math.sqrt(2.0) * k * math.sin(m * phi) * p


@njit(cache=True)
def _sh_batch(lmax: int, dirs: np.ndarray) -> np.ndarray:
    n = dirs.shape[0]
    out = np.empty((n, (lmax + 1) ** 2))
    for i in range(n):
        sh_eval(lmax, dirs[i, 0], dirs[i, 1], dirs[i, 2], out[i])
    return out


def sh_basis(lmax: int, dirs: np.ndarray) -> np.ndarray:
    """Y_j at unit directions ``dirs`` (n, 3): (n, (lmax + 1)^2)."""
    return _sh_batch(int(lmax), np.ascontiguousarray(dirs, dtype=np.float64).reshape(-1, 3))


def sh_band(lmax: int) -> np.ndarray:
    """The band l of every coefficient j: (sh_count(lmax),) int."""
    return np.concatenate([np.full(2 * l + 1, l) for l in range(lmax + 1)])


def hg_band_factors(g: float, lmax: int) -> np.ndarray:
    """SH coefficients of the HG phase convolution, ``g^l`` per coefficient (Funk-Hecke): the exitance towards
    travel direction w is sum_j g^l(j) L_j Y_j(w) for incident radiance L_j (as a function of travel direction)."""
    return np.power(float(g), sh_band(lmax).astype(np.float64)) if g != 0 else (sh_band(lmax) == 0).astype(float)


def auto_exitance_order(g: float, tolerance: float) -> int:
    """The least SH band limit whose first dropped band weighs at most ``tolerance`` in the phase convolution:
    the least l_max with |g|^(l_max + 1) <= tolerance (the HG factors :func:`hg_band_factors` fall as g^l), capped
    at the largest order the transfer takes. g = 0 gives 0: an isotropic phase function reads band 0 only, so the
    other bands would be stored, traced and compressed for nothing."""
    lo, hi = EXITANCE_ORDERS
    a = abs(float(g))
    for lmax in range(lo, hi):
        if a ** (lmax + 1) <= tolerance:
            return lmax
    return hi
