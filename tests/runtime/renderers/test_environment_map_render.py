"""Environment maps in the renderers: every renderer that handles the constant environment handles a map.

- a constant-valued map renders like today's constant EnvironmentLight of the same radiance: statistically (block
  z-scores over seeds) in the path tracer and the photon-mapped renderer (photon emission, NEE at the first
  interaction), exactly where no random direction is drawn (the ray marcher, camera rays that miss or escape);
- a furnace: albedo 1 under a constant *map* (rotated: the tables and MIS per direction), every pixel sees 1;
- NEE + MIS and pure phase sampling agree under a non-constant map (the escape's MIS weight uses the map's pdf);
- a map that is black but for a small bright patch lights single scattering like a directional light of the same
  irradiance from the patch's direction; with the map turned by yaw 90 like the light direction turned by 90;
- the first-interaction renderers see the map behind the volume along each camera ray exactly as the path tracer.

The photon map vs path tracer L_i under a non-constant map is in tests/runtime/photons/test_light_kinds.py.
Planted bugs these kill are listed in bench/mutants.py (``env_*``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import assert_estimates_agree, coloured_tf, constant_tf, mean_and_error, small_camera, smooth_field

from photon_fields.runtime.photons.estimate import PhotonMapEstimator
from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, EnvironmentMap, Light
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.environment_map import rotation_matrix
from photon_fields.train.photons.tracing import trace_photons

#: Exactly representable in float32 (the map's pixels), so a constant map's radiance equals the light's bit for bit.
SKY = np.array([0.75, 1.0, 1.25])


def scene_with(lights: tuple[Light, ...], tf: TransferFunction | None = None, g: float = 0.3,
               size: int = 24) -> Scene:
    vol = make_volume(smooth_field(16), window=(0.0, 1.0), name="smooth")
    return Scene(vol, tf or coloured_tf(8.0), lights, small_camera(size), g, "envmap")


def constant_map(h: int = 16, rotation: float | list[float] = 0.0) -> EnvironmentMap:
    return EnvironmentMap("constant", [1.0, 1.0, 1.0], 1.0, rotation, np.broadcast_to(SKY, (h, 2 * h, 3)))


def sky_map(h: int = 16) -> np.ndarray:
    """A smooth sky (bright zenith, dim ground, a broad warm glow) that phase sampling can still converge on."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(2 * h) + 0.5) / (2 * h)
    vv, uu = np.meshgrid(v, u, indexing="ij")
    glow = np.exp(-((vv - 0.3) ** 2 + (uu - 0.2) ** 2) / 0.02)
    base = np.where(vv < 0.5, 1.5 - vv, 0.2)
    return (base[..., None] * [0.6, 0.8, 1.0] + glow[..., None] * [3.0, 2.0, 0.8]).astype(np.float32)


def pt_stats(scene: Scene, layer: str, seeds: range, **kw) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN003
    return mean_and_error([render_path_traced(scene, seed=s, progress=False, **kw).layers[layer] for s in seeds])


def test_constant_map_matches_the_constant_environment_in_the_path_tracer() -> None:
    env = scene_with((EnvironmentLight(SKY),))
    emap = scene_with((constant_map(rotation=[30.0, 40.0, 0.0]),))
    for layer in ("L_d", "L_i"):
        assert_estimates_agree(pt_stats(env, layer, range(6), spp=8), pt_stats(emap, layer, range(10, 16), spp=8),
                               f"path tracer {layer}")
    # Camera rays that miss the volume or escape it draw no direction: the same seed sees the same L_e.
    a = render_path_traced(env, spp=2, seed=1, progress=False).layers["L_e"]
    b = render_path_traced(emap, spp=2, seed=1, progress=False).layers["L_e"]
    np.testing.assert_array_equal(a, b)


def test_constant_map_matches_the_constant_environment_in_the_photon_mapper() -> None:
    """Photon emission (direction from the map, power scaled by L / (p int L)) and the first-interaction NEE."""
    layers = {}
    for name, light in (("env", EnvironmentLight(SKY)), ("map", constant_map(rotation=[-60.0, 15.0, 5.0]))):
        scene = scene_with((light,), size=24)
        imgs = []
        for seed in range(4):
            pmap = trace_photons(scene, 100_000, phases=(scene.g,), seed=seed, progress=False)
            imgs.append(render_neural(scene, PhotonMapEstimator(pmap, scene.medium()), spp=4, seed=20 + seed,
                                      progress=False).layers)
        layers[name] = imgs
    for layer in ("L_d", "L_i"):
        assert_estimates_agree(mean_and_error([x[layer] for x in layers["env"]]),
                               mean_and_error([x[layer] for x in layers["map"]]), f"photon mapper {layer}")


def test_ray_marcher_sees_a_constant_map_like_the_constant_environment() -> None:
    a = render_ray_marched(scene_with((EnvironmentLight(SKY), DirectionalLight([0, -1, 0], [1, 1, 1], 1.0))),
                           seed=2, progress=False).layers
    b = render_ray_marched(scene_with((constant_map(), DirectionalLight([0, -1, 0], [1, 1, 1], 1.0))),
                           seed=2, progress=False).layers
    np.testing.assert_allclose(a["L"], b["L"], rtol=1e-6)


