"""The WRLS temporal denoiser (runtime/denoise/wrls.py): exactness on constant input, noise reduction without
bias on a static camera, the wRLS weighting against outliers, neighbourhood clamping, reprojection of the
history under camera motion, restarts, determinism and one-line input errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import constant_tf

from photon_fields.runtime.denoise.depth import DepthEstimator
from photon_fields.runtime.denoise.reprojection import pack_view, pixel_direction, reproject_image
from photon_fields.runtime.denoise.wrls import WRLSDenoiser, WRLSParams
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.camera import Camera, orbit_camera
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.threads import numba_threads
from photon_fields.runtime.transport.medium import build_medium

H, W = 40, 48


def smooth_image(h: int = H, w: int = W) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w] / float(max(h, w))
    return np.stack([1.0 + 0.3 * np.sin(2 * np.pi * xx) * np.cos(np.pi * yy), 0.8 + 0.2 * np.cos(2 * np.pi * yy),
                     0.6 + 0.1 * xx], axis=-1).astype(np.float32)


@pytest.fixture(scope="module")
def box():  # noqa: ANN201
    """A homogeneous unit box (sigma_t = 4): its depth maps are analytic (test_wrls_reprojection.py)."""
    return build_medium(make_volume(np.ones((8, 8, 8)), window=(0.0, 1.0)), constant_tf(4.0))


def box_camera(width: int = W, height: int = H) -> Camera:
    return Camera([0.4, 0.3, 2.2], [0.0, 0.05, 0.0], [0.0, 1.0, 0.0], 35.0, width, height)


def world_pattern(cam: Camera, depth: np.ndarray) -> np.ndarray:
    """A smooth radiance fixed in world space, seen by ``cam`` at the points ``depth`` gives (0: background):
    what a renderer would show of a static scene from two viewpoints."""
    view = pack_view(cam)
    img = np.zeros((cam.height, cam.width, 3), np.float32)
    for py in range(cam.height):
        for px in range(cam.width):
            if np.isfinite(depth[py, px]):
                x, y, z = cam.eye + depth[py, px] * np.array(pixel_direction(view, px + 0.5, py + 0.5))
                img[py, px] = (1 + 0.5 * math.sin(9 * x + 1) * math.cos(7 * y), 1 + 0.4 * math.cos(8 * x - 6 * y),
                               0.8 + 0.3 * math.sin(5 * z + 9 * x))
    return img


# --- exactness and statistics on a static camera --------------------------------------------------------


def test_a_constant_image_stays_constant_static_and_moving(box) -> None:  # noqa: ANN001
    c = np.array([0.3, 0.7, 1.9], np.float32)
    frame = np.broadcast_to(c, (H, W, 3)).copy()
    dn = WRLSDenoiser(W, H)
    for _ in range(6):
        np.testing.assert_allclose(dn.denoise(frame), frame, rtol=2e-6)
    moving = WRLSDenoiser(W, H, medium=box)
    for i in range(6):
        np.testing.assert_allclose(moving.denoise(frame, camera=orbit_camera(box_camera(), 2.0 * i)), frame,
                                   rtol=2e-6)
    assert moving.history_weight.max() == 1.0  # the history was reprojected, not restarted


def test_static_noise_is_reduced_without_bias() -> None:
    """A fixed smooth image + i.i.d. Gaussian noise of sigma 0.2 (20 % of the signal): after 20 frames the
    denoised error is a quarter of the single-frame noise, and the signed error averaged over the image and
    frames 20-39 is below 2 % of sigma."""
    truth = smooth_image()
    sigma = 0.2
    rng = np.random.default_rng(1)
    dn = WRLSDenoiser(W, H)
    outs = []
    for _ in range(40):
        outs.append(dn.denoise(truth + sigma * rng.standard_normal(truth.shape).astype(np.float32)))
    err = np.asarray(outs[20:], np.float64) - truth
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms < 0.3 * sigma, rms / sigma  # measured 0.24 sigma
    assert abs(float(err.mean())) < 0.02 * sigma, err.mean() / sigma  # measured -0.003 sigma
    assert np.all(np.abs(err.mean(axis=(0, 1, 2))) < 0.03 * sigma)  # per channel
    # The first frame has no history: it is only the reconstruction and spatial filters'.
    first = float(np.sqrt(np.mean((outs[0] - truth) ** 2)))
    assert rms < 0.5 * first


def test_accumulated_progressive_input_converges_with_it() -> None:
    """ProgressiveRender's use (module docstring): fed the running mean of the frames, the output's error
    keeps falling with it instead of settling at the feature's noise floor."""
    truth = smooth_image()
    rng = np.random.default_rng(5)
    dn = WRLSDenoiser(W, H)
    acc = np.zeros_like(truth, dtype=np.float64)
    errors = {}
    for n in range(1, 65):
        acc += truth + 0.5 * rng.standard_normal(truth.shape)
        out = dn.denoise((acc / n).astype(np.float32))
        errors[n] = float(np.sqrt(np.mean((out - truth) ** 2)))
    assert errors[64] < 0.5 * errors[8], errors


