"""Frames for the page: linear radiance -> display sRGB bytes -> JPEG (or PNG when lossless is asked).

:func:`tonemap` is :func:`photon_fields.runtime.io.images.tonemap_srgb` with a fixed exposure (ACES fitted curve,
then the sRGB transfer function) in one numba pass: the numpy version's float64 temporaries cost more than a
whole 1-spp frame budget at interactive sizes. It agrees with ``tonemap_srgb`` to one code value (float32 vs
float64 rounding; tests/runtime/viewer/test_viewer_encode.py), so a screenshot's PNG, written by the shared image
writer with the same exposure, looks like what the page showed.
"""

from __future__ import annotations

import io

import numpy as np
from numba import njit, prange
from PIL import Image

from photon_fields.runtime.io.images import CURVE_WHITE

#: JPEG quality of streamed frames: no visible blocking on smooth volume shading at a few tens of kB per 512^2.
JPEG_QUALITY = 85


@njit(cache=True, parallel=True)
def _tonemap(rgb: np.ndarray, scale: float, white: float, out: np.ndarray) -> None:
    h, w = rgb.shape[0], rgb.shape[1]
    for y in prange(h):
        for x in range(w):
            finite = True
            for c in range(3):
                if not np.isfinite(rgb[y, x, c]):
                    finite = False
            for c in range(3):
                v = float(rgb[y, x, c]) * scale if finite else 0.0
                v = min(max(v, 0.0), white)
                a = v * (2.51 * v + 0.03) / (v * (2.43 * v + 0.59) + 0.14)
                a = min(max(a, 0.0), 1.0)
                e = 12.92 * a if a <= 0.0031308 else 1.055 * a ** (1.0 / 2.4) - 0.055
                out[y, x, c] = np.uint8(min(max(np.floor(e * 255.0 + 0.5), 0.0), 255.0))


def tonemap(rgb: np.ndarray, exposure_stops: float) -> np.ndarray:
    """(H, W, 3) linear radiance -> (H, W, 3) uint8 display sRGB at ``exposure_stops`` (non-finite pixels black)."""
    arr = np.ascontiguousarray(rgb, dtype=np.float32)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {arr.shape}")
    if not np.isfinite(exposure_stops):
        raise ValueError(f"exposure must be a finite number of stops, got {exposure_stops}")
    out = np.empty(arr.shape, np.uint8)
    _tonemap(arr, float(2.0 ** float(np.clip(exposure_stops, -1000.0, 1000.0))), CURVE_WHITE, out)
    return out


def encode(rgb8: np.ndarray, fmt: str = "jpeg") -> bytes:
    """``rgb8`` (H, W, 3) uint8 as JPEG (:data:`JPEG_QUALITY`) or PNG bytes."""
    buf = io.BytesIO()
    image = Image.fromarray(np.ascontiguousarray(rgb8))
    if fmt == "jpeg":
        image.save(buf, format="JPEG", quality=JPEG_QUALITY)
    elif fmt == "png":
        image.save(buf, format="PNG", compress_level=1)  # fast: frames are streamed, not archived
    else:
        raise ValueError(f"unknown frame format {fmt!r}")
    return buf.getvalue()
