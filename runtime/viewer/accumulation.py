"""One view's frames accumulated: per-layer sums of the samples rendered for it, and their mean.

A progressive renderer's frames are samples of the same image: the session adds each to the sums and shows the mean.
The first sample is kept as the renderer's float32 layers, not copied: every moving frame is the first sample of its
view, and four float64 allocations and sums cost ~8 ms at 512x512 (bench/README.md); the sums turn float64 when
the second sample arrives. A deterministic renderer's frame is its view's image: it replaces the sums.
"""

from __future__ import annotations

import numpy as np

#: The layers a frame contributes.
ACCUMULATED_LAYERS = ("L", "L_d", "L_i", "L_e")


class Accumulation:
    """``sums[layer]``: the layer summed over ``samples`` frames; ``gathered``: how many of them took the final
    gather. The session owns it (its render thread adds, ``screenshot`` reads under the session's lock)."""

    def __init__(self) -> None:
        self.sums: dict[str, np.ndarray] = {}
        self.samples = 0
        self.gathered = 0

    def clear(self) -> None:
        self.sums, self.samples, self.gathered = {}, 0, 0

    @property
    def empty(self) -> bool:
        return not self.sums

    def __getitem__(self, layer: str) -> np.ndarray:
        return self.sums[layer]

    def add(self, layers: dict[str, np.ndarray], *, gathered: bool, replace: bool) -> None:
        """One more frame: summed in, or (``replace``: a deterministic renderer's) the image itself."""
        if replace or not self.sums:  # the first sample, kept as it is: float32, no copies
            self.sums = {k: layers[k] for k in ACCUMULATED_LAYERS}
        else:
            for k in ACCUMULATED_LAYERS:
                if self.sums[k].dtype != np.float64:  # the second sample: from here on, float64 sums
                    self.sums[k] = self.sums[k].astype(np.float64)
                self.sums[k] += layers[k]
        self.samples += 1
        self.gathered += int(gathered)

    def mean(self, layer: str) -> np.ndarray | None:
        """The layer's mean, float32 (None before the first frame); a first sample as it is."""
        s = self.sums.get(layer)
        return s if s is None or s.dtype == np.float32 else (s / max(self.samples, 1)).astype(np.float32)

    def means(self) -> dict[str, np.ndarray]:
        """Every layer's mean, float32 copies."""
        return {k: (v / max(self.samples, 1)).astype(np.float32) for k, v in self.sums.items()}
