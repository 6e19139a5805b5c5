"""The kernel in g (runtime/photons/phase_window.py): its weights, the windowed photon-map estimate as a
weighted sum of the bins' estimates, and its convergence to the path tracer at a g that no bin was traced with."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import constant_tf, small_camera, smooth_field

from photon_fields.models_spec import DEFAULT_PHASES, PHASE_BINS, PHASE_WINDOW
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.estimate import PhotonMapEstimator
from photon_fields.runtime.photons.knn_radiance import indexed_radiance
from photon_fields.runtime.photons.phase_window import check_window, map_window, window_range, window_weights
from photon_fields.runtime.photons.photon_grid import build_photon_index
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped
from photon_fields.runtime.scene.lights import DirectionalLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.train.photons.tracing import trace_photons

#: Narrow bins over [0.4, 0.85]: whole windows of +-0.15 for g in [0.55, 0.7].
BINS = tuple(round(0.4 + 0.05 * i, 6) for i in range(10))


@pytest.fixture(scope="module")
def thin_scene() -> Scene:
    """Optically thin, smooth, box-filling medium with high albedo (as in test_photon_estimate.py)."""
    vol = make_volume(smooth_field(32), window=(0.0, 1.0), name="smooth")
    return Scene(vol, constant_tf(8.0, 0.95), (DirectionalLight([-0.5, -1.0, -0.3], [1, 1, 1], 3.0),),
                 small_camera(16), 0.62, "thin")


@pytest.mark.parametrize("g", [-0.75, -0.6125, -0.3, 0.0, 0.33, 0.75])
def test_window_weights_are_a_normalized_kernel_centred_on_g(g: float) -> None:
    idx, w = window_weights(PHASE_BINS, g, PHASE_WINDOW)
    bins = np.asarray(PHASE_BINS)[idx]
    assert np.all(w > 0) and math.isclose(w.sum(), 1.0)
    assert np.all(np.abs(bins - g) < PHASE_WINDOW)
    # Whole windows are symmetric: the kernel's mean is g (first-order exact average over g) ...
    assert math.isclose(float(w @ bins), g, abs_tol=1e-12)
    # ... and triangular: weight falls linearly with the distance to g.
    np.testing.assert_allclose(w / w.max(), (1 - np.abs(bins - g) / PHASE_WINDOW) / (1 - np.abs(bins - g).min()
                                                                                     / PHASE_WINDOW))


def test_auto_window_reads_binned_maps_only() -> None:
    assert map_window(PHASE_BINS) == PHASE_WINDOW and map_window(BINS) == PHASE_WINDOW
    assert map_window(DEFAULT_PHASES) is None and map_window((0.3,)) is None
    assert map_window(PHASE_BINS, None) is None and map_window(DEFAULT_PHASES, 0.2) == 0.2


def test_window_range_and_refusals() -> None:
    assert window_range(PHASE_BINS, PHASE_WINDOW) == pytest.approx((-0.8, 0.8))
    lo, hi = window_range(PHASE_BINS, PHASE_WINDOW)  # past the paper's G on both sides: its ends are not the field's
    assert lo < min(DEFAULT_PHASES) and hi > max(DEFAULT_PHASES)
    with pytest.raises(InputError, match="too sparse"):
        check_window(DEFAULT_PHASES, PHASE_WINDOW)  # 0.375 apart: a window would hold one phase
    with pytest.raises(InputError, match="half-width"):
        check_window(PHASE_BINS, 0.0)
    with pytest.raises(InputError, match="no phase bin"):
        window_weights(BINS, 0.1, PHASE_WINDOW)
    with pytest.raises(InputError, match="narrower than one"):
        window_range((0.0, 0.05, 0.1), PHASE_WINDOW)


def test_window_estimate_is_the_weighted_sum_of_the_bins_estimates(thin_scene: Scene) -> None:
    """With every photon inside r_max counted (K above the map's size, so r = r_max for every query), Eq. 5 is
    linear in the photons: the windowed estimate equals sum_b w_b Q_b, the bins' own estimates with the phase
    function at the query's g."""
    pmap = trace_photons(thin_scene, 40_000, phases=BINS, seed=4, progress=False)
    m = thin_scene.medium()
    est = PhotonMapEstimator(pmap, m, k=1 << 16, radius=0.08, g_window=PHASE_WINDOW)
    rng = np.random.default_rng(1)
    x = m.bmin + (0.2 + 0.6 * rng.random((200, 3))) * m.bsize
    d = rng.normal(size=(200, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    g = 0.62
    window, _, _ = indexed_radiance(est.binned_index(), x, d, g, 1 << 16, 0.08)
    idx, w = window_weights(BINS, g, PHASE_WINDOW)
    mixed = sum(wb * indexed_radiance(est.index(int(b)), x, d, g, 1 << 16, 0.08)[0] for b, wb in zip(idx, w,
                                                                                                   strict=True))
    assert window.mean() > 0
    # rtol 1e-6: the two sides round their (differently scaled) photon weights to float32 (photon_grid.PhotonIndex).
    np.testing.assert_allclose(window, mixed, rtol=1e-6, atol=1e-12 * window.max())


@pytest.mark.parametrize("lights", [1, 2])
def test_binned_index_is_the_union_of_the_kernels_bins(thin_scene: Scene, lights: int) -> None:
    """With an adaptive radius (K = 24, far below the photons in r_max), the binned index's estimate at g is the
    estimate over a plain index of the kernel's bins, each photon weighted by its bin's normalized kernel weight:
    the same K nearest photons, the same radius, the same sum. At g in the middle of the bins, between two bins,
    at a traced bin (where the kernel's end bins weigh 0) and where the window is cut by the bins' range; one g per
    query equals the scalar calls; and each photon is held once."""
    scene = replace(thin_scene, lights=(*thin_scene.lights, DirectionalLight([0.3, -1.0, 0.5], [1, 0.5, 0.2], 2.0)),
                    _cache={})
    pmap = trace_photons(scene, 30_000, phases=BINS, seed=6, progress=False)
    m = scene.medium()
    est = PhotonMapEstimator(pmap, m, k=24, radius=0.2, g_window=PHASE_WINDOW, lights=lights)
    binned = est.binned_index()
    assert len(binned.grid.order) == len(pmap) and binned.grid.bins == len(BINS)
    rng = np.random.default_rng(2)
    x = m.bmin + (0.1 + 0.8 * rng.random((300, 3))) * m.bsize
    d = rng.normal(size=(300, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    sigma = est._photon_sigma()
    for g in (0.62, 0.625, 0.6, 0.45, 0.84):
        idx, w = window_weights(BINS, g, PHASE_WINDOW)
        scale = np.zeros(len(BINS))
        scale[idx] = w
        keep = scale[pmap.phase] > 0
        union = build_photon_index(pmap.position[keep], pmap.direction[keep],
                                   pmap.power[keep] * scale[pmap.phase[keep], None] / sigma[keep, None],
                                   light=pmap.light[keep], lights=lights)
        want, r_want, f_want = indexed_radiance(union, x, d, g, 24, 0.2)
        got, r_got, f_got = indexed_radiance(binned, x, d, g, 24, 0.2)
        assert (f_got == 24).mean() > 0.9 and want.mean() > 0
        np.testing.assert_array_equal(f_got, f_want)
        np.testing.assert_array_equal(r_got, r_want)
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-12 * want.max())  # float32 weights on both sides
    gs = rng.uniform(0.55, 0.7, 300)
    per_query = indexed_radiance(binned, x, d, gs, 24, 0.2)[0]
    one_by_one = np.concatenate([indexed_radiance(binned, x[i:i + 1], d[i:i + 1], gs[i], 24, 0.2)[0]
                                 for i in range(300)])
    np.testing.assert_allclose(per_query, one_by_one, rtol=1e-12)


def test_windowed_photon_map_converges_to_path_tracer_between_bins(thin_scene: Scene) -> None:
    """At g = 0.62, which no bin was traced with, the windowed map (1M photons over ten bins) matches the path
    tracer's L_i at g = 0.62: image mean within 4 % and relative L2 within 10 %, the bounds of the single-phase
    test in test_photon_estimate.py. A map that answered with the nearest bin's earlier bounces, or weights
    that do not sum to one, would not."""
    ref = render_path_traced(thin_scene, spp=2048, seed=1, progress=False).layers["L_i"]
    pmap = trace_photons(thin_scene, 1_000_000, phases=BINS, seed=2, progress=False)
    li = render_photon_mapped(thin_scene, pmap, spp=64, seed=1, progress=False).layers["L_i"]  # "auto": binned
    rel_l2 = math.sqrt(float(((li - ref) ** 2).sum() / (ref**2).sum()))
    assert abs(li.mean() / ref.mean() - 1.0) < 0.04
    assert rel_l2 < 0.10
    with pytest.raises(InputError, match="phase set"):  # without the window, g must be a traced phase
        render_photon_mapped(thin_scene, pmap, spp=1, progress=False, g_window=None)
