"""Image metrics: relative L2 by its definition, SSIM equal to scikit-image's and sensitive to structure."""

from __future__ import annotations

import numpy as np
import pytest

from photon_fields.runtime.eval.metrics import display_image, relative_l2, ssim, ssim_display


def _image(seed: int, shape: tuple[int, ...] = (40, 48, 3)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:shape[0], 0:shape[1]] / 20.0
    base = (1.0 + np.sin(3 * x) * np.cos(2 * y))[:, :, None] * np.array([0.8, 0.5, 0.3])
    return base + 0.05 * rng.random(shape)


def test_relative_l2_definition() -> None:
    ref = _image(0)
    assert relative_l2(ref, ref) == 0.0
    assert relative_l2(1.1 * ref, ref) == pytest.approx(0.1, rel=1e-12)
    assert relative_l2(np.zeros_like(ref), ref) == pytest.approx(1.0)
    assert relative_l2(ref, np.zeros_like(ref)) == float("inf")
    with pytest.raises(ValueError, match="shape"):
        relative_l2(ref, ref[:-1])


def test_ssim_matches_scikit_image() -> None:
    skm = pytest.importorskip("skimage.metrics")
    a, b = display_image(_image(1), 0.7), display_image(_image(2) * 1.2, 0.7)
    ours = ssim_display(a, b)
    theirs = skm.structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                       data_range=1.0, channel_axis=2)
    assert ours == pytest.approx(theirs, abs=1e-10)
    assert ours < 0.999  # the two images do differ


def test_ssim_is_one_for_equal_images_and_drops_with_noise_and_exposure() -> None:
    ref = _image(3)
    assert ssim(ref, ref) == pytest.approx(1.0, abs=1e-12)
    noisy = ref * (1.0 + 0.3 * np.random.default_rng(4).standard_normal(ref.shape))
    s_noise = ssim(noisy, ref)
    assert s_noise < 0.95
    assert ssim(ref * 0.25, ref) < 0.9  # far too dark: the reference's exposure is used for both
    assert ssim(ref * 0.98, ref) > s_noise  # a 2 % scale error hurts less than 30 % noise
