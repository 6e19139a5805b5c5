"""Reference path tracer and ray marcher: energy conservation, estimator agreement, determinism."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from conftest import coloured_tf, constant_tf, small_camera, smooth_field

from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, PointLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume


def _scene(lights, sigma: float = 8.0, albedo=0.8, g: float = 0.0, size: int = 24,  # noqa: ANN001
           tf: TransferFunction | None = None) -> Scene:
    vol = make_volume(smooth_field(), window=(0.0, 1.0), name="smooth")
    return Scene(vol, tf or constant_tf(sigma, albedo), tuple(lights), small_camera(size), g, "test")


def _block_means(img: np.ndarray, b: int = 6) -> np.ndarray:
    h, w = img.shape[:2]
    return img[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b, -1).mean(axis=(1, 3))


def _seeds_stats(scene: Scene, layer: str, seeds: range, **kw) -> tuple[np.ndarray, np.ndarray]:  # noqa: ANN003
    """Block means over independent renders: (mean, standard error) per block and channel."""
    imgs = np.stack([_block_means(render_path_traced(scene, seed=s, progress=False, **kw).layers[layer])
                     for s in seeds])
    return imgs.mean(0), imgs.std(0, ddof=1) / math.sqrt(len(seeds))


def test_white_furnace() -> None:
    """Albedo 1 under a uniform environment of radiance 1: every camera ray sees radiance 1, in any
    medium. Loss or gain of energy anywhere in the estimator (RR, MIS, tracking) breaks this."""
    scene = _scene([EnvironmentLight([1.0, 1.0, 1.0], 1.0)], sigma=20.0, albedo=1.0, g=0.5, size=16)
    res = render_path_traced(scene, spp=64, max_depth=10_000, seed=3, progress=False)
    L = res.layers["L"][..., 0]
    # In a furnace the true image is constant, so the pixel spread is pure noise: use it for the error bar.
    se_img = L.std() / math.sqrt(L.size)
    assert abs(L.mean() - 1.0) < 5 * se_img
    se_block = L.std() / 4.0  # 4x4-pixel blocks
    assert np.all(np.abs(_block_means(L[..., None], 4) - 1.0) < 5 * se_block)
    # Multiple scattering is a large part of it (so the test exercises deep paths).
    assert res.layers["L_i"].mean() > 0.2


def test_absorbing_furnace_loses_energy() -> None:
    """Same set-up with albedo 0.5: strictly less than the furnace radiance (the test can fail)."""
    scene = _scene([EnvironmentLight([1.0, 1.0, 1.0], 1.0)], sigma=20.0, albedo=0.5, size=16)
    L = render_path_traced(scene, spp=16, seed=3, progress=False).layers["L"]
    assert L.mean() < 0.9


def test_nee_mis_and_phase_sampling_agree() -> None:
    """NEE+MIS and pure phase sampling are two estimators of the same image (environment light,
    anisotropic phase, a coloured albedo that varies with density, so the throughput differs per channel and
    Russian roulette works on its largest component): block means agree within 5 combined standard errors."""
    scene = _scene([EnvironmentLight([0.9, 1.0, 1.1], 1.0)], g=0.6, tf=coloured_tf(10.0))
    a, sa = _seeds_stats(scene, "L", range(8), spp=8, nee=True)
    b, sb = _seeds_stats(scene, "L", range(10, 18), spp=8, nee=False)
    z = np.abs(a - b) / np.sqrt(sa**2 + sb**2 + 1e-8)
    assert np.percentile(z, 99) < 5.0
    assert abs(a.mean() - b.mean()) / a.mean() < 0.01


def test_layers_add_up_and_single_scattering_has_no_li() -> None:
    scene = _scene([DirectionalLight([-0.5, -1.0, -0.3], [1.0, 1.0, 1.0], 2.0)])
    res = render_path_traced(scene, spp=4, seed=1, progress=False)
    lay = res.layers
    np.testing.assert_allclose(lay["L"], lay["L_e"] + lay["L_d"] + lay["L_i"], rtol=1e-6)
    assert lay["L_i"].mean() > 0.05 * lay["L_d"].mean()
    single = render_path_traced(scene, spp=4, seed=1, max_depth=1, progress=False).layers
    assert single["L_i"].max() == 0.0
    # Same seed, same first vertex: single scattering's L_d equals the full render's L_d exactly.
    np.testing.assert_array_equal(single["L_d"], lay["L_d"])


@pytest.mark.parametrize("light", [DirectionalLight([-0.5, -1.0, -0.3], [1.0, 0.8, 0.6], 2.0),
                                   PointLight([0.8, 0.9, 0.7], [1.0, 1.0, 1.0], 1.5)])
@pytest.mark.parametrize("shadows", ["march", "volume"])
def test_ray_marcher_matches_single_scattering(light, shadows: str) -> None:  # noqa: ANN001
    """With one delta light and no multiple scattering, the marcher's model is exact: it and the path
    tracer limited to one scattering vertex agree (up to quadrature error, the light volume's interpolation and
    noise), with shadow rays per sample and with the preview's light volume."""
    scene = _scene([light], sigma=6.0, albedo=0.9, g=0.3)
    pt, se = _seeds_stats(scene, "L_d", range(16), spp=8, max_depth=1)
    # The marcher is noise-free along a ray but still jitters sub-pixel positions, which matters at
    # the volume's silhouette: give it enough passes that its coverage noise is small.
    rm = _block_means(render_ray_marched(scene, spp=192, step=0.5, max_step=0.5, shadows=shadows, shadow_step=0.5,
                                         progress=False).layers["L_d"])
    rel = np.abs(pt - rm) / (np.abs(pt) + 1e-3)
    z = np.abs(pt - rm) / (se + 1e-6)
    assert abs(pt.mean() - rm.mean()) / pt.mean() < 0.02  # marcher quadrature error at half-voxel steps
    assert np.all((z < 5) | (rel < 0.03))


def test_same_seed_same_image_for_any_batching_and_threads() -> None:
    scene = _scene([DirectionalLight([-0.5, -1.0, -0.3], [1.0, 1.0, 1.0], 2.0),
                    EnvironmentLight([0.2, 0.2, 0.3], 1.0)], size=12)
    ref = render_path_traced(scene, spp=4, seed=5, progress=False).layers
    again = render_path_traced(scene, spp=4, seed=5, batch_size=97, progress=False).layers
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        single = render_path_traced(scene, spp=4, seed=5, progress=False).layers
    finally:
        numba.set_num_threads(old)
    other = render_path_traced(scene, spp=4, seed=6, progress=False).layers
    for k in ref:
        np.testing.assert_array_equal(ref[k], again[k])
        np.testing.assert_array_equal(ref[k], single[k])
    assert not np.array_equal(ref["L"], other["L"])


def test_empty_pixels_see_only_environment() -> None:
    scene = _scene([EnvironmentLight([0.5, 0.5, 0.5], 1.0)], size=16)
    scene = scene.with_overrides(camera=small_camera(16, fov=120.0))
    L = render_path_traced(scene, spp=2, seed=0, progress=False).layers
    corner = L["L"][0, 0]
    np.testing.assert_allclose(corner, 0.5, rtol=1e-6)
    assert L["L_d"][0, 0].max() == 0.0
