"""NEE with one light per vertex (runtime.transport.direct_light.direct_light_one, ``light_sampling="one"``) against
a shadow ray to every light ("all"): the same mean, exactly the same numbers with one light, no noise where every
light is unshadowed, and the renderers' images with either setting converge to one image.

- per point, many independent estimates of both at points inside a heterogeneous medium lit by a directional light, a
  point light, a constant environment and an environment map (with and without the environment's MIS weight):
  two estimators, one mean (z-scores);
- in an empty medium (transmittance 1) with lights of one colour, "one" is exact at every point: the choice is in
  proportion to each light's unshadowed contribution (phase function, falloff and power), or its variance is not 0;
- one light: bit for bit the "all" numbers (nothing drawn);
- whole images (neural renderer with a stand-in field; photon-map renderer's final gather) with block z-scores;
- NEE in two stages (the lights' samples, then their shadow rays by residual tracking: the marched camera's picks)
  against the one-stage NEE with ratio-tracked shadow rays: one mean, per setting.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_estimates_agree, mean_and_error, small_camera, smooth_field

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, EnvironmentMap, PointLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.direct_light import direct_light_batch, sample_lights_batch
from photon_fields.runtime.transport.residual_tracking import shadowed_light_batch
from photon_fields.runtime.transport.tracking import SHADOW_SWITCH
from photon_fields.runtime.wavefront import first_interaction

TF = TransferFunction(np.array([0.0, 0.55, 1.0]), np.array([[0.9, 0.6, 0.3], [0.5, 0.9, 0.7], [0.8, 0.7, 0.95]]),
                      np.array([0.0, 0.3, 1.0]), 5.0, "thin")


def _sky() -> np.ndarray:
    """A small equirectangular map with a bright, coloured patch (so its samples vary)."""
    img = np.full((8, 16, 3), 0.2)
    img[1:3, 4:7] = [4.0, 2.0, 1.0]
    return img


def _scene(lights: tuple, field: np.ndarray | None = None) -> Scene:
    volume = make_volume(smooth_field(16) if field is None else field, window=(0.0, 1.0), name="smooth")
    return Scene(volume, TF, lights, small_camera(24), 0.4, "lit")


FOUR_LIGHTS = (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.8, 0.6], 2.0),
               PointLight([0.9, 0.5, 0.7], [0.4, 0.6, 1.0], 0.8), EnvironmentLight([0.3, 0.35, 0.4], 0.5),
               EnvironmentMap(image=_sky(), power=0.3))


def _estimates(scene: Scene, x: np.ndarray, d: np.ndarray, repeats: int, env_mis: bool, one: bool,
               seed: int, staged: bool = False) -> np.ndarray:
    """(repeats, 3, points) independent NEE estimates at points x along directions d; ``staged``: the lights'
    samples, then their shadow rays by residual tracking (two strata per majorant optical depth, two voxels at
    most, events at the majorant)."""
    m = scene.medium()
    kind, vec, rgb = scene.packed_lights()
    env = scene.packed_environment_map()
    n = x.shape[1]
    xs, ds = np.tile(x, repeats), np.tile(d, repeats)
    states = (np.arange(repeats * n, dtype=np.uint64) * np.uint64(2654435761) + np.uint64(seed)) | np.uint64(1)
    if staged:
        lights, weight = sample_lights_batch(kind, vec, rgb, env, scene.g, xs, ds, states, env_mis, one)
        out = shadowed_light_batch(m, xs, lights, weight, states, 2.0, 2.0 * scene.volume.voxel_size, 1.0,
                                   SHADOW_SWITCH)
    else:
        out = direct_light_batch(m, kind, vec, rgb, env, scene.g, xs, ds, states, env_mis, one)
    return out.reshape(3, repeats, n).transpose(1, 0, 2)


def _points(n: int = 12, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.uniform(-0.4, 0.4, (3, n))
    d = rng.normal(size=(3, n))
    return x, d / np.linalg.norm(d, axis=0)


@pytest.mark.parametrize("env_mis", [False, True])
def test_one_light_and_every_light_have_one_mean(env_mis: bool) -> None:
    scene = _scene(FOUR_LIGHTS)
    x, d = _points()
    reps = 4000
    every = _estimates(scene, x, d, reps, env_mis, False, 11)
    one = _estimates(scene, x, d, reps, env_mis, True, 12)
    assert every.mean() > 0.0
    z = np.abs(every.mean(0) - one.mean(0)) / np.sqrt(every.var(0) / reps + one.var(0) / reps + 1e-18)
    assert z.max() < 4.5, z.max()
    # one shadow ray instead of four: noisier per estimate, but not without bound
    assert one.var(0).sum() > every.var(0).sum()


@pytest.mark.parametrize(("env_mis", "one"), [(False, True), (False, False), (True, True)])
def test_staged_nee_with_residual_shadow_rays_has_the_one_stage_mean(env_mis: bool, one: bool) -> None:
    """The marched camera's picks' NEE (direct_light.sample_lights_batch, then
    residual_tracking.shadowed_light_batch) against direct_light_batch: each light's weight, direction and distance
    carried between the stages, every light's ray summed ("all") and the drawn one's scaled ("one")."""
    scene = _scene(FOUR_LIGHTS)
    x, d = _points()
    reps = 4000
    plain = _estimates(scene, x, d, reps, env_mis, one, 21)
    staged = _estimates(scene, x, d, reps, env_mis, one, 22, staged=True)
    assert plain.mean() > 0.0
    z = np.abs(plain.mean(0) - staged.mean(0)) / np.sqrt(plain.var(0) / reps + staged.var(0) / reps + 1e-18)
    assert z.max() < 4.5, z.max()


def test_choice_follows_each_lights_unshadowed_contribution() -> None:
    """Empty medium, lights of one colour: every light is unshadowed, so drawing light k with probability
    c_k / sum c and dividing by it returns sum c exactly; a choice by power alone (or uniform) would not."""
    lights = (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.8, 0.6], 2.0),
              PointLight([0.9, 0.5, 0.7], [1.0, 0.8, 0.6], 0.8), PointLight([-0.7, 0.2, 0.9], [1.0, 0.8, 0.6], 0.3))
    scene = _scene(lights, field=np.zeros((8, 8, 8)))
    x, d = _points(20)
    every = _estimates(scene, x, d, 1, True, False, 1)[0]
    one = _estimates(scene, x, d, 50, True, True, 2)
    np.testing.assert_allclose(one, np.broadcast_to(every, one.shape), rtol=1e-12)


def test_one_light_is_every_light_bit_for_bit() -> None:
    scene = _scene((PointLight([0.9, 0.5, 0.7], [0.4, 0.6, 1.0], 0.8),))
    x, d = _points()
    np.testing.assert_array_equal(_estimates(scene, x, d, 20, False, True, 5), _estimates(scene, x, d, 20, False,
                                                                                          False, 5))


class _StandIn:
    """A deterministic Q(x, d, g) in place of the field."""

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        base = 1.0 + 0.5 * np.sin(3.0 * x[0]) + 0.3 * x[1] + 0.2 * d[2] ** 2
        return np.stack([base, 0.7 * base + 0.1 * x[2], 1.3 - 0.2 * base])


@pytest.mark.parametrize("gather", [None, 0])
def test_images_with_one_light_and_every_light_agree(gather: int | None) -> None:
    """The neural renderer's L_d (and, with the final gather's NEE at the bounce, its L_i) with either setting."""
    scene = _scene(FOUR_LIGHTS[:3])
    layer = "L_d" if gather is None else "L_i"
    images = {s: [render_neural(scene, _StandIn(), spp=4, seed=seed, progress=False, light_sampling=s,
                                final_gather_after=gather).layers[layer] for seed in range(base, base + 10)]
              for s, base in (("all", 0), ("one", 100))}
    assert_estimates_agree(mean_and_error(images["all"]), mean_and_error(images["one"]), f"{layer}, gather {gather}")


def test_default_and_command_line() -> None:
    from photon_fields.runtime.renderers.registry import LIGHT_OPTION, RENDERERS

    assert first_interaction.DEFAULT_LIGHT_SAMPLING == "one"
    assert LIGHT_OPTION.default == first_interaction.DEFAULT_LIGHT_SAMPLING
    assert [LIGHT_OPTION.value(s) for s in first_interaction.LIGHT_SAMPLINGS] == ["all", "one"]
    for name in ("field", "photonmap"):
        assert LIGHT_OPTION in RENDERERS[name].options
    with pytest.raises(InputError, match="--light-sampling"):
        LIGHT_OPTION.value("some")
    with pytest.raises(InputError, match="light sampling"):
        render_neural(_scene(FOUR_LIGHTS[:1]), _StandIn(), spp=1, progress=False, light_sampling="both")