# --- the wRLS weighting and the clamping ---------------------------------------------------------------


SPIKES = ((10, 10), (24, 30), (33, 41), (5, 37))


def spike_deviations(**params: object) -> tuple[np.ndarray, np.ndarray]:
    """Max |output - truth| at four pixels over the frame where they are 50x too bright (an outlier frame,
    a firefly) and the 10 after it; and the same for an exponential moving average of the input."""
    truth = smooth_image()
    rng = np.random.default_rng(2)
    dn = WRLSDenoiser(W, H, **params)
    ema = None
    dev, ema_dev = [], []
    for t in range(31):
        frame = truth + 0.05 * rng.standard_normal(truth.shape).astype(np.float32)
        if t == 20:
            for y, x in SPIKES:
                frame[y, x] *= 50.0
        out = dn.denoise(frame)
        ema = frame if ema is None else 0.75 * ema + 0.25 * frame
        if t >= 20:
            dev.append(max(float(np.abs(out[y, x] - truth[y, x]).max()) for y, x in SPIKES))
            ema_dev.append(max(float(np.abs(ema[y, x] - truth[y, x]).max()) for y, x in SPIKES))
    return np.array(dev), np.array(ema_dev)


def test_an_outlier_frame_is_down_weighted_by_wrls_not_by_plain_rls() -> None:
    """Eq. 13's weight: the spike barely moves the wRLS output (0.65 at the spike frame, measured), while
    plain RLS (w = 1, Eq. 10) takes it into its coefficients (2.5, and twice the deviation for the next ten
    frames) and a moving average of the frames shows a quarter of it (15)."""
    wrls, ema = spike_deviations()
    rls, _ = spike_deviations(bandwidth=1e12)
    assert wrls[0] < 0.4 * rls[0], (wrls[0], rls[0])
    assert wrls[0] < 0.1 * ema[0], (wrls[0], ema[0])
    assert wrls[1:].mean() < 0.6 * rls[1:].mean(), (wrls[1:], rls[1:])
    assert wrls[1:].max() < 0.15  # the spike leaves no trace (clamping removes it from the feature)


def test_clamping_drops_a_stale_history_at_once() -> None:
    """Psi of Eq. 12: after an abrupt change of a static image the history is clamped to the new frame's
    neighbourhood, so the output follows at once (unclamped it would be 0.75 old + 0.25 new)."""
    dn = WRLSDenoiser(W, H)
    old = np.full((H, W, 3), 0.2, np.float32)
    new = np.full((H, W, 3), 1.0, np.float32)
    for _ in range(10):
        dn.denoise(old)
    np.testing.assert_allclose(dn.denoise(new), new, rtol=1e-5)


