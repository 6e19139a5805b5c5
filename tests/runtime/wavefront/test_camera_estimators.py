"""The camera estimators of the first-interaction renderers (runtime.wavefront.first_interaction): "forced" and
"marched" must estimate the same image as "delta", layer by layer, with less noise where rays rarely interact.

- one ray, many seeds: the resampled collision's weighted distance histogram and its transmittance estimate
  against delta tracking's collision histogram and escape frequency (two estimators, one mean, z-scores);
- whole images: L_e (an environment behind the volume), L_d (NEE) and L_i (a deterministic stand-in for the
  field, so only the camera estimator is tested) against "delta" with block z-scores over seeds, on a thin
  medium with empty space around it, where forced collisions matter most; and the noise they remove there;
  "marched" also with a light volume of random values (its control variate must not bias it) and on a dense
  medium (walks ended by the delta-tracked rest); its walk alone on thin walls, with strata short and long (the
  residual tracking keeps it unbiased).
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
from photon_fields.runtime.wavefront.camera_choice import AUTO


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


def _scrambled_light_volume(scene: Scene) -> None:
    """Fill the scene's light volume (what "marched" reads as its control variate) with transmittances that have
    nothing to do with the medium: the estimator must stay unbiased whatever the cache holds."""
    from photon_fields.runtime.renderers.ray_marcher import camera_light_volume

    lv = camera_light_volume(scene, "marched")
    lv.values[:] = np.random.default_rng(5).uniform(0.0, 1.0, lv.values.shape).astype(np.float32)


@pytest.fixture(scope="module")
def renders() -> dict[str, list[dict[str, np.ndarray]]]:
    """Per estimator, renders with independent seeds; "forced, roulette" keeps collisions of weight below 0.8
    (most of them here) with probability W / 0.8, so its roulette is tested too; "marched, scrambled cache" reads
    a light volume of random values; "dense" renders are of the medium at 8x the density, where most walks end in
    the delta-tracked rest."""
    q = _StandIn()
    out = {}
    for name, camera, seeds, w_min, density in (
            ("delta", "delta", range(12), None, 4.0), ("forced", "forced", range(100, 112), None, 4.0),
            ("forced, roulette", "forced", range(200, 212), 0.8, 4.0),
            ("marched", "marched", range(300, 312), None, 4.0),
            ("marched, scrambled cache", "marched", range(400, 412), None, 4.0),
            ("delta, dense", "delta", range(500, 512), None, 32.0),
            ("marched, dense", "marched", range(600, 612), None, 32.0)):
        scene = _thin_scene(density)
        if "scrambled" in name:
            _scrambled_light_volume(scene)
        with pytest.MonkeyPatch.context() as patch:
            if w_min is not None:
                patch.setattr(first_interaction, "FORCED_MIN_WEIGHT", w_min)
            out[name] = [render_neural(scene, q, spp=4, seed=seed, progress=False, camera=camera).layers
                         for seed in seeds]
    return out


@pytest.mark.parametrize("other", ["forced", "forced, roulette", "marched", "marched, scrambled cache",
                                   "marched, dense"])
@pytest.mark.parametrize("layer", ["L_e", "L_d", "L_i"])
def test_camera_estimators_estimate_the_same_image(renders, layer: str, other: str) -> None:  # noqa: ANN001
    """Every estimator against delta tracking (the path tracer's first bounce) on the same scene, layer by layer."""
    delta = mean_and_error([r[layer] for r in renders["delta, dense" if "dense" in other else "delta"]])
    assert delta[0].mean() > 0.0
    assert_estimates_agree(delta, mean_and_error([r[layer] for r in renders[other]]), f"{other}: {layer}")


def test_marched_estimator_removes_noise_from_the_direct_light(renders) -> None:  # noqa: ANN001
    """Per pixel, the variance over seeds of L_d: "marched" (the cached light summed over strata of the ray,
    corrected at one point) at most half the forced estimator's (measured: a third)."""
    var = {name: np.stack([r["L_d"] for r in renders[name]]).var(0, ddof=1).mean() for name in ("forced", "marched")}
    assert var["marched"] < 0.5 * var["forced"], var


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

    assert CAMERA_OPTION.default == AUTO  # the renderers' default; first_interaction's own is forced
    assert sorted(CAMERA_OPTION.value(name) for name in (*first_interaction.CAMERA_ESTIMATORS, AUTO)) == [
        "auto", "delta", "forced", "marched"]
    with pytest.raises(InputError, match="--camera-estimator"):
        CAMERA_OPTION.value("ratio")


def _sheets_scene(density: float) -> Scene:
    """A lattice of thin walls (one voxel in six along each axis, about one optical depth across at ``density``
    16) in empty space, seen by a one-pixel camera (its jittered rays spread over the whole view)."""
    i = np.arange(24)
    on = (i % 6 == 2)
    field = (on[:, None, None] | on[None, :, None] | on[None, None, :]).astype(float)
    tf = TransferFunction(np.array([0.0, 1.0]), np.array([[0.8, 0.7, 0.6], [0.8, 0.7, 0.6]]), np.array([0.0, 1.0]),
                          density, "sheets")
    lights = (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.8, 0.6], 2.0),)
    return Scene(make_volume(field, window=(0.0, 1.0), name="sheets"), tf, lights, small_camera(1), 0.3, "sheets")