def test_ray_marcher_sees_the_map_along_each_camera_ray() -> None:
    """The ray marcher's fused kernel keeps no ray direction either: per pixel (1 spp, one seed) its L_e under a map
    is its transmittance (L_e under a constant sky, over the sky) times the map along that pixel's camera ray (the
    path tracer's L_e through a transparent medium, which sees the map along the same rays)."""
    sky = EnvironmentMap("sky", image=sky_map(), rotation=[120.0, -20.0, 0.0])
    with_map = render_ray_marched(scene_with((sky,), size=16), seed=6, progress=False).layers["L_e"]
    constant = render_ray_marched(scene_with((EnvironmentLight(SKY),), size=16), seed=6, progress=False).layers["L_e"]
    clear = TransferFunction(np.array([0.0, 1.0]), np.ones((2, 3)), np.zeros(2), 1.0, "clear")
    behind = render_path_traced(scene_with((sky,), tf=clear, size=16), spp=1, seed=6, progress=False).layers
    t = constant / SKY
    assert np.any((t > 0.05) & (t < 0.95)) and t.max() > 0.99  # rays through the medium and beside it
    np.testing.assert_allclose(with_map, constant / SKY * behind["L_e"], rtol=1e-5, atol=1e-7)


def test_furnace_under_a_constant_map() -> None:
    scene = scene_with((constant_map(rotation=[20.0, 50.0, 10.0]),), tf=constant_tf(20.0, 1.0), g=0.5, size=16)
    res = render_path_traced(scene, spp=64, max_depth=10_000, seed=3, progress=False)
    L = res.layers["L"] / SKY
    se = L.std() / math.sqrt(L.size)
    assert np.all(np.abs(L.mean(axis=(0, 1)) - 1.0) < 5 * se + 1e-3), L.mean(axis=(0, 1))
    assert res.layers["L_i"].mean() > 0.2


def test_nee_with_mis_and_phase_sampling_agree_under_a_map() -> None:
    scene = scene_with((EnvironmentMap("sky", image=sky_map(), rotation=[70.0, 0.0, 0.0]),), g=0.6)
    a = pt_stats(scene, "L", range(8), spp=8, nee=True)
    b = pt_stats(scene, "L", range(10, 18), spp=8, nee=False)
    assert_estimates_agree(a, b, "NEE + MIS vs phase sampling")


def patch_map(h: int = 64, row: int = 18, col: int = 80) -> tuple[EnvironmentMap, np.ndarray]:
    """A black map with a 2 x 2-pixel patch of radiance 400 (2.8 degrees per pixel), and the unit direction of
    the patch's centre in the map's frame."""
    img = np.zeros((h, 2 * h, 3), np.float32)
    img[row:row + 2, col:col + 2] = [400.0, 350.0, 300.0]
    th, ph = math.pi * (row + 1) / h, 2 * math.pi * (col + 1) / (2 * h)
    return EnvironmentMap("patch", image=img), np.array([math.sin(th) * math.sin(ph), math.cos(th),
                                                         -math.sin(th) * math.cos(ph)])


@pytest.mark.parametrize("yaw", [0.0, 90.0])
def test_bright_patch_lights_like_a_directional_light(yaw: float) -> None:
    """Single scattering (max_depth 1, NEE) from the patch vs a directional light of irradiance int L dw travelling
    away from the patch: 1.5 % in the image mean, 3 % per 6x6 block (the patch is 5.6 degrees wide: soft shadows).
    With yaw 90 the map and the light direction are turned alike."""
    light, w = patch_map()
    light = light.rotated(yaw)
    w = rotation_matrix(yaw) @ w
    map_scene = scene_with((light,), tf=coloured_tf(6.0), g=0.2)
    irradiance = map_scene.packed_environment_map().integral
    dir_scene = scene_with((DirectionalLight(-w, irradiance / irradiance.max(), float(irradiance.max())),),
                           tf=coloured_tf(6.0), g=0.2)
    # The same seeds: identical camera paths and first vertices (common random numbers), so the comparison is of
    # the two lights' NEE at the same points. Measured per seed: ratios 0.988-1.007 (yaw 0 and 90, 4 seeds each);
    # 16 seeds: 0.996-0.999.
    ma, _ = pt_stats(map_scene, "L_d", range(4), spp=16, max_depth=1)
    mb, _ = pt_stats(dir_scene, "L_d", range(4), spp=16, max_depth=1)
    assert mb.mean() > 0.01
    np.testing.assert_allclose(ma.mean(axis=(0, 1)), mb.mean(axis=(0, 1)), rtol=0.015)
    assert np.sqrt(((ma - mb) ** 2).sum() / (mb**2).sum()) < 0.03


@pytest.mark.parametrize("camera", ["delta", "forced"])
def test_first_interaction_renderers_see_the_map_along_each_camera_ray(camera: str) -> None:
    """The fused first-interaction kernel keeps no direction of a ray that misses or escapes; the map behind it is
    looked up along the regenerated camera ray. "delta" sees exactly the path tracer's L_e (same seed, same
    rays); "forced" weights it by the transmittance estimate: the same image in expectation."""
    scene = scene_with((EnvironmentMap("sky", image=sky_map(), rotation=[120.0, -20.0, 0.0]),), size=16)
    ref = render_path_traced(scene, spp=4, seed=6, progress=False).layers["L_e"]
    if camera == "delta":
        fi = render_neural(scene, None, spp=4, seed=6, progress=False, camera="delta").layers["L_e"]
        np.testing.assert_allclose(fi, ref, rtol=1e-5, atol=1e-7)
        return
    a = mean_and_error([render_neural(scene, None, spp=4, seed=s, progress=False, camera="forced").layers["L_e"]
                        for s in range(6)])
    b = mean_and_error([render_path_traced(scene, spp=4, seed=s, progress=False).layers["L_e"]
                        for s in range(10, 16)])
    assert_estimates_agree(a, b, "forced L_e")
