"""Frame encoding (runtime/viewer/encode.py): the fast tone map matches the shared one, PNG is lossless."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from photon_fields.runtime.io.images import tonemap_srgb
from photon_fields.runtime.viewer.encode import encode, tonemap


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
