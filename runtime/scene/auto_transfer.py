"""The ``auto`` transfer function: one keyed to the volume's histogram, so that a volume renders without hand work.

A preset has fixed control points on the normalized scalar axis, which suits the volumes it was drawn for and
nothing else: a CT normalized by its min/max has soft tissue near 0.3 and bone near 0.7, an MRI has its tissue
spread over the lower half, the embedded scenes each differ again. ``auto`` reads the positions off the data:

1. **Background.** Air around a CT, the noise floor of an MRI, the empty space of a simulation: often most of
   the volume, and any percentile taken over it would sit in the background, so it is left out of the
   statistics (and stays clear). It is every voxel within :data:`BACKGROUND` of the volume's minimum and, when
   the histogram's highest peak (of :data:`BINS` bins) lies in the lowest :data:`BACKGROUND_PEAK` of the range,
   that peak up to where its upper flank falls below :data:`PEAK_TAIL` of its height (a noise floor is a peak
   above the minimum, not at it). When every voxel is background (a constant volume), all voxels count.
2. **Visible range.** Over the remaining voxels, opacity is 0 at their :data:`LOW_PERCENTILE` and 1 at their
   :data:`HIGH_PERCENTILE`, rising as the square of the position in between (:data:`RAMP`): the bulk material
   (soft tissue, brain) is translucent and the densest few percent (bone, vessels, the cores of the embedded
   scenes) are opaque. Percentiles, not the min and max, so that a handful of outlier voxels (metal in a CT, a
   hot pixel) neither stretch the range nor become the only thing visible.
3. **Density.** ``density_scale`` is chosen so that a unit length of the *average* non-background material has
   optical depth :data:`OPTICAL_DEPTH` (clipped to :data:`DENSITY_RANGE`): too high and the volume renders as a
   solid block showing its outer surface only, too low and it renders as nothing. The longest box side is 1, so
   a ray crossing an object half the box wide meets an optical depth of about 3: dense enough to cast shadows,
   thin enough to see into.

Albedo runs from cool at the low end to warm at the high end (high throughout, since the point of the product
is multiple scattering), so that the colour tells values apart too.

The result is an ordinary :class:`TransferFunction` named ``auto``: scenes resolve it when they are built (the
volume is known then), and a scene's fingerprint and recorded spec are those of the concrete function, so a
field trained for an ``auto`` scene matches the same scene written out with explicit points.
tests/runtime/scene/test_auto_transfer.py checks the rule on a CT-like, an MRI-like and the embedded volumes.
"""

from __future__ import annotations

import numpy as np

from photon_fields.runtime.scene.transfer import AUTO, TransferFunction
from photon_fields.runtime.scene.volume import Volume

#: Normalized distance above the volume's minimum within which a voxel counts as background.
BACKGROUND = 0.02
#: Histogram bins, the part of the range where a peak counts as background, and where that peak ends.
BINS, BACKGROUND_PEAK, PEAK_TAIL = 256, 0.25, 0.05
#: Percentiles of the non-background values where opacity starts rising and where it reaches 1.
LOW_PERCENTILE, HIGH_PERCENTILE = 5.0, 99.5
#: Opacity at evenly spaced positions between the two percentiles (a quadratic ramp).
RAMP = np.linspace(0.0, 1.0, 5) ** 2
#: Optical depth of a unit length (the longest box side) of the average non-background material.
OPTICAL_DEPTH = 6.0
#: Bounds of the chosen density scale (the presets use 60 to 200).
DENSITY_RANGE = (10.0, 1000.0)
#: Voxels above which the statistics are taken on every other voxel along each axis (repeatedly).
SAMPLE_VOXELS = 1 << 22
#: Smallest width of the visible range on the normalized axis (a two-valued volume has none).
MIN_WIDTH = 0.02
_COOL, _WARM = np.array([0.55, 0.7, 0.92]), np.array([0.95, 0.82, 0.62])


def auto_transfer_function(volume: Volume, density_scale: float | None = None) -> TransferFunction:
    """The ``auto`` transfer function of ``volume`` (module docstring); ``density_scale`` overrides the chosen
    one (a scene's ``{"preset": "auto", "density_scale": 40}``)."""
    data = volume.data
    while data.size > SAMPLE_VOXELS:
        data = data[::2, ::2, ::2]
    values = np.asarray(data, dtype=np.float64).ravel()
    foreground = values[values > background_level(values)]
    if foreground.size == 0:
        foreground = values
    lo, hi = (float(v) for v in np.percentile(foreground, [LOW_PERCENTILE, HIGH_PERCENTILE]))
    hi = min(1.0, max(hi, lo + MIN_WIDTH))
    lo = max(0.0, min(lo, hi - MIN_WIDTH))
    points = np.linspace(lo, hi, RAMP.size)
    t = np.linspace(0.0, 1.0, RAMP.size)[:, None]
    albedo = (1 - t) * _COOL + t * _WARM
    if density_scale is None:
        mean_opacity = float(np.mean(np.interp(foreground, points, RAMP)))
        density_scale = float(np.clip(OPTICAL_DEPTH / max(mean_opacity, 1e-9), *DENSITY_RANGE))
    return TransferFunction(points, albedo, RAMP.copy(), density_scale, AUTO)


def background_level(values: np.ndarray) -> float:
    """The normalized value at or below which a voxel of ``values`` is background (module docstring, rule 1)."""
    lowest = float(values.min())
    counts, edges = np.histogram(values, bins=BINS, range=(0.0, 1.0))
    peak = int(np.argmax(counts))
    level = lowest + BACKGROUND
    if edges[peak] < BACKGROUND_PEAK:
        below = np.nonzero(counts[peak:] < PEAK_TAIL * counts[peak])[0]
        end = peak + int(below[0]) if below.size else BINS
        level = max(level, float(edges[end]))
    return level
