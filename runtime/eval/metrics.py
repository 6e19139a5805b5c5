"""Image error metrics used to judge a renderer against a reference (benchmarks, evaluation, regression tests).

- :func:`relative_l2`: ``||img - ref||_2 / ||ref||_2`` over all pixels and channels of the *linear* HDR
  images (what the estimators compute; the paper's "relative L2").
- :func:`ssim`: the structural similarity index of Wang et al. (2004) on what a person sees: both images
  tone-mapped with the *reference's* automatic exposure (:func:`display_image`, the PNG pipeline of
  :mod:`photon_fields.runtime.io.images` without the uint8 rounding), so an image that is too bright or too dark scores
  lower. Gaussian window sigma 1.5 (11 taps), K1 = 0.01, K2 = 0.03, data range 1, population covariances,
  mean over the channels and over the pixels at least 5 pixels from the border: scikit-image's
  ``structural_similarity(..., gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
  data_range=1, channel_axis=2)``, to which ``tests/runtime/eval/test_metrics.py`` compares it. Implemented here with
  scipy so the runtime needs no scikit-image.

Images are (H, W, 3) or (H, W) float arrays; non-finite pixels count as errors (relative L2 becomes inf,
SSIM treats them as black after tone mapping).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter

from photon_fields.runtime.io.images import CURVE_WHITE, aces_fitted, auto_exposure_scale, srgb_oetf

SSIM_SIGMA = 1.5
SSIM_TRUNCATE = 3.5  # 2 * int(3.5 * 1.5 + 0.5) + 1 = 11 taps, as scikit-image
SSIM_K1, SSIM_K2 = 0.01, 0.03


def _pair(img: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(img, dtype=np.float64)
    b = np.asarray(ref, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"image and reference differ in shape: {a.shape} vs {b.shape}")
    if a.ndim == 2:
        a, b = a[:, :, None], b[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3):
        raise ValueError(f"expected (H, W, 3) or (H, W) images, got {np.asarray(img).shape}")
    return a, b


def relative_l2(img: np.ndarray, ref: np.ndarray) -> float:
    """``||img - ref|| / ||ref||`` over all values (linear radiance); inf if the reference is black."""
    a, b = _pair(img, ref)
    den = float(np.sqrt(np.sum(b * b)))
    num = float(np.sqrt(np.sum((a - b) ** 2)))
    return num / den if den > 0 else (0.0 if num == 0 else float("inf"))


def display_image(rgb: np.ndarray, scale: float) -> np.ndarray:
    """Linear radiance -> display sRGB in [0, 1] (float) with exposure factor ``scale``: the PNG curve."""
    a = np.asarray(rgb, dtype=np.float64)
    finite = np.isfinite(a)
    a = np.where(finite, a, 0.0)
    return srgb_oetf(aces_fitted(np.clip(a * scale, 0.0, CURVE_WHITE)))


def ssim(img: np.ndarray, ref: np.ndarray) -> float:
    """Mean SSIM of ``img`` against ``ref`` after tone mapping both with the reference's exposure."""
    a, b = _pair(img, ref)
    rgb = b if b.shape[2] == 3 else np.repeat(b, 3, axis=2)
    scale = auto_exposure_scale(rgb, np.all(np.isfinite(rgb), axis=2))
    return ssim_display(display_image(a, scale), display_image(b, scale))


def ssim_display(x: np.ndarray, y: np.ndarray) -> float:
    """SSIM of two display images with values in [0, 1] (data range 1), (H, W, C) or (H, W)."""
    x, y = _pair(x, y)
    pad = int(SSIM_TRUNCATE * SSIM_SIGMA + 0.5)
    if min(x.shape[:2]) <= 2 * pad:
        raise ValueError(f"images must be larger than {2 * pad}x{2 * pad} pixels for SSIM, got {x.shape[:2]}")
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    scores = []
    for c in range(x.shape[2]):
        def blur(v: np.ndarray) -> np.ndarray:
            return gaussian_filter(v, SSIM_SIGMA, truncate=SSIM_TRUNCATE, mode="reflect")

        xc, yc = x[:, :, c], y[:, :, c]
        mx, my = blur(xc), blur(yc)
        vx = blur(xc * xc) - mx * mx
        vy = blur(yc * yc) - my * my
        cxy = blur(xc * yc) - mx * my
        s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
        scores.append(float(s[pad:-pad, pad:-pad].mean()))
    return float(np.mean(scores))
