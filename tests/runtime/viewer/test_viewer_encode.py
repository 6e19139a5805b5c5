"""Frame encoding (runtime/viewer/encode.py): the fast tone map matches the shared one, PNG is lossless."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from photon_fields.runtime.io.images import CURVE_WHITE, tonemap_srgb
from photon_fields.runtime.viewer.encode import _code, _code_thresholds, encode, tonemap


@pytest.mark.parametrize("stops", [-3.0, 0.0, 1.7, 6.0])
def test_tonemap_matches_the_shared_tone_map(stops: float) -> None:
    rng = np.random.default_rng(1)
    rgb = (rng.lognormal(-1.0, 1.5, (37, 53, 3))).astype(np.float32)
    rgb[0, 0] = [np.nan, 1.0, 1.0]
    rgb[1, 1] = [np.inf, 0.0, 0.0]
    rgb[2, 2] = [-1.0, 0.0, 5.0]
    ours, ref = tonemap(rgb, stops).astype(int), tonemap_srgb(rgb, stops).astype(int)
    assert np.abs(ours - ref).max() <= 1
    assert np.mean(ours == ref) > 0.99
    assert ours[0, 0].tolist() == [0, 0, 0] and ours[1, 1].tolist() == [0, 0, 0]


def test_png_frames_are_lossless_and_jpeg_close() -> None:
    rgb8 = tonemap(np.random.default_rng(2).random((20, 30, 3), dtype=np.float32), 0.0)
    back = np.asarray(Image.open(io.BytesIO(encode(rgb8, "png"))))
    assert np.array_equal(back, rgb8)
    jpeg = np.asarray(Image.open(io.BytesIO(encode(rgb8, "jpeg"))))
    assert jpeg.shape == rgb8.shape
    with pytest.raises(ValueError):
        encode(rgb8, "gif")


def test_thresholds_are_where_each_code_begins() -> None:
    """thresholds[k - 1] is the least exposed radiance of code k: the curve gives k there and k - 1 one float
    below (or the code is beyond the curve's range: inf)."""
    limits = _code_thresholds(CURVE_WHITE)
    assert limits.shape == (256,) and np.isinf(limits[255]) and np.all(np.diff(limits[np.isfinite(limits)]) > 0)
    for k in range(1, 256):
        t = limits[k - 1]
        if np.isinf(t):
            assert _code(CURVE_WHITE, CURVE_WHITE) < k
            continue
        assert _code(t, CURVE_WHITE) >= k and _code(np.nextafter(t, -np.inf), CURVE_WHITE) < k, k


@pytest.mark.parametrize("stops", [-40.0, -3.0, 0.0, 1.7, 6.0, 40.0])
def test_table_driven_codes_equal_the_curve_per_value(stops: float) -> None:
    """The pass's table lookup against the curve evaluated at every value (exposed in float64, as the curve
    is): the same code except where a value lies within a rounding of a threshold."""
    rng = np.random.default_rng(3)
    rgb = rng.lognormal(-1.0, 2.5, (60, 70, 3)).astype(np.float32) * np.float32(2.0 ** -stops)
    rgb[::9, ::4] = 0.0
    rgb[::7, ::5, 1] = -1.0
    scale = 2.0 ** stops
    direct = np.array([_code(float(v) * scale, CURVE_WHITE) for v in rgb.reshape(-1)]).reshape(rgb.shape)
    ours = tonemap(rgb, stops).astype(int)
    assert np.abs(ours - direct).max() <= 1
    assert np.mean(ours == direct) > 0.9999
    assert len(np.unique(direct)) > 200  # the codes span the range, not one end of it
