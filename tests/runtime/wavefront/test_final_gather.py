"""The final gather (runtime.wavefront.final_gather): one real bounce before the L_i estimate.

- With an estimator that returns 0, the gathered L_i is exactly the light of paths with two scattering vertices:
  the path tracer's ``max_depth = 2`` L_i (block z-scores over seeds), for both camera estimators, with a
  directional light and an environment (a bounce that escapes must score 0: that path belongs to L_d);
- the bounce's directions follow the phase function around the camera ray (chi-square on the cosine), and the
  estimator is asked at collisions in the medium (sigma_t > 0), with the render's g;
- an estimator's value reaches L_i scaled by the bounce's weight: L_i is affine in the estimator;
- the same seed gives the same image, and progressive frames equal one render with all their samples;
- the command line offers it for the field and the photon map.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_estimates_agree, mean_and_error, small_camera, smooth_field
from scipy import stats

from photon_fields.runtime.renderers.neural import ProgressiveRender, render_neural
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import extinction_at
from photon_fields.runtime.transport.phase import hg_sample_cos
from photon_fields.runtime.wavefront import final_gather

G = 0.4


def _scene() -> Scene:
    """Optical depth ~1-3 across the box with empty space below the TF's first point, a coloured albedo, a
    directional light and an environment: bounces both collide and escape."""
    tf = TransferFunction(np.array([0.0, 0.45, 1.0]), np.array([[0.9, 0.6, 0.3], [0.6, 0.9, 0.7], [0.85, 0.75, 0.95]]),
                          np.array([0.0, 0.0, 1.0]), 8.0, "gather")
    lights = (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.8, 0.6], 2.0), EnvironmentLight([0.3, 0.35, 0.4], 1.0))
    return Scene(make_volume(smooth_field(20), window=(0.0, 1.0), name="smooth"), tf, lights, small_camera(20), G,
                 "gather")


class _Zero:
    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        return np.zeros_like(x)


class _Recorder:
    """A stand-in estimator (smooth in x and d, per channel) that keeps what it was asked."""

    def __init__(self, scale: float = 1.0) -> None:
        self.scale, self.calls = scale, []

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        self.calls.append((x.copy(), d.copy(), g))
        base = 1.0 + 0.5 * np.sin(3.0 * x[0]) + 0.3 * x[1] + 0.2 * d[2] ** 2
        return self.scale * np.stack([base, 0.7 * base + 0.1 * x[2], 1.3 - 0.2 * base])


@pytest.fixture(scope="module")
def li_two_vertices() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    scene = _scene()
    out = {"pt": mean_and_error([render_path_traced(scene, spp=4, max_depth=2, seed=s, progress=False).layers["L_i"]
                                 for s in range(12)])}
    for camera in ("delta", "forced"):
        out[camera] = mean_and_error([render_neural(scene, _Zero(), spp=4, seed=100 + s, progress=False, camera=camera,
                                                    final_gather_after=0).layers["L_i"] for s in range(12)])
    return out


@pytest.mark.parametrize("camera", ["delta", "forced"])
def test_gather_of_nothing_is_the_path_tracers_second_bounce(li_two_vertices, camera: str) -> None:  # noqa: ANN001
    assert li_two_vertices["pt"][0].mean() > 0.0
    assert_estimates_agree(li_two_vertices["pt"], li_two_vertices[camera], f"{camera}: gathered L_i, depth 2")


def test_estimator_is_asked_at_collisions_in_the_medium_with_the_renders_g() -> None:
    scene = _scene()
    rec = _Recorder()
    render_neural(scene, rec, spp=8, seed=3, progress=False, final_gather_after=0)
    x2 = np.concatenate([c[0] for c in rec.calls], axis=1)
    w = np.concatenate([c[1] for c in rec.calls], axis=1)
    assert {c[2] for c in rec.calls} == {G}
    assert x2.shape[1] > 500
    np.testing.assert_allclose(np.linalg.norm(w, axis=0), 1.0, atol=1e-9)
    m = scene.medium()
    assert min(extinction_at(m, *x2[:, i]) for i in range(x2.shape[1])) > 0.0


def test_bounce_directions_follow_the_phase_function() -> None:
    """Chi-square of the cosine between the incoming direction and the bounce's against HG(g) (20 equiprobable
    bins), and E[w] = g d (the azimuth is uniform), from one fixed direction and from random ones."""
    m = _scene().medium()
    n, bins = 40_000, 20
    rng = np.random.default_rng(0)
    fixed = np.tile(np.array([[0.3], [-0.5], [0.81]]) / np.linalg.norm([0.3, -0.5, 0.81]), (1, n))
    random = rng.normal(size=(3, n))
    random /= np.linalg.norm(random, axis=0)
    edges = np.array([hg_sample_cos(G, u) for u in np.linspace(0.0, 1.0, bins + 1)])
    edges[0], edges[-1] = -1.0 - 1e-12, 1.0 + 1e-12
    for d in (fixed, random):
        x = np.zeros((3, n))  # the box centre
        states = rng.integers(1, 2**63, n).astype(np.uint64)
        x2, w, weight, out = np.empty((3, n)), np.empty((3, n)), np.empty((3, n)), np.empty(n, np.uint64)
        hit = final_gather._bounce(m, G, x, np.ascontiguousarray(d), states, False, 0.25, x2, w, weight, out)
        assert 0.05 < hit.mean() < 0.999  # bounces both collide and escape
        counts = np.histogram(np.einsum("ij,ij->j", d, w), edges)[0]
        assert stats.chisquare(counts).pvalue > 1e-3, counts
        if d is fixed:
            z = np.abs(w.mean(1) - G * d[:, 0]) / (w.std(1) / np.sqrt(n))
            assert z.max() < 4.5, z


def test_gathered_li_is_affine_in_the_estimator() -> None:
    """L_i(gather(c Q)) = L_i(gather(0)) + c (L_i(gather(Q)) - L_i(gather(0))), with the same seed: the estimator's
    value is used once, linearly, at every bounce that collides."""
    scene = _scene()
    li = {c: render_neural(scene, _Recorder(c) if c else _Zero(), spp=2, seed=5, progress=False,
                           final_gather_after=0, camera="forced").layers["L_i"] for c in (0.0, 1.0, 3.0)}
    assert (li[1.0] - li[0.0]).mean() > 0.0
    np.testing.assert_allclose(li[3.0] - li[0.0], 3.0 * (li[1.0] - li[0.0]), rtol=1e-5, atol=1e-7)  # float32 layers


def test_same_seed_same_image_and_progressive_frames_equal_one_render() -> None:
    scene = _scene()
    one = render_neural(scene, _Recorder(), spp=3, seed=9, progress=False, final_gather_after=0).layers
    again = render_neural(scene, _Recorder(), spp=3, seed=9, progress=False, final_gather_after=0).layers
    prog = ProgressiveRender(scene, _Recorder(), spp=1, seed=9, final_gather_after=0)
    for _ in range(3):
        frames = prog.frame().layers
    for layer in ("L", "L_d", "L_i"):
        np.testing.assert_array_equal(one[layer], again[layer])
        np.testing.assert_allclose(frames[layer], one[layer], rtol=1e-6, atol=1e-9)
    plain = render_neural(scene, _Recorder(), spp=3, seed=9, progress=False).layers
    np.testing.assert_array_equal(plain["L_d"], one["L_d"])  # the bounce does not draw from NEE's stream
    assert not np.array_equal(plain["L_i"], one["L_i"])


def test_command_line_offers_final_gather_for_field_and_photon_map() -> None:
    from photon_fields.runtime.renderers.registry import GATHER_OPTION, RENDERERS

    for name in ("field", "photonmap"):
        assert GATHER_OPTION in RENDERERS[name].options
    assert GATHER_OPTION.keyword == "final_gather_after"
    assert [GATHER_OPTION.type(t) for t in ("never", "0", "128")] == [None, 0, 128]


@pytest.mark.parametrize(("after", "gathered"), [(None, 0), (0, 5), (2, 3), (5, 0), (9, 0)])
def test_samples_from_final_gather_after_on_are_gathered_and_the_rest_plain(after: int | None, gathered: int) -> None:
    """A render of 5 samples gathering from sample ``after`` on is, sample for sample, the plain render of the
    samples before it and the gathered render of the rest into one film (work batches of 2 samples' items straddle
    the switch when it is odd: the switch must fall between two batches)."""
    from photon_fields.runtime.wavefront.film import Film

    scene = _scene()
    n = scene.camera.width * scene.camera.height
    one = render_neural(scene, _Recorder(), spp=5, seed=4, progress=False, batch_size=2 * n + n // 2,
                        final_gather_after=after)
    film = Film(scene.camera.width, scene.camera.height)
    plain = 5 - gathered
    if plain:
        render_neural(scene, _Recorder(), spp=plain, seed=4, progress=False, film=film, final_gather_after=None)
    if gathered:
        render_neural(scene, _Recorder(), spp=gathered, seed=4, progress=False, film=film, first_sample=plain,
                      final_gather_after=0)
    both = film.layers()
    assert one.stats["final_gather_spp"] == gathered
    for layer in ("L", "L_d", "L_i"):
        np.testing.assert_allclose(one.layers[layer], both[layer], rtol=1e-6, atol=1e-9)
