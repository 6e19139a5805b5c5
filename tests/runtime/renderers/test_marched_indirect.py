"""The ray marcher with a field's L_i (``render_ray_marched(estimator=...)``, ``--method raymarch-field``): one
scattering point per ray drawn along the march with probability w_k / W, weighted W a Q.

- With a constant albedo and a constant Q every pixel's L_i is a Q (1 - T) exactly (W telescopes to one minus the
  ray's transmittance), which an environment seen through the medium (L_e = E T) completes to a Q: the weight.
- With a Q that varies along the rays the picks must be distributed as the segments' weights: the image converges
  to the neural renderer's L_i with the same Q (the first-interaction estimator, unbiased), up to the march's
  quadrature error.
- With delta lights the direct term is the plain marcher's, bit for bit; an environment's single scattering (which
  the march leaves out) is NEE at the pick and converges to the neural renderer's L_d.
"""

from __future__ import annotations

import numpy as np
from conftest import constant_tf

from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight
from photon_fields.runtime.scene.scene import Scene, builtin_scene

Q_RGB = np.array([0.7, 0.5, 0.3])


def constant_q(x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
    """Q = Q_RGB everywhere."""
    return np.repeat(Q_RGB[:, None], x.shape[1], axis=1)


def graded_q(x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
    """Q growing steeply along x and with the direction: where along a ray the pick falls matters."""
    return np.exp(4.0 * x[0] + d[1])[None, :] * Q_RGB[:, None]


def test_a_constant_field_weights_each_ray_by_its_collision_probability() -> None:
    vortex = builtin_scene("vortex")
    albedo = 0.8
    tf = constant_tf(60.0, albedo)
    env = 0.25
    scene = Scene(vortex.volume, tf, (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 1.0, 1.0], 2.0),
                                      EnvironmentLight([env, env, env])), vortex.camera.with_resolution(40, 36), 0.3,
                  "constant")
    layers = render_ray_marched(scene, spp=1, seed=3, progress=False, estimator=constant_q,
                                min_transmittance=0.0).layers
    li, le = layers["L_i"].astype(np.float64), layers["L_e"].astype(np.float64)
    assert 0.05 < li[..., 0].max() / (albedo * Q_RGB[0]) < 1.0  # some rays cross medium, none is opaque
    for c in range(3):
        np.testing.assert_allclose(li[..., c] / (albedo * Q_RGB[c]) + le[..., c] / env, 1.0, atol=2e-6)
    plain = render_ray_marched(scene, spp=1, seed=3, progress=False, min_transmittance=0.0).layers
    np.testing.assert_array_equal(layers["L_e"], plain["L_e"])
    assert plain["L_i"].max() == 0.0


def test_the_picks_converge_to_the_neural_renderers_l_i_with_the_same_field() -> None:
    scene = builtin_scene("vortex").with_overrides(width=24, height=24)
    layers = render_ray_marched(scene, spp=64, seed=1, progress=False, estimator=graded_q, step=0.5).layers
    marched = layers["L_i"]
    # delta lights only: the direct term is the plain marcher's, bit for bit
    np.testing.assert_array_equal(layers["L_d"], render_ray_marched(scene, spp=64, seed=1, progress=False,
                                                                    step=0.5).layers["L_d"])
    neural = render_neural(scene, graded_q, spp=128, seed=2, progress=False, final_gather_after=None).layers["L_i"]
    assert neural.mean() > 0.0
    assert abs(marched.mean() / neural.mean() - 1.0) < 0.03  # the march's quadrature: ~1-2 % on vortex
    # per pixel too, to within both images' noise (~0.1 each): picks by the wrong weights move whole rays' values
    assert np.linalg.norm(marched - neural) / np.linalg.norm(neural) < 0.2


def test_an_environments_single_scattering_comes_from_nee_at_the_pick() -> None:
    """The light volume holds delta lights only: an environment's L_d is one NEE sample at each ray's pick, and
    converges to the neural renderer's L_d (NEE at its first interactions): image means over four seeds each agree
    within four standard errors plus 1 % for the march's quadrature."""
    vortex = builtin_scene("vortex")
    scene = Scene(vortex.volume, vortex.tf, (EnvironmentLight([0.6, 0.7, 0.9]),),
                  vortex.camera.with_resolution(24, 24), 0.3, "sky only")
    assert render_ray_marched(scene, spp=1, seed=1, progress=False).layers["L_d"].max() == 0.0  # the plain march
    marched = np.array([render_ray_marched(scene, spp=32, seed=s, progress=False, estimator=constant_q)
                        .layers["L_d"].mean((0, 1)) for s in range(4)])
    neural = np.array([render_neural(scene, None, spp=64, seed=10 + s, progress=False).layers["L_d"].mean((0, 1))
                       for s in range(4)])
    assert np.all(neural.mean(0) > 0.0)
    se = np.sqrt(marched.var(0, ddof=1) / 4 + neural.var(0, ddof=1) / 4)
    assert np.all(np.abs(marched.mean(0) - neural.mean(0)) < 4 * se + 0.01 * neural.mean(0)), (marched, neural)
