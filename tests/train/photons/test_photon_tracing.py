"""Multi-phase photon tracing (Alg. 1): energy, phase balance, HG at scattering, determinism, bad input."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from conftest import coloured_tf, constant_tf, equal_probability_edges, hg_cdf, small_camera, smooth_field
from scipy import stats

from photon_fields.models_spec import PAPER_PHASES
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentMap, PointLight
from photon_fields.runtime.scene.scene import Scene, builtin_scene
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.environment_map import NO_ENV_MAP
from photon_fields.train.photons.tracing import CHUNK, _trace_chunk, light_fluxes, trace_photons


def _dense_scene(albedo: float, sigma: float = 200.0, intensity: float = 2.0) -> Scene:
    """A homogeneous, optically very thick box (100 mean free paths from centre to wall) with a point light
    at its centre: photons practically never escape within 16 collisions."""
    vol = make_volume(np.ones((8, 8, 8)), window=(0.0, 1.0))
    return Scene(vol, constant_tf(sigma, albedo), (PointLight([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], intensity),),
                 small_camera(), 0.0, "dense")


@pytest.mark.parametrize("albedo", [0.5, 0.9])
def test_stored_energy_matches_analytic_series(albedo: float) -> None:
    """No escape: the power arriving at collision k is Phi * a^(k-1), so each phase's records carry
    Phi * sum_{k=2}^{M} a^(k-1) in total, Phi = 4 pi I. Checks emission, Russian roulette, the
    skip-first-interaction rule and the per-phase normalization together."""
    scene = _dense_scene(albedo)
    M = 16
    pmap = trace_photons(scene, 120_000, max_bounces=M, seed=4, progress=False)
    phi = 4 * math.pi * 2.0
    expected = phi * sum(albedo ** (k - 1) for k in range(2, M + 1))
    # With grey albedo, Russian roulette keeps every record's power at Phi / N, so a phase's total is
    # Phi * mean(c) with c the records per path: P(c >= j) = a^j for j <= M - 1. Its standard error
    # follows from E[c^2] = sum_j (2j - 1) a^j.
    j = np.arange(1, M)
    mean_c = np.sum(albedo**j)
    var_c = np.sum((2 * j - 1) * albedo**j) - mean_c**2
    assert expected == pytest.approx(phi * mean_c)
    for ph in range(3):
        total = pmap.power[pmap.phase == ph, 0].astype(np.float64).sum()
        n_paths = pmap.meta["emitted_per_phase"][ph]
        se = phi * math.sqrt(var_c / n_paths)
        assert abs(total - expected) < 4 * se, (ph, total, expected, se)


def test_phases_hold_equal_thirds() -> None:
    pmap = trace_photons(builtin_scene("blobs", resolution=32), 30_000, phases=PAPER_PHASES, seed=1,
                         progress=False)
    counts = np.bincount(pmap.phase, minlength=3)
    assert counts.sum() == len(pmap) >= 30_000
    assert np.all(np.abs(counts - 10_000) < 16)  # whole paths are kept: at most max_bounces - 1 extra
    assert pmap.metadata()["per_phase"] == counts.tolist()


@pytest.mark.parametrize("g_index", [0, 1, 2])
def test_directions_follow_hg_at_scattering(g_index: int) -> None:
    """Consecutive records of one path: the direction arriving at collision k+1 is the HG sample around
    the direction arriving at collision k. In the thick box no selection by escape biases it."""
    scene = _dense_scene(0.99)
    m = scene.medium()
    kind, vec, _ = scene.packed_lights()
    flux, cos_max = light_fluxes(scene)
    phases = np.array([-0.75, 0.0, 0.75])
    max_b = 3  # records at collisions 2 and 3
    slots = max_b - 1
    pos = np.empty((CHUNK * slots, 3), np.float32)
    dirs = np.empty((CHUNK * slots, 3), np.float32)
    pw = np.empty((CHUNK * slots, 3), np.float32)
    ph = np.empty(CHUNK * slots, np.uint8)
    cnt = np.empty(CHUNK, np.int64)
    cos = []
    for chunk in range(3):
        _trace_chunk(m, kind, vec, scene.packed_environment_map(), flux, cos_max, np.array([1.0]), phases,
                     np.array([g_index]), 9, chunk * CHUNK, CHUNK, max_b, 0.0, slots, pos, dirs, pw, ph,
                     np.empty(CHUNK * slots, np.uint8), np.empty(CHUNK * slots, np.uint8),
                     np.empty(CHUNK * slots, np.float32), cnt, np.empty(CHUNK, np.int64))
        both = np.flatnonzero(cnt == 2)
        d1 = dirs[both * slots].astype(np.float64)
        d2 = dirs[both * slots + 1].astype(np.float64)
        cos.append(np.einsum("ij,ij->i", d1, d2))
    mu = np.clip(np.concatenate(cos), -1, 1)
    g = phases[g_index]
    edges = equal_probability_edges(g, 30)
    counts, _ = np.histogram(mu, bins=edges)
    expected = np.diff(hg_cdf(g, edges))
    assert stats.chisquare(counts, expected / expected.sum() * counts.sum()).pvalue > 1e-3
    assert abs(mu.mean() - g) < 5 * mu.std() / math.sqrt(mu.size)


def test_tracing_kernel_refuses_an_unknown_light_kind() -> None:
    """A kind number no light has (pack_lights never makes one) stops the kernel instead of being emitted as
    another kind. numba reports an exception raised inside a prange loop as a SystemError whose cause is
    the kernel's ValueError."""
    scene = _dense_scene(0.5)
    n, max_b = 64, 4
    slots = max_b - 1
    out = [np.empty((n * slots, 3), np.float32) for _ in range(3)]
    with pytest.raises((ValueError, SystemError)) as info:
        _trace_chunk(scene.medium(), np.array([99]), np.zeros((1, 3)), NO_ENV_MAP, np.ones((1, 3)), np.array([-1.0]),
                     np.array([1.0]), np.array([0.0]), np.array([0]), 1, 0, n, max_b, 0.0, slots, *out,
                     np.empty(n * slots, np.uint8), np.empty(n * slots, np.uint8), np.empty(n * slots, np.uint8),
                     np.empty(n * slots, np.float32), np.empty(n, np.int64), np.empty(n, np.int64))
    assert "unknown light kind" in str(info.value) + repr(info.value.__cause__)


