"""Frames for the page: linear radiance -> display sRGB bytes -> JPEG (or PNG when lossless is asked).

:func:`tonemap` is :func:`photon_fields.runtime.io.images.tonemap_srgb` with a fixed exposure (ACES fitted curve,
then the sRGB transfer function) in one numba pass: the numpy version's float64 temporaries cost more than a
whole 1-spp frame budget at interactive sizes. The curve and the transfer function together are a monotone step
function from the exposed radiance to the 256 codes, so the pass does not evaluate them per pixel (a power per
channel cost more than the JPEG encoder): :func:`_code_thresholds` finds the least radiance of each code by
bisection on the same float64 arithmetic, and each channel's code is the number of thresholds at or below its
value, counted from a table indexed by the value's top 16 bits (sign, exponent and 7 mantissa bits: the code at
the bin's lower edge) and then over the thresholds inside the bin (rarely more than one). One table read per
channel, and the same codes as evaluating the curve (tests/runtime/viewer/test_viewer_encode.py). It agrees with
``tonemap_srgb`` to one code value (float32 vs float64 rounding), so a screenshot's PNG, written by the shared
image writer with the same exposure, looks like what the page showed.
"""

from __future__ import annotations

import functools
import io

import numpy as np
from numba import njit, prange
from PIL import Image

from photon_fields.runtime.io.images import CURVE_WHITE

#: JPEG quality of streamed frames: no visible blocking on smooth volume shading at a few tens of kB per 512^2.
JPEG_QUALITY = 85


@njit(cache=True)
def _code(v: float, white: float) -> int:
    """The display code of exposed radiance ``v``: the ACES fitted curve on [0, white], then sRGB, rounded."""
    v = min(max(v, 0.0), white)
    a = v * (2.51 * v + 0.03) / (v * (2.43 * v + 0.59) + 0.14)
    a = min(max(a, 0.0), 1.0)
    e = 12.92 * a if a <= 0.0031308 else 1.055 * a ** (1.0 / 2.4) - 0.055
    return int(min(max(np.floor(e * 255.0 + 0.5), 0.0), 255.0))


@njit(cache=True)
def _code_thresholds(white: float) -> np.ndarray:
    """thresholds[k - 1] = the least exposed radiance whose code is >= k (k = 1 .. 255; inf past the curve's
    range), by bisection over [0, white] (the code is monotone in the radiance); thresholds[255] = inf pads the
    table to 256 for the tone map's fixed eight halving steps."""
    out = np.full(256, np.inf)
    for k in range(1, 256):
        if _code(white, white) < k:
            continue
        lo, hi = 0.0, white
        if _code(lo, white) >= k:
            out[k - 1] = lo
            continue
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if _code(mid, white) >= k:
                hi = mid
            else:
                lo = mid
        out[k - 1] = hi
    return out


@njit(cache=True, parallel=True)
def _tonemap(rgb: np.ndarray, bits: np.ndarray, bins: np.ndarray, limits: np.ndarray, out: np.ndarray) -> None:
    """``out`` = the number of ``limits`` (256, ascending, in units of ``rgb``, the last inf) at or below each
    channel's value: from ``bins`` (the count at the lower edge of each of the 2^15 positive float32 bins of equal
    top 16 bits; ``bits`` is ``rgb`` viewed as uint32), then over the limits inside the bin; non-finite pixels and
    values <= 0 black."""
    h, w = rgb.shape[0], rgb.shape[1]
    sign = np.uint32(0x80000000)
    shift = np.uint32(16)
    for y in prange(h):
        for x in range(w):
            finite = True
            for c in range(3):
                if not np.isfinite(rgb[y, x, c]):
                    finite = False
            for c in range(3):
                code = 0
                b = bits[y, x, c]
                if finite and b < sign:
                    v = rgb[y, x, c]
                    code = bins[b >> shift]
                    while limits[code] <= v:
                        code += 1
                out[y, x, c] = np.uint8(code)


def tonemap(rgb: np.ndarray, exposure_stops: float) -> np.ndarray:
    """(H, W, 3) linear radiance -> (H, W, 3) uint8 display sRGB at ``exposure_stops`` (non-finite pixels black)."""
    arr = np.ascontiguousarray(rgb, dtype=np.float32)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {arr.shape}")
    if not np.isfinite(exposure_stops):
        raise ValueError(f"exposure must be a finite number of stops, got {exposure_stops}")
    out = np.empty(arr.shape, np.uint8)
    bins, limits = _tables(float(2.0 ** float(np.clip(exposure_stops, -1000.0, 1000.0))))
    _tonemap(arr, arr.view(np.uint32), bins, limits, out)
    return out


@functools.lru_cache(maxsize=1)
def _thresholds(white: float) -> np.ndarray:
    """:func:`_code_thresholds` (the exposed radiance of each code), once per white point."""
    return _code_thresholds(white)


@functools.lru_cache(maxsize=8)
def _tables(scale: float) -> tuple[np.ndarray, np.ndarray]:
    """For an exposure ``scale``: the codes' thresholds in units of the frame (256, float64, the last inf) and the
    code at the lower edge of every positive finite float32 bin of equal top 16 bits (the others unused: 0)."""
    limits = _thresholds(CURVE_WHITE) / scale
    edges = (np.arange(0x7F80, dtype=np.uint32) << np.uint32(16)).view(np.float32).astype(np.float64)
    bins = np.zeros(1 << 15, np.int64)
    bins[:0x7F80] = np.minimum(np.searchsorted(limits, edges, side="right"), 255)
    limits.setflags(write=False)
    bins.setflags(write=False)
    return bins, limits


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
