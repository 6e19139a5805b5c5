"""The camera estimators of the first-interaction renderers (runtime.wavefront.first_interaction): "forced"
must estimate the same image as "delta", layer by layer, with less noise where rays rarely interact.

- one ray, many seeds: the resampled collision's weighted distance histogram and its transmittance estimate
  against delta tracking's collision histogram and escape frequency (two estimators, one mean, z-scores);
- whole images: L_e (an environment behind the volume), L_d (NEE) and L_i (a deterministic stand-in for the
  field, so only the camera estimator is tested) against "delta" with block z-scores over seeds, on a thin
  medium with empty space around it, where forced collisions matter most; and the noise they remove there.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import assert_estimates_agree, mean_and_error, small_camera, smooth_field

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.tracking import camera_collision, delta_track, resampled_collision
from photon_fields.runtime.wavefront import first_interaction


def _thin_scene(density: float = 4.0) -> Scene:
    """A medium of optical depth ~0.3-1 along most rays (at ``density`` 4), with empty space between the blobs
    (density below the TF's first point is empty) and a coloured, density-dependent albedo."""
    field = smooth_field(24)
    tf = TransferFunction(np.array([0.0, 0.55, 1.0]), np.array([[0.9, 0.6, 0.3], [0.5, 0.9, 0.7], [0.8, 0.7, 0.95]]),
                          np.array([0.0, 0.0, 1.0]), density, "thin")
    lights = (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.8, 0.6], 2.0), EnvironmentLight([0.3, 0.35, 0.4], 1.0))
    return Scene(make_volume(field, window=(0.0, 1.0), name="smooth"), tf, lights, small_camera(24), 0.3, "thin")


class _StandIn:
    """A deterministic Q(x, d, g) in place of the field: smooth in x and d, different per channel."""

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        base = 1.0 + 0.5 * np.sin(3.0 * x[0]) + 0.3 * x[1] + 0.2 * d[2] ** 2
        return np.stack([base, 0.7 * base + 0.1 * x[2], 1.3 - 0.2 * base])


@pytest.mark.parametrize("walk", ["resampled", "camera"])
@pytest.mark.parametrize("density", [4.0, 16.0])
def test_resampled_collision_matches_delta_tracking_on_one_ray(walk: str, density: float) -> None:
    """E[W 1{t in bin}] equals P(delta collision in bin) per bin, and E[T] the escape probability: for the plain
    resampled collision and for the camera's walk, which finishes the ray by delta tracking once its transmittance
    estimate is below CAMERA_SWITCH (on the denser medium, in most walks)."""
    scene = _thin_scene(density)
    m = scene.medium()
    o, d = np.array([-1.0, 0.05, -0.1]), np.array([1.0, 0.02, 0.01])
    d /= np.linalg.norm(d)
    n, edges = 20_000, np.linspace(0.0, 2.0, 11)
    delta_hist, forced_hist = np.zeros((n, 10)), np.zeros((n, 10))
    escaped, transmit = np.zeros(n), np.zeros(n)
    for i in range(n):
        t, _ = delta_track(m, *o, *d, 0.0, math.inf, np.uint64(2 * i + 1))
        if math.isfinite(t):
            delta_hist[i, np.searchsorted(edges, t) - 1] = 1.0
        else:
            escaped[i] = 1.0
        if walk == "resampled":
            t, w, transmit[i], _ = resampled_collision(m, *o, *d, 0.0, math.inf, np.uint64(2 * i + 2))
        else:
            t, w, transmit[i], _ = camera_collision(m, *o, *d, 0.0, math.inf, np.uint64(2 * i + 2), True, 0.0)
        if math.isfinite(t):
            forced_hist[i, np.searchsorted(edges, t) - 1] = w
    assert (0.2 < escaped.mean() < 0.8) if density == 4.0 else (0.005 < escaped.mean() < 0.1), escaped.mean()
    pairs = ((delta_hist, forced_hist, "collision histogram"), (escaped[:, None], transmit[:, None], "escape"))
    for a, b, what in pairs:
        z = np.abs(a.mean(0) - b.mean(0)) / np.sqrt(a.var(0) / n + b.var(0) / n + 1e-18)
        assert z.max() < 4.5, (what, a.mean(0), b.mean(0), z)


@pytest.fixture(scope="module")
def renders() -> dict[str, list[dict[str, np.ndarray]]]:
    """Per estimator, renders with independent seeds; "forced, roulette" keeps collisions of weight below 0.8
    (most of them here) with probability W / 0.8, so its roulette is tested too."""
    scene, q = _thin_scene(), _StandIn()
    out = {}
    for name, camera, seeds, w_min in (("delta", "delta", range(12), None), ("forced", "forced", range(100, 112), None),
                                       ("forced, roulette", "forced", range(200, 212), 0.8)):
        with pytest.MonkeyPatch.context() as patch:
            if w_min is not None:
                patch.setattr(first_interaction, "FORCED_MIN_WEIGHT", w_min)
            out[name] = [render_neural(scene, q, spp=4, seed=seed, progress=False, camera=camera).layers
                         for seed in seeds]
    return out


@pytest.mark.parametrize("forced", ["forced", "forced, roulette"])
@pytest.mark.parametrize("layer", ["L_e", "L_d", "L_i"])
def test_forced_and_delta_estimate_the_same_image(renders, layer: str, forced: str) -> None:  # noqa: ANN001
    delta = mean_and_error([r[layer] for r in renders["delta"]])
    assert delta[0].mean() > 0.0
    assert_estimates_agree(delta, mean_and_error([r[layer] for r in renders[forced]]), f"{forced}: {layer}")


def test_forced_collisions_remove_noise_in_thin_media(renders) -> None:  # noqa: ANN001
    """Per pixel, the variance over seeds of L_i and L_e: at most half of delta tracking's."""
    for layer in ("L_i", "L_e"):
        var = {name: np.stack([r[layer] for r in renders[name]]).var(0, ddof=1).mean() for name in ("delta", "forced")}
        assert var["forced"] < 0.5 * var["delta"], (layer, var)


def test_unknown_camera_estimator_is_refused() -> None:
    with pytest.raises(InputError, match="camera estimator"):
        render_neural(_thin_scene(), _StandIn(), spp=1, progress=False, camera="forcd")


def test_command_line_offers_every_camera_estimator() -> None:
    from photon_fields.runtime.renderers.registry import CAMERA_OPTION

    assert CAMERA_OPTION.default == first_interaction.DEFAULT_CAMERA_ESTIMATOR
    assert [CAMERA_OPTION.value(name) for name in first_interaction.CAMERA_ESTIMATORS] == ["delta", "forced"]
    with pytest.raises(InputError, match="--camera-estimator"):
        CAMERA_OPTION.value("ratio")