@pytest.mark.parametrize("strata", ["default", "coarse"])
@pytest.mark.parametrize("density", [16.0, 48.0])
def test_marched_walk_matches_delta_tracking_on_sharp_walls(density: float, strata: str,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """The marched walk alone, on rays through thin walls: its transmittance estimate to the ray's end and its
    weight W (the candidates' sum) against delta tracking's escape and collision frequencies over the same rays,
    two estimators of one mean each. With the default strata and with coarse ones (8 voxels, 4 majorant optical
    depths long): the residual tracking keeps it unbiased whatever the partition, where exp(-sum sigma_t(t_k) l_k)
    alone is biased high wherever a stratum holds a wall."""
    from photon_fields.runtime.renderers.ray_marcher import camera_light_volume
    from photon_fields.runtime.wavefront import marched_camera
    from photon_fields.runtime.wavefront.depth_bounds import unbounded

    if strata == "coarse":
        monkeypatch.setattr(marched_camera, "STRATA_PER_DEPTH", 0.25)
        monkeypatch.setattr(marched_camera, "STRATUM_VOXELS", 8.0)
    scene = _sheets_scene(density)
    m, n = scene.medium(), 40_000
    lv = camera_light_volume(scene, "marched")
    marched = marched_camera.march_camera_rays(scene, m, lv, np.arange(n), 1, unbounded())
    scratch = first_interaction.FirstInteractions.empty(n)
    status, transmit = np.empty(n, np.uint8), np.empty(n)
    first_interaction.sample_first_interactions(scene, m, 0, n, 2, scratch, status, transmit, "delta")
    collided = (status == first_interaction.INTERACTED).astype(float)
    assert 0.2 < collided.mean() < 0.8, collided.mean()
    w_marched = marched.weight.sum(axis=0)  # the picks' sign(w_J) W / P: W where no weight is negative
    for a, b, what in ((1.0 - collided, marched.transmit, "transmittance"), (collided, w_marched, "W")):
        z = abs(a.mean() - b.mean()) / math.sqrt(a.var() / n + b.var() / n)
        assert z < 4.5, (what, a.mean(), b.mean(), z)
    if strata == "default":
        # The picks are stratified draws from the walk's candidates (one random number per candidate, shifted by
        # q / P for pick q): two coincide in 5-9 % of these walks, where independent draws would in sum_k p_k^2
        # (0.20-0.24 over the default strata of these walls), and one draw for all would always.
        interacting = marched.status == first_interaction.INTERACTED
        for p, q in ((0, 1), (1, 2)):
            assert np.all(marched.x[p] == marched.x[q], axis=0)[interacting].mean() < 0.15, (p, q)


def _ramp_scene() -> Scene:
    """sigma_t affine in position (a scalar ramp along a diagonal through a linear opacity), about 0.3 optical depths
    along the rays of a one-pixel camera (no walk reaches the switch to the opaque rest): along any ray sigma_t is
    linear, but for half a voxel at the box's faces, where lookups clamp."""
    i = np.arange(24) / 23.0
    field = (i[:, None, None] + 0.5 * i[None, :, None] + 0.25 * i[None, None, :]) / 1.75
    tf = TransferFunction(np.array([0.0, 1.0]), np.array([[0.8, 0.7, 0.6], [0.8, 0.7, 0.6]]), np.array([0.0, 1.0]),
                          1.0, "ramp")
    lights = (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.8, 0.6], 2.0),)
    return Scene(make_volume(field, window=(0.0, 1.0), name="ramp"), tf, lights, small_camera(1), 0.3, "ramp")


def test_marched_walk_control_follows_a_linear_medium() -> None:
    """The residual tracker's control is linear between the walk's points (runtime.wavefront.marched_camera), so
    where sigma_t is linear along the ray only each ray's ends (before its first point, after its last) leave the
    events a residual to correct: the transmittance estimate to the ray's end is within 0.0015 rms of a fine
    midpoint sum over the same rays (measured 0.0006; a control constant per stratum: 0.003), and unbiased."""
    from photon_fields.runtime.renderers.ray_marcher import camera_light_volume
    from photon_fields.runtime.transport.marching import march_transmittance
    from photon_fields.runtime.wavefront import marched_camera
    from photon_fields.runtime.wavefront.depth_bounds import unbounded
    from photon_fields.runtime.wavefront.rays import camera_ray, clip_to_box

    scene = _ramp_scene()
    m, n, seed = scene.medium(), 2000, 7
    cam = scene.camera
    origin, du, dv = cam.image_plane()
    eye = np.asarray(cam.eye, dtype=np.float64)
    exact = np.ones(n)
    for w in range(n):
        dx, dy, dz, _, _ = camera_ray(origin, du, dv, 1, 1, w, np.uint64(seed))
        hit, ox, oy, oz, tmax = clip_to_box(m, *eye, dx, dy, dz)
        if hit:
            exact[w] = march_transmittance(m, ox, oy, oz, dx, dy, dz, tmax, 1e-3, False)
    walked = marched_camera.march_camera_rays(scene, m, camera_light_volume(scene, "marched"), np.arange(n), seed,
                                              unbounded())
    assert 0.6 < exact.mean() < 0.9 and exact.min() > marched_camera.CAMERA_SWITCH, (exact.mean(), exact.min())
    err = walked.transmit - exact
    assert math.sqrt(np.mean(err**2)) < 0.0015, math.sqrt(np.mean(err**2))
    assert abs(err.mean()) < 4.5 * err.std() / math.sqrt(n), (err.mean(), err.std())