# --- reprojection and restarts ---------------------------------------------------------------------------


def test_history_follows_the_camera(box) -> None:  # noqa: ANN001
    """A world-fixed pattern seen from two viewpoints 2 degrees apart: reprojected along the depth map, the
    history agrees with the new view to 0.3 % rms (bilinear resampling); taken from the same pixel, as if
    the camera had not moved, it is 30x worse."""
    c0, c1 = box_camera(), orbit_camera(box_camera(), 2.0)
    de = DepthEstimator(box, block=1, stride=1)
    d0, d1 = de.depth(c0), de.depth(c1)
    p0, p1 = world_pattern(c0, d0), world_pattern(c1, d1)
    errors = {}
    for mode in ("reprojected", "same pixel"):
        dn = WRLSDenoiser(W, H, reconstruction_sigma=0.0, window_radius=0)
        dn.denoise(p0, camera=c0, depth=d0)
        out = dn.denoise(p1, camera=c1, depth=d1) if mode == "reprojected" else dn.denoise(p1)
        kept = np.isfinite(d1) & (dn.history_weight > 0.99)
        assert kept.mean() > 0.3
        errors[mode] = float(np.sqrt(np.mean((out - p1)[kept] ** 2)))
    assert errors["reprojected"] < 0.01, errors
    assert errors["reprojected"] < 0.1 * errors["same pixel"], errors


def test_off_screen_and_disoccluded_pixels_restart(box) -> None:  # noqa: ANN001
    """Pixels whose point was outside the previous view, or whose previous pixels saw another depth, find no
    history (weight 0) and restart: their output is the frame itself (no reconstruction or spatial filter
    here); background pixels keep theirs (both depths infinite)."""
    c0, c1 = box_camera(), orbit_camera(box_camera(), 6.0)
    de = DepthEstimator(box, block=1, stride=1)
    d0, d1 = de.depth(c0), de.depth(c1)
    d0_occluded = d0.copy()
    d0_occluded[10:20, 15:30] *= 0.7  # something nearer covered these pixels in frame 0
    rng = np.random.default_rng(3)
    f0 = rng.uniform(0.5, 1.5, (H, W, 3)).astype(np.float32)
    f1 = rng.uniform(0.5, 1.5, (H, W, 3)).astype(np.float32)
    dn = WRLSDenoiser(W, H, reconstruction_sigma=0.0, window_radius=0)
    dn.denoise(f0, camera=c0, depth=d0_occluded)
    out = dn.denoise(f1, camera=c1, depth=d1)
    weight = dn.history_weight
    # Where each pixel's point lands in frame 0 (the reprojection itself is checked analytically elsewhere).
    xs, ys, _, _ = reproject_image(pack_view(c1), pack_view(c0), d1.astype(np.float64))
    off_screen = (xs < 0) | (xs >= W) | (ys < 0) | (ys >= H)
    assert off_screen.sum() >= H  # a 6-degree orbit step uncovers at least a column
    inside = ~off_screen & (xs > 1.5) & (xs < W - 1.5) & (ys > 1.5) & (ys < H - 1.5)
    occluded = inside & np.isfinite(d1) & (xs > 16) & (xs < 29) & (ys > 11) & (ys < 19)
    open_medium = inside & np.isfinite(d1) & ((xs < 13) | (xs > 32) | (ys < 8) | (ys > 22))
    bx, by = np.floor(xs - 0.5).astype(int), np.floor(ys - 0.5).astype(int)
    taps_background = np.ones_like(inside)
    for oy in (0, 1):
        for ox in (0, 1):
            taps_background &= np.isinf(d0_occluded[np.clip(by + oy, 0, H - 1), np.clip(bx + ox, 0, W - 1)])
    background = inside & np.isinf(d1) & taps_background
    assert occluded.sum() > 20 and open_medium.sum() > 20 and background.sum() > 20
    assert np.all(weight[off_screen] == 0.0)
    assert np.all(weight[occluded] == 0.0)
    assert np.all(weight[background] > 0.99)
    assert np.median(weight[open_medium]) > 0.99
    restarted = weight == 0.0
    np.testing.assert_allclose(out[restarted], f1[restarted], rtol=1e-6)
    assert not np.allclose(out[~restarted], f1[~restarted], rtol=1e-2)  # the others blend in their history