def test_same_seed_same_map_for_any_thread_count() -> None:
    scene = builtin_scene("shell", resolution=32)
    a = trace_photons(scene, 20_000, seed=3, progress=False)
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        b = trace_photons(scene, 20_000, seed=3, progress=False)
    finally:
        numba.set_num_threads(old)
    c = trace_photons(scene, 20_000, seed=4, progress=False)
    for name in ("position", "direction", "power", "phase"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.emitted == b.emitted
    assert not np.array_equal(a.position, c.position)


def test_records_are_past_first_interaction_inside_the_volume() -> None:
    scene = builtin_scene("blobs", resolution=32)
    pmap = trace_photons(scene, 20_000, seed=2, progress=False)
    m = scene.medium()
    assert np.all(pmap.position >= m.bmin - 1e-6) and np.all(pmap.position <= m.bmin + m.bsize + 1e-6)
    np.testing.assert_allclose(np.linalg.norm(pmap.direction, axis=1), 1.0, atol=1e-5)
    from photon_fields.runtime.transport.medium import extinction_batch

    # Records sit at real collisions, where sigma_t > 0.
    assert np.all(extinction_batch(m, pmap.position.T.astype(np.float64)) > 0)


def test_directional_light_flux_covers_the_box() -> None:
    vol = make_volume(np.ones((4, 4, 4)), window=(0.0, 1.0))
    scene = Scene(vol, constant_tf(1.0), (DirectionalLight([0, -1, 0], [1, 1, 1], 2.0),), small_camera())
    flux, _ = light_fluxes(scene)
    r = 0.5 * math.sqrt(3)
    np.testing.assert_allclose(flux[0], 2.0 * math.pi * r * r)


def test_distant_point_light_carries_the_power_of_a_directional_light() -> None:
    """A point light of intensity E D^2 at distance D = 1000 in direction -d lights the volume like a directional
    light of irradiance E travelling along d (up to O(box / D) = 0.1 %). The two emit by different code: the
    point light samples the cone towards the bounding sphere (solid-angle fraction ~4e-7 of its 4 pi I) and
    scales the photons' power by that fraction, the directional light samples a disk of flux E pi R^2. Their
    maps must carry the same stored power per channel, and the same power-weighted centroid. Measured over
    4 independent seed pairs (200k records, coloured albedo): ratios within 1.1 % of 1, centroids within
    0.0023 box units. Bounds 2.5 % and 0.01."""
    vol = make_volume(smooth_field(24), window=(0.0, 1.0), name="smooth")
    d = np.array([-0.5, -1.0, -0.3]) / np.linalg.norm([-0.5, -1.0, -0.3])
    D, E = 1000.0, 2.0
    maps = [trace_photons(Scene(vol, coloured_tf(), (light,), small_camera(), 0.0, "far"), 200_000, phases=(0.0,),
                          seed=seed, progress=False)
            for seed, light in ((1, DirectionalLight(d, [1.0, 0.9, 0.8], E)),
                                (2, PointLight(-D * d, [1.0, 0.9, 0.8], E * D * D)))]
    total = [m.power.astype(np.float64).sum(axis=0) for m in maps]
    centroid = [(m.position * m.power[:, :1]).sum(axis=0) / m.power[:, 0].sum() for m in maps]
    assert np.all(np.abs(total[1] / total[0] - 1.0) < 0.025), total
    assert np.all(np.abs(centroid[1] - centroid[0]) < 0.01), centroid


def test_save_load_round_trip_and_refusals(tmp_path) -> None:  # noqa: ANN001
    scene = builtin_scene("blobs", resolution=32)
    pmap = trace_photons(scene, 5_000, seed=2, progress=False)
    path = pmap.save(tmp_path / "m.npz")
    back = PhotonMap.load(path, expected_fingerprint=scene.fingerprint())
    for name in ("position", "direction", "power", "phase"):
        np.testing.assert_array_equal(getattr(pmap, name), getattr(back, name))
    assert back.phases == pmap.phases and back.emitted == pmap.emitted
    other = builtin_scene("shell", resolution=32)
    with pytest.raises(InputError, match="another scene"):
        PhotonMap.load(path, expected_fingerprint=other.fingerprint())
    bad = tmp_path / "bad.npz"
    bad.write_bytes(path.read_bytes()[:200])
    with pytest.raises(InputError, match="bad.npz"):
        PhotonMap.load(bad)
    with pytest.raises(InputError, match="not found"):
        PhotonMap.load(tmp_path / "missing.npz")


@pytest.mark.parametrize("kwargs, match", [({"photons": 0}, "positive"), ({"phases": []}, "empty"),
                                           ({"phases": [0.2, 1.5]}, r"\[-1, 1\]"), ({"max_bounces": 1}, "max_bounces")])
def test_bad_arguments(kwargs: dict, match: str) -> None:
    args = {"photons": 100, **kwargs}
    with pytest.raises(InputError, match=match):
        trace_photons(builtin_scene("blobs", resolution=32), args.pop("photons"), progress=False, **args)


def test_lights_that_never_reach_the_volume_are_reported() -> None:
    vol = make_volume(np.ones((4, 4, 4)), window=(0.0, 1.0))
    black = constant_tf(50.0, albedo=0.0)  # every photon is absorbed at its first collision
    scene = Scene(vol, black, (DirectionalLight([0, -1, 0], [1, 1, 1], 1.0),), small_camera())
    with pytest.raises(InputError, match="scatters twice"):
        trace_photons(scene, 1000, progress=False)


def test_environment_map_photons_keep_the_colour_of_their_direction() -> None:
    """Under a map whose upper half is pure red and lower half pure blue, in a white (albedo 1, so no roulette)
    medium, every photon record carries the colour of the half its photon came from (exactly one of R and B),
    and both halves are represented: the tracer applies emit_photon's per-channel power scale L / (p int L). With
    the scale dropped every photon would carry the map's average colour."""
    h = 8
    img = np.zeros((h, 2 * h, 3), np.float32)
    img[: h // 2, :, 0] = 1.0
    img[h // 2:, :, 2] = 2.0
    vol = make_volume(np.ones((8, 8, 8)), window=(0.0, 1.0))
    scene = Scene(vol, constant_tf(4.0, 1.0), (EnvironmentMap("halves", image=img, rotation=[0.0, 30.0, 0.0]),),
                  small_camera(), 0.0, "halves")
    pmap = trace_photons(scene, 20_000, phases=(0.0,), max_bounces=4, seed=2, progress=False)
    pw = pmap.power
    assert np.all(pw[:, 1] == 0.0)
    red, blue = pw[:, 0] > 0, pw[:, 2] > 0
    assert not np.any(red & blue) and np.all(red | blue)
    assert 0.2 < red.mean() < 0.8


def test_a_trace_past_its_deadline_is_the_full_traces_first_paths() -> None:
    """``deadline`` (the update's time-capped retrace) stops after the chunk that passes it once ``min_photons``
    records are held: every phase's records are then the first ones of the full trace with the same seed (the
    same paths' random streams), and each phase's power is normalized by its own emitted paths (unbiased)."""
    scene = builtin_scene("blobs", resolution=32)
    full = trace_photons(scene, 60_000, phases=PAPER_PHASES, seed=5, progress=False)
    capped = trace_photons(scene, 60_000, phases=PAPER_PHASES, seed=5, progress=False, deadline=0.0,
                           min_photons=2_000)
    assert 2_000 <= len(capped) < len(full)
    assert sum(capped.meta["emitted_per_phase"]) == CHUNK  # one chunk of paths, over the three phases
    for ph in range(3):
        a, b = capped.phase == ph, full.phase == ph
        n = int(a.sum())
        assert n > 0
        np.testing.assert_array_equal(capped.position[a], full.position[b][:n])
        np.testing.assert_array_equal(capped.direction[a], full.direction[b][:n])
        rescale = capped.meta["emitted_per_phase"][ph] / full.meta["emitted_per_phase"][ph]
        np.testing.assert_allclose(capped.power[a] * rescale, full.power[b][:n], rtol=1e-6)
    # not before min_photons: a deadline long past still traces on until they are there
    floor = trace_photons(scene, 60_000, phases=PAPER_PHASES, seed=5, progress=False, deadline=0.0,
                          min_photons=len(capped) + 1)
    assert len(floor) > len(capped)
