"""One interface over the two lighting bases (DSF, Sec. 5; SH, Sec. 6.1): a lighting is a coefficient array
``(m, 3)`` (RGB per basis light) and each basis light ``k`` is the distant radiance ``B_k(w)`` arriving from
direction ``w``. The transfer (``runtime/pvrt/precompute.py``) holds each voxel's response to each ``B_k``, so a
lighting's response is ``sum_k coeff_k * response_k`` (Eq. 15).

- :meth:`LightingBasis.project_directional`: a directional light of irradiance E arriving from ``w_l``, a delta
  ``E delta(w - w_l)``: SH coefficients ``E Y_k(w_l)``; DSF: the three basis lights of the icosahedral triangle
  holding ``w_l`` with its barycentric weights ``b_k`` (Sec. 8.2), scaled so that the flux is kept:
  ``s_k = E b_k / Omega_k`` (``integral B_k = Omega_k``).
- :meth:`LightingBasis.project_sky`: a sky ``L(w)`` (a callable on directions): SH by quadrature,
  ``c_k = integral L Y_k``; DSF by the prefiltering of Sec. 8.1 with the basis' own kernel as the filter,
  ``s_k = integral L wbar_k / Omega_k`` (a local mean around ``w_k`` of radius ``h``; a constant sky gives
  ``s_k = L`` exactly).
- :meth:`LightingBasis.rotate`: the coefficients of the lighting rotated by ``R`` (``L'(w) = L(R^T w)``). DSF
  (Sec. 5.1, "rotate the prefiltered environment light and sample it again"): ``s'_k = S(R^T w_k)`` by Eq. 7; SH:
  the rotation matrix ``M_jk = integral Y_j(w) Y_k(R^T w) dw`` (block-diagonal by band, orthogonal).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.pvrt.constants import BASIS_KINDS, DSF_ORDERS, SH_ORDERS, SPHERE_QUADRATURE
from photon_fields.runtime.pvrt.dsf import DSF, fibonacci_sphere
from photon_fields.runtime.pvrt.sh import sh_basis, sh_count

#: A sky: unit directions (n, 3) the light arrives from -> RGB radiance (n, 3).
SkyFunction = Callable[[np.ndarray], np.ndarray]


def check_basis(kind: str, order: int, what: str = "basis") -> tuple[str, int]:
    """A known basis kind and an order in its range, or a one-line InputError."""
    if kind not in BASIS_KINDS:
        raise InputError(what, f"unknown basis {kind!r} (expected one of {', '.join(BASIS_KINDS)})")
    lo, hi = DSF_ORDERS if kind == "dsf" else SH_ORDERS
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or not lo <= order <= hi:
        meaning = "icosahedral subdivision level" if kind == "dsf" else "SH band limit l_max"
        raise InputError(f"{what} order", f"a {kind} order ({meaning}) must be an integer in [{lo}, {hi}], "
                         f"got {order!r}")
    return kind, int(order)


@dataclass(frozen=True, eq=False)
class LightingBasis:
    kind: str
    order: int
    dsf: DSF | None = None
    _quad: np.ndarray = field(default_factory=lambda: fibonacci_sphere(SPHERE_QUADRATURE), repr=False)

    @property
    def size(self) -> int:
        """m, the number of basis lights."""
        return self.dsf.size if self.dsf is not None else sh_count(self.order)

    @property
    def resolution(self) -> float:
        """The angular detail the basis resolves, radians: a DSF basis light's cone radius h, or pi / (l_max + 1)
        for SH (the width of its finest band's lobes)."""
        return float(self.dsf.h) if self.dsf is not None else math.pi / (self.order + 1)

    def evaluate(self, w: np.ndarray) -> np.ndarray:
        """B_k(w) at unit directions (q, 3) the light arrives from: (q, m)."""
        return self.dsf.evaluate(w) if self.dsf is not None else sh_basis(self.order, w)

    def reconstruct(self, coeffs: np.ndarray, w: np.ndarray) -> np.ndarray:
        """The lighting ``sum_k coeffs_k B_k(w)`` at directions (q, 3): (q, 3) RGB."""
        return self.evaluate(w) @ np.asarray(coeffs, dtype=np.float64).reshape(self.size, -1)

    def project_directional(self, towards_light: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        """Coefficients (m, 3) of a directional light of irradiance ``rgb`` arriving from ``towards_light``."""
        w = np.asarray(towards_light, dtype=np.float64)
        w = w / np.linalg.norm(w)
        out = np.zeros((self.size, 3))
        if self.dsf is None:
            out += sh_basis(self.order, w[None])[0][:, None] * np.asarray(rgb)[None, :]
            return out
        idx, bary = self.dsf.barycentric(w)
        out[idx] = (bary / self.dsf.solid_angle[idx])[:, None] * np.asarray(rgb)[None, :]
        return out

    def project_sky(self, sky: SkyFunction) -> np.ndarray:
        """Coefficients (m, 3) of the sky ``sky(w) -> (n, 3)`` (module docstring)."""
        q = self._quad
        values = np.asarray(sky(q), dtype=np.float64)
        if values.shape != (len(q), 3) or not np.all(np.isfinite(values)):
            raise InputError("sky", f"a sky function must return finite RGB radiance of shape (n, 3) for n "
                             f"directions, got shape {values.shape}")
        b = self.evaluate(q) * (4.0 * math.pi / len(q))  # (q, m) quadrature-weighted basis
        proj = b.T @ values
        if self.dsf is not None:
            proj /= self.dsf.solid_angle[:, None]
        return proj

    def rotate(self, coeffs: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """Coefficients of the lighting rotated by the 3x3 rotation ``rotation`` (module docstring)."""
        r = np.asarray(rotation, dtype=np.float64)
        c = np.asarray(coeffs, dtype=np.float64).reshape(self.size, -1)
        if self.dsf is not None:
            return self.dsf.evaluate(self.dsf.dirs @ r) @ c  # S(R^T w_k): rows of dirs times R = (R^T w_k)^T
        return sh_rotation(self.order, r, self._quad) @ c


def sh_rotation(lmax: int, rotation: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """M_jk = integral Y_j(w) Y_k(R^T w) dw by quadrature, projected onto the nearest orthogonal block per band."""
    y = sh_basis(lmax, quad)
    y_rot = sh_basis(lmax, quad @ np.asarray(rotation))
    m = y.T @ y_rot * (4.0 * math.pi / len(quad))
    out = np.zeros_like(m)
    for band in range(lmax + 1):  # exact rotations do not mix bands, and each band's block is orthogonal
        s = slice(band * band, (band + 1) ** 2)
        u, _, vt = np.linalg.svd(m[s, s])
        out[s, s] = u @ vt
    return out


@lru_cache(maxsize=8)
def make_basis(kind: str, order: int) -> LightingBasis:
    """The lighting basis ``kind`` ("dsf" or "sh") of ``order`` (checked; built once per process)."""
    kind, order = check_basis(kind, order)
    return LightingBasis(kind, order, DSF.build(order) if kind == "dsf" else None)