# --- determinism and input errors ----------------------------------------------------------------------


def test_same_inputs_give_bit_identical_outputs_at_any_thread_count(box) -> None:  # noqa: ANN001
    rng = np.random.default_rng(4)
    frames = [rng.gamma(1.0, 1.0, (H, W, 3)).astype(np.float32) for _ in range(4)]
    cams = [orbit_camera(box_camera(), 1.5 * i) for i in range(4)]

    def run(threads: int) -> list[np.ndarray]:
        dn = WRLSDenoiser(W, H, medium=box)
        with numba_threads(threads):
            return [dn.denoise(f, camera=c) for f, c in zip(frames, cams, strict=True)]

    first, again, one_thread = run(2), run(2), run(1)
    for a, b, c in zip(first, again, one_thread, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)


def one_line_error(call, *args, **kwargs) -> str:  # noqa: ANN001
    with pytest.raises(InputError) as err:
        call(*args, **kwargs)
    text = str(err.value)
    assert "\n" not in text
    return text


def test_a_frame_of_another_size_is_one_clear_line() -> None:
    dn = WRLSDenoiser(W, H)
    dn.denoise(smooth_image())
    text = one_line_error(dn.denoise, smooth_image(H, W + 8))
    assert text.startswith("WRLS denoiser frame") and f"{W + 8}x{H}" in text and f"{W}x{H}" in text
    assert "(H, W, 3)" in one_line_error(dn.denoise, np.zeros((H, W)))
    bad = smooth_image()
    bad[3, 4, 1] = np.nan
    assert "NaN" in one_line_error(dn.denoise, bad)


def test_other_bad_inputs_are_one_clear_line(box) -> None:  # noqa: ANN001
    dn = WRLSDenoiser(W, H)
    assert "camera" in one_line_error(dn.denoise, smooth_image(), camera=box_camera(W + 1, H))
    assert "depth" in one_line_error(dn.denoise, smooth_image(), camera=box_camera(), depth=np.ones((H, W + 1)))
    assert "depth" in one_line_error(dn.denoise, smooth_image(), camera=box_camera(), depth=np.zeros((H, W)))
    dn.denoise(smooth_image(), camera=box_camera(), depth=np.full((H, W), 2.0))
    text = one_line_error(dn.denoise, smooth_image(), camera=orbit_camera(box_camera(), 3.0))
    assert "moving camera needs a depth map" in text
    assert "unknown parameter" in one_line_error(WRLSDenoiser, W, H, alpah=0.5)
    assert "WRLS alpha" in one_line_error(WRLSDenoiser, W, H, alpha=1.5)
    assert "WRLS predictor" in one_line_error(WRLSParams, predictor="current")
    assert "WRLS denoiser width" in one_line_error(WRLSDenoiser, 0, H)


def test_the_model_covariance_cannot_wind_up() -> None:
    """Samples that Eq. 13 always weights ~0 leave P growing as lambda^-t (covariance wind-up); with a short
    memory that would overflow float32 within ~850 frames and turn the output into NaN. It stays finite."""
    dn = WRLSDenoiser(8, 8, forgetting=0.9, reconstruction_sigma=0.0)
    base = np.full((8, 8, 3), 1.0, np.float32)
    out = None
    for t in range(1200):
        out = dn.denoise(base * (40.0 if t % 2 else 0.025))  # every frame far from the feature
    assert out is not None and np.all(np.isfinite(out))
    assert np.all(np.isfinite(dn._cur)) and np.all(np.isfinite(dn._prev))
