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

LAYERS = ("L_e", "L_d", "L_i")


class Film:
    def __init__(self, width: int, height: int) -> None:
        self.width, self.height = width, height
        self.acc = {name: np.zeros((3, width * height)) for name in LAYERS}
        self.samples = 0

    def splat(self, layer: str, pixel: np.ndarray, rgb: np.ndarray) -> None:
        """Add rgb (3, n) contributions at flat pixel indices ``pixel`` (n,); repeated pixels add up."""
        if pixel.shape[0] == 0:
            return
        acc = self.acc[layer]
        for c in range(3):
            acc[c] += np.bincount(pixel, weights=rgb[c], minlength=acc.shape[1])

    def splat_by_depth(self, depth: np.ndarray, pixel: np.ndarray, rgb: np.ndarray) -> None:
        """Route contributions of paths with ``depth`` scattering vertices to L_e / L_d / L_i."""
        for layer, sel in (("L_e", depth == 0), ("L_d", depth == 1), ("L_i", depth >= 2)):
            if np.any(sel):
                self.splat(layer, pixel[sel], rgb[:, sel])

    def layers(self) -> dict[str, np.ndarray]:
        """Mean estimates as (H, W, 3) float32 arrays, plus the total L."""
        scale = 1.0 / max(self.samples, 1)
        out = {name: (a * scale).T.reshape(self.height, self.width, 3).astype(np.float32)
               for name, a in self.acc.items()}
        out["L"] = out["L_e"] + out["L_d"] + out["L_i"]
        return {k: out[k] for k in ("L", "L_d", "L_i", "L_e")}
