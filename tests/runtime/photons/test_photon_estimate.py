"""Photon-map radiance estimate (Eq. 5) and the photon-mapping renderer against the path tracer."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import constant_tf, small_camera, smooth_field

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.estimate import ball_pattern, support_fraction
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, PointLight
from photon_fields.runtime.scene.scene import Scene, builtin_scene
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.train.photons.tracing import trace_photons


@pytest.fixture(scope="module")
def thin_scene() -> Scene:
    """Optically thin, smooth, box-filling medium with high albedo: lots of multiple scattering and no
    empty space except outside the box."""
    vol = make_volume(smooth_field(32), window=(0.0, 1.0), name="smooth")
    return Scene(vol, constant_tf(8.0, 0.95), (DirectionalLight([-0.5, -1.0, -0.3], [1, 1, 1], 3.0),),
                 small_camera(16), 0.0, "thin")


def test_ball_pattern_fills_the_ball_evenly() -> None:
    p = ball_pattern(64)
    assert p.shape == (64, 3) and np.all(np.linalg.norm(p, axis=1) <= 1.0)
    assert np.array_equal(p[0], np.zeros(3))
    # Evenly spread: each octant holds about an eighth of the points.
    octant = (p[1:] > 0).astype(int) @ np.array([1, 2, 4])
    assert np.bincount(octant, minlength=8).min() >= 5


def test_support_fraction_at_box_faces_and_corners() -> None:
    vol = make_volume(np.ones((8, 8, 8)), window=(0.0, 1.0))
    m = Scene(vol, constant_tf(1.0), (PointLight([0, 0, 0], [1, 1, 1], 1.0),), small_camera()).medium()
    pattern = ball_pattern(4096)
    x = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5, 0.5, 0.5], [0.5, 0.5, 0.0]])
    f = support_fraction(m, x, np.full(4, 0.1), pattern)
    np.testing.assert_allclose(f, [1.0, 0.5, 0.125, 0.25], atol=0.02)


def test_photon_map_renderer_direct_light_equals_path_tracer(thin_scene: Scene) -> None:
    """Same seed, same first interactions (the "delta" camera estimator) and shadow rays: L_d is identical to
    the path tracer's for delta lights, whatever the estimator does for L_i."""
    pmap = trace_photons(thin_scene, 20_000, seed=1, progress=False)
    pm = render_photon_mapped(thin_scene, pmap, spp=4, seed=7, progress=False, camera="delta").layers
    pt = render_path_traced(thin_scene, spp=4, seed=7, progress=False).layers
    np.testing.assert_array_equal(pm["L_d"], pt["L_d"])
    assert pm["L_i"].mean() > 0


def test_photon_map_li_converges_to_path_tracer(thin_scene: Scene) -> None:
    """At 1M photons the photon-map L_i matches the path tracer's L_i: image mean within 4 % and relative
    L2 within 10 % (measured 2 % / 6 %; at 100k: 0.5 % / 13 %). bench/bench_photons.py reports the
    whole 100k / 1M / 4M series."""
    ref = render_path_traced(thin_scene, spp=2048, seed=1, progress=False).layers["L_i"]
    pmap = trace_photons(thin_scene, 1_000_000, seed=2, progress=False)
    li = render_photon_mapped(thin_scene, pmap, spp=64, seed=1, progress=False).layers["L_i"]
    rel_l2 = math.sqrt(float(((li - ref) ** 2).sum() / (ref**2).sum()))
    assert abs(li.mean() / ref.mean() - 1.0) < 0.04
    assert rel_l2 < 0.10


def test_photon_map_white_furnace_under_an_environment_light() -> None:
    """Albedo 1 everywhere under a uniform environment of radiance 1: every camera ray sees radiance 1 (the path
    tracer's white furnace, tests/runtime/renderers/test_path_tracer.py). L_e and L_d (NEE) are exact here; L_i, about
    half of L,
    comes from the environment's photons alone (uniform directions through a disk, flux 4 pi^2 R^2 L), so their
    power is checked against an analytic value. Traced with 64 collisions, so no light is cut off (the optical
    radius is ~2). Measured (300k photons, g = 0.3, 5 seeds): image mean of L 0.989-1.007, 4x4-pixel block means
    in [0.94, 1.055]. Bounds: 3 % on the mean, 10 % on every block."""
    vol = make_volume(smooth_field(24), window=(0.0, 1.0), name="smooth")
    scene = Scene(vol, constant_tf(8.0, 1.0), (EnvironmentLight([1.0, 1.0, 1.0], 1.0),), small_camera(16), 0.3,
                  "furnace")
    pmap = trace_photons(scene, 300_000, phases=(0.3,), max_bounces=64, seed=1, progress=False)
    layers = render_photon_mapped(scene, pmap, spp=16, seed=2, progress=False).layers
    L = layers["L"]
    assert layers["L_i"].mean() > 0.4 * L.mean()  # the photons carry a large share of it
    assert np.all(np.abs(L.mean(axis=(0, 1)) - 1.0) < 0.03), L.mean(axis=(0, 1))
    blocks = L.reshape(4, 4, 4, 4, 3).mean(axis=(1, 3))
    assert np.all(np.abs(blocks - 1.0) < 0.10), blocks.min()


def test_phase_not_in_map_and_foreign_map_are_refused(thin_scene: Scene) -> None:
    pmap = trace_photons(thin_scene, 5_000, phases=(-0.75, 0.0, 0.75), seed=1, progress=False)
    with pytest.raises(InputError, match="phase set"):
        render_photon_mapped(thin_scene.with_overrides(g=0.3), pmap, progress=False)
    other = builtin_scene("blobs", resolution=32)
    with pytest.raises(InputError, match="another scene"):
        render_photon_mapped(other, pmap, progress=False)
    # Forcing it renders anyway (the user takes responsibility).
    res = render_photon_mapped(other.with_overrides(g=0.0, width=8, height=8), pmap, progress=False, force=True)
    assert np.all(np.isfinite(res.layers["L"]))
