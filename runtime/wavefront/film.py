"""Per-pixel accumulation of radiance estimates, split by path class.

Layers (each RGB, float64 accumulators, divided by the sample count on read-out):

- ``L_e``: radiance reaching the camera with no scattering (the environment seen through the volume).
- ``L_d``: paths with exactly one scattering vertex: direct light in-scattered at the first interaction.
- ``L_i``: paths with two or more scattering vertices: the multiple-scattering term the photon field
  replaces (paper Eq. 3-4).
- ``L = L_e + L_d + L_i``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

LAYERS = ("L_e", "L_d", "L_i")


class Film:
    def __init__(self, width: int, height: int) -> None:
        self.width, self.height = width, height
        self.acc = {name: np.zeros((3, width * height)) for name in LAYERS}
        self.samples = 0

    def splat(self, layer: str, pixel: np.ndarray, rgb: np.ndarray, distinct: bool = False,
              weight: np.ndarray | None = None) -> None:
        """Add rgb (3, n) contributions at flat pixel indices ``pixel`` (n,); repeated pixels add up.
        ``weight`` (3, n), if given, multiplies them first (``weight * rgb`` in float64, as numpy would).

        ``distinct=True`` promises that no pixel repeats (a batch of at most one sample per pixel): each
        contribution is then added straight into the accumulator, which is the same sum bit for bit as
        ``acc += bincount(...)`` (that adds ``0 + v`` to the pixel, and ``0 + v == v`` whenever the
        accumulator, which never holds -0, does not depend on the sign of a zero), without bincount's three
        full-film temporaries."""
        if pixel.shape[0] == 0:
            return
        acc = self.acc[layer]
        if distinct:
            _add_at_distinct(acc, pixel, rgb, np.ones((3, 1)) if weight is None else weight, weight is not None)
            return
        if weight is not None:
            rgb = weight * rgb
        for c in range(3):
            acc[c] += np.bincount(pixel, weights=rgb[c], minlength=acc.shape[1])

    def splat_by_depth(self, depth: np.ndarray, pixel: np.ndarray, rgb: np.ndarray) -> None:
        """Route contributions of paths with ``depth`` scattering vertices to L_e / L_d / L_i."""
        for layer, sel in (("L_e", depth == 0), ("L_d", depth == 1), ("L_i", depth >= 2)):
            if np.any(sel):
                self.splat(layer, pixel[sel], rgb[:, sel])

    def layers(self) -> dict[str, np.ndarray]:
        """Mean estimates as (H, W, 3) float32 arrays, plus the total L.

        One numba pass over the accumulators (:func:`_mean_layers`), the same roundings as the numpy
        ``(acc * scale).T.reshape(H, W, 3).astype(float32)`` per layer and ``(L_e + L_d) + L_i`` in float32,
        without its float64 temporaries."""
        scale = 1.0 / max(self.samples, 1)
        out = {name: np.empty((self.height, self.width, 3), np.float32) for name in ("L", "L_d", "L_i", "L_e")}
        _mean_layers(self.acc["L_e"], self.acc["L_d"], self.acc["L_i"], scale, out["L_e"].reshape(-1, 3),
                     out["L_d"].reshape(-1, 3), out["L_i"].reshape(-1, 3), out["L"].reshape(-1, 3))
        return out

@njit(cache=True)
def _add_at_distinct(acc: np.ndarray, pixel: np.ndarray, rgb: np.ndarray, weight: np.ndarray,
                     weighted: bool) -> None:
    # Serial: a few 10k scattered adds take well under a millisecond, no parallel region to wake. The
    # product is float64 (float32 rgb is widened first), the same rounding as numpy's weight * rgb.
    for i in range(pixel.shape[0]):
        p = pixel[i]
        if weighted:
            acc[0, p] += weight[0, i] * np.float64(rgb[0, i])
            acc[1, p] += weight[1, i] * np.float64(rgb[1, i])
            acc[2, p] += weight[2, i] * np.float64(rgb[2, i])
        else:
            acc[0, p] += rgb[0, i]
            acc[1, p] += rgb[1, i]
            acc[2, p] += rgb[2, i]


#: Pixels per task of :func:`_mean_layers`.
_MEAN_BLOCK = 16384


@njit(cache=True, parallel=True)
def _mean_layers(acc_e: np.ndarray, acc_d: np.ndarray, acc_i: np.ndarray, scale: float, e: np.ndarray, d: np.ndarray,
                 i: np.ndarray, total: np.ndarray) -> None:
    # In blocks of pixels, one parallel region: the read-out of a 512x512 film streams 19 MB of accumulators.
    n = acc_e.shape[1]
    for block in prange((n + _MEAN_BLOCK - 1) // _MEAN_BLOCK):
        for p in range(block * _MEAN_BLOCK, min(n, (block + 1) * _MEAN_BLOCK)):
            for c in range(3):
                e[p, c] = np.float32(acc_e[c, p] * scale)
                d[p, c] = np.float32(acc_d[c, p] * scale)
                i[p, c] = np.float32(acc_i[c, p] * scale)
                total[p, c] = (e[p, c] + d[p, c]) + i[p, c]
