"""Per-light-kind transport (runtime.transport.emitters): the photon emission samplers' distributions
(chi-square against the uniform distributions they must produce), fluxes and emission cones against the
geometry of the bounding sphere, the direct-light samples, and the refusal of an unknown kind.

The chi-square tests bin the samples' coordinates transformed to [0, 1) (cosine, squared disk radius,
azimuth), where the correct sampler is uniform, in joint 2-D histograms of 10 x 12 cells (so a correlation
between two coordinates fails too) and require p > 1e-3; 240k samples give ~2000 per cell. Over 100 seeds
the correct samplers' p-values were uniform (Kolmogorov-Smirnov p 0.15-0.73), so a false alarm has
probability 1e-3 per check; the seeds here are fixed. Planted bugs they catch (bench/mutants.py:
``point_cone_angle_uniform``, ``disk_radius_uniform``, ``env_emission_reuses_disk_numbers``): the cone's
angle sampled uniformly instead of its cosine, the disk's radius uniform instead of its square, the
environment's direction drawn from the disk's random numbers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import constant_tf
from numba import njit
from scipy import stats

from photon_fields.runtime.scene.lights import DIRECTIONAL, ENVIRONMENT, ENVIRONMENT_MAP, POINT
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.direct_light import direct_light_batch
from photon_fields.runtime.transport.emitters import (
    delta_light_direction,
    emission_fluxes,
    emit_photon,
    environment_index,
    sample_light_direction,
)
from photon_fields.runtime.transport.environment_map import (
    NO_ENV_MAP,
    EnvMap,
    build_env_map,
    env_map_eval_batch,
    rotation_matrix,
)
from photon_fields.runtime.transport.medium import Medium, build_medium
from photon_fields.runtime.transport.rng import next_float, stream_states, uniform_batch

N = 240_000
P_MIN = 1e-3
UNKNOWN = 99  # no light kind has this number
ONES = np.ones(3)  # a light's rgb: the samples' values are per unit rgb


@pytest.fixture(scope="module")
def medium() -> Medium:
    """A non-cubic box (1 x 0.75 x 0.5, centred at the origin)."""
    return build_medium(make_volume(np.ones((8, 6, 4)), window=(0.0, 1.0)), constant_tf(1.0))


def bounding_sphere(m: Medium) -> tuple[np.ndarray, float]:
    return m.bmin + 0.5 * m.bsize, 0.5 * float(np.linalg.norm(m.bsize))


@njit
def _emit_batch(kind: int, vec: np.ndarray, cos_max: float, c: np.ndarray, radius: float,
                u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    o = np.empty((u.shape[0], 3))
    w = np.empty((u.shape[0], 3))
    for i in range(u.shape[0]):
        o[i, 0], o[i, 1], o[i, 2], w[i, 0], w[i, 1], w[i, 2], _, _, _ = emit_photon(
            kind, vec, NO_ENV_MAP, cos_max, c[0], c[1], c[2], radius, u[i, 0], u[i, 1], u[i, 2], u[i, 3])
    return o, w


@njit
def _environment_nee_batch(states: np.ndarray) -> np.ndarray:
    out = np.empty((states.shape[0], 5))
    vec = np.zeros(3)
    for i in range(states.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3], _, _, out[i, 4], _, states[i] = sample_light_direction(
            ENVIRONMENT, vec, ONES, NO_ENV_MAP, 0.1, 0.2, 0.3, states[i])
    return out


def emit(kind: int, vec: np.ndarray, cos_max: float, m: Medium, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """N photons (origins (N, 3), travel directions (N, 3)) from the project's own random streams."""
    c, radius = bounding_sphere(m)
    u = uniform_batch(stream_states(seed, 0, N), 4)
    return _emit_batch(kind, np.asarray(vec, dtype=np.float64), cos_max, c, radius, u)


def frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing each row of ``axis`` (n, 3) to an orthonormal frame (independent of the
    code under test's ``orthonormal_basis``)."""
    helper = np.array([0.267, 0.535, 0.802])
    t = np.cross(axis, helper)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    return t, np.cross(axis, t)


def azimuth01(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The azimuth of each row of ``v`` around ``axis`` (rows or one vector), mapped to [0, 1)."""
    t, b = frame(np.broadcast_to(axis, v.shape))
    return (np.arctan2(np.einsum("ij,ij->i", v, b), np.einsum("ij,ij->i", v, t)) / (2 * math.pi)) % 1.0


def joint_uniform_p(a: np.ndarray, b: np.ndarray, bins: tuple[int, int] = (10, 12)) -> float:
    """Chi-square p-value of (a, b) against the uniform distribution on [0, 1)^2."""
    counts, _, _ = np.histogram2d(a, b, bins=bins, range=((0.0, 1.0), (0.0, 1.0)))
    assert counts.sum() == a.size, "samples outside [0, 1)"
    return float(stats.chisquare(counts.ravel()).pvalue)


def disk_coordinates(o: np.ndarray, w: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(signed distance of each origin from the centre along its direction, lateral offset (n, 3))."""
    rel = o - c
    s = np.einsum("ij,ij->i", rel, w)
    return s, rel - s[:, None] * w


# --- emission ---------------------------------------------------------------------------------------


def test_point_light_outside_emits_uniformly_into_the_cone_that_subtends_the_sphere(medium: Medium) -> None:
    """Outside the bounding sphere: every photon starts at the light and its line passes through the sphere;
    cos(angle to the centre) is uniform on [cos_max, 1] and the azimuth uniform (the cone's solid angle,
    uniformly); the cone is the sphere's: isotropic directions hit the sphere with probability
    (1 - cos_max) / 2; the flux is I times the cone's solid angle."""
    c, radius = bounding_sphere(medium)
    pos = c + np.array([0.9, 0.6, 0.2])
    rgb = np.array([[0.5, 1.0, 2.0]])
    dist = float(np.linalg.norm(pos - c))
    assert dist > radius
    flux, cos_max = emission_fluxes(medium, np.array([POINT]), pos[None], rgb)
    assert cos_max[0] == pytest.approx(math.sqrt(1.0 - (radius / dist) ** 2), rel=1e-14)
    np.testing.assert_allclose(flux[0], rgb[0] * 2 * math.pi * (1.0 - cos_max[0]), rtol=1e-14)

    o, w = emit(POINT, pos, float(cos_max[0]), medium, seed=5)
    assert np.all(o == pos)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    to_c = c - pos
    along = w @ to_c
    assert np.all(along > 0.0)
    miss = np.linalg.norm(to_c[None] - along[:, None] * w, axis=1)
    assert miss.max() <= radius * (1 + 1e-9)
    axis = to_c / dist
    mu = w @ axis
    assert mu.min() >= cos_max[0] - 1e-12
    x = np.minimum((1.0 - mu) / (1.0 - cos_max[0]), np.nextafter(1.0, 0.0))
    assert joint_uniform_p(x, azimuth01(w, axis)) > P_MIN

    # The cone is the set of directions that reach the sphere (not narrower, not wider).
    iso = np.random.default_rng(1).normal(size=(N, 3))
    iso /= np.linalg.norm(iso, axis=1, keepdims=True)
    a = iso @ to_c
    hits = (a > 0) & (np.linalg.norm(to_c[None] - a[:, None] * iso, axis=1) <= radius)
    q = (1.0 - cos_max[0]) / 2.0
    assert abs(hits.mean() - q) < 5 * math.sqrt(q * (1 - q) / N)


def test_point_light_inside_emits_uniformly_over_the_whole_sphere(medium: Medium) -> None:
    c, _ = bounding_sphere(medium)
    pos = c + np.array([0.1, -0.2, 0.05])
    rgb = np.array([[1.0, 0.5, 0.25]])
    flux, cos_max = emission_fluxes(medium, np.array([POINT]), pos[None], rgb)
    assert cos_max[0] == -1.0
    np.testing.assert_allclose(flux[0], 4 * math.pi * rgb[0], rtol=1e-14)
    o, w = emit(POINT, pos, -1.0, medium, seed=6)
    assert np.all(o == pos)
    axis = np.array([0.0, 0.6, 0.8])
    x = np.minimum((1.0 - w @ axis) / 2.0, np.nextafter(1.0, 0.0))
    assert joint_uniform_p(x, azimuth01(w, axis)) > P_MIN


def test_directional_light_emits_parallel_rays_uniformly_over_a_disk_across_the_sphere(medium: Medium) -> None:
    """Every photon travels along the light's direction from a disk of radius R perpendicular to it,
    1.01 R behind the centre, uniform over the disk's area; the flux is E pi R^2."""
    c, radius = bounding_sphere(medium)
    d = np.array([-0.5, -1.0, -0.3]) / np.linalg.norm([-0.5, -1.0, -0.3])
    rgb = np.array([[3.0, 2.0, 1.0]])
    flux, cos_max = emission_fluxes(medium, np.array([DIRECTIONAL]), d[None], rgb)
    np.testing.assert_allclose(flux[0], rgb[0] * math.pi * radius**2, rtol=1e-14)
    o, w = emit(DIRECTIONAL, d, float(cos_max[0]), medium, seed=7)
    assert np.all(w == d)
    s, lateral = disk_coordinates(o, w, c)
    np.testing.assert_allclose(s, -1.01 * radius, rtol=1e-12)
    r2 = (np.linalg.norm(lateral, axis=1) / radius) ** 2
    assert r2.max() < 1.0 + 1e-12
    assert joint_uniform_p(np.minimum(r2, np.nextafter(1.0, 0.0)), azimuth01(lateral, d)) > P_MIN


def test_environment_emits_uniform_directions_through_a_disk_across_the_sphere(medium: Medium) -> None:
    """Uniform travel directions, each from a disk perpendicular to it as for the directional light,
    with the disk position independent of the direction; flux 4 pi^2 R^2 L."""
    c, radius = bounding_sphere(medium)
    rgb = np.array([[0.9, 1.0, 1.1]])
    flux, cos_max = emission_fluxes(medium, np.array([ENVIRONMENT]), np.zeros((1, 3)), rgb)
    np.testing.assert_allclose(flux[0], rgb[0] * 4 * math.pi**2 * radius**2, rtol=1e-14)
    o, w = emit(ENVIRONMENT, np.zeros(3), float(cos_max[0]), medium, seed=8)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    axis = np.array([0.0, 0.6, 0.8])
    x = np.minimum((1.0 - w @ axis) / 2.0, np.nextafter(1.0, 0.0))
    assert joint_uniform_p(x, azimuth01(w, axis)) > P_MIN
    s, lateral = disk_coordinates(o, w, c)
    np.testing.assert_allclose(s, -1.01 * radius, rtol=1e-12)
    r2 = np.minimum((np.linalg.norm(lateral, axis=1) / radius) ** 2, np.nextafter(1.0, 0.0))
    assert joint_uniform_p(r2, azimuth01(lateral, w)) > P_MIN
    assert joint_uniform_p(x, r2) > P_MIN  # disk position independent of the direction


@njit
def _emit_map_batch(env: EnvMap, c: np.ndarray, radius: float, u: np.ndarray) -> tuple[np.ndarray, ...]:
    o, w, scale = np.empty((u.shape[0], 3)), np.empty((u.shape[0], 3)), np.empty((u.shape[0], 3))
    for i in range(u.shape[0]):
        r = emit_photon(ENVIRONMENT_MAP, np.zeros(3), env, -1.0, c[0], c[1], c[2], radius, u[i, 0], u[i, 1], u[i, 2],
                        u[i, 3])
        o[i, 0], o[i, 1], o[i, 2], w[i, 0], w[i, 1], w[i, 2] = r[0], r[1], r[2], r[3], r[4], r[5]
        scale[i, 0], scale[i, 1], scale[i, 2] = r[6], r[7], r[8]
    return o, w, scale


def test_environment_map_photons_carry_the_maps_radiance_by_direction(medium: Medium) -> None:
    """A map photon travels along -w with w from the map's density, from a disk as for the constant environment,
    and its power scale s_c = L_c(w) / (p(w) int L_c) makes the weighted directions follow each channel's own
    radiance: per cell of arriving directions w (6 x 8 in cos theta, phi), mean(s_c 1[w in cell]) = int_cell L_c dw
    / int L_c dw (z < 5). The map's channels differ by direction (a red sun, a blue sky, a green ground), so the
    luminance-based density alone (s = 1) fails, and so does a photon travelling towards its light. Flux
    pi R^2 int L dw per channel."""
    h = 16
    img = np.zeros((h, 2 * h, 3))
    img[: h // 2] = [0.1, 0.3, 1.0]
    img[h // 2:] = [0.05, 0.4, 0.05]
    img[3:5, 10:12] = [60.0, 20.0, 2.0]
    env = build_env_map(img, rotation_matrix(30.0, 20.0))
    c, radius = bounding_sphere(medium)
    flux, _ = emission_fluxes(medium, np.array([ENVIRONMENT_MAP]), np.zeros((1, 3)), np.ones((1, 3)), env)
    np.testing.assert_allclose(flux[0], math.pi * radius**2 * env.integral, rtol=1e-14)
    o, d, scale = _emit_map_batch(env, c, radius, uniform_batch(stream_states(12, 0, N), 4))
    s, lateral = disk_coordinates(o, d, c)
    np.testing.assert_allclose(s, -1.01 * radius, rtol=1e-12)
    assert (np.linalg.norm(lateral, axis=1) / radius).max() < 1.0 + 1e-12
    w = -d  # where the light comes from
    bins = (6, 8)
    zi = np.minimum(((w[:, 1] + 1) / 2 * bins[0]).astype(int), bins[0] - 1)
    pi = np.minimum(((np.arctan2(w[:, 2], w[:, 0]) / (2 * math.pi)) % 1.0 * bins[1]).astype(int), bins[1] - 1)
    cell = zi * bins[1] + pi
    # Expected: each channel's radiance integrated over the cells on a fine (cos theta, phi) grid.
    sub = 60
    nz, nphi = bins[0] * sub, bins[1] * sub
    zz, pp = np.meshgrid(-1 + 2 * (np.arange(nz) + 0.5) / nz, 2 * math.pi * (np.arange(nphi) + 0.5) / nphi,
                         indexing="ij")
    ss = np.sqrt(1 - zz**2)
    rad, _ = env_map_eval_batch(env, np.stack([ss * np.cos(pp), zz, ss * np.sin(pp)]).reshape(3, -1))
    dw = (2.0 / nz) * (2 * math.pi / nphi)
    for ch in range(3):
        per_cell = (rad[ch].reshape(nz, nphi) * dw).reshape(bins[0], sub, bins[1], sub).sum(axis=(1, 3)).ravel()
        expected = per_cell / env.integral[ch]
        x = np.zeros((N, bins[0] * bins[1]))
        x[np.arange(N), cell] = scale[:, ch]
        z = (x.mean(axis=0) - expected) / (x.std(axis=0) / math.sqrt(N) + 1e-12)
        assert np.abs(z).max() < 5.0, (ch, np.abs(z).max())
        assert abs(scale[:, ch].mean() - 1.0) < 5 * scale[:, ch].std() / math.sqrt(N)


# --- direct-light sampling --------------------------------------------------------------------------


def test_delta_light_samples_point_at_the_light() -> None:
    p = np.array([0.1, -0.2, 0.3])
    pos = np.array([0.9, 0.6, 0.2])
    state = np.uint64(12345)
    lx, ly, lz, value, _, _, pdf, dist, st = sample_light_direction(POINT, pos, ONES, NO_ENV_MAP, *p, state)
    r = float(np.linalg.norm(pos - p))
    np.testing.assert_allclose([lx, ly, lz], (pos - p) / r, rtol=1e-14)
    assert value == pytest.approx(1.0 / r**2, rel=1e-14) and dist == pytest.approx(r, rel=1e-14)
    assert math.isinf(pdf) and st == state
    assert sample_light_direction(POINT, p, ONES, NO_ENV_MAP, *p, state)[3] == 0.0  # on the light: no contribution
    d = np.array([0.0, -0.6, -0.8])
    lx, ly, lz, value, _, _, pdf, dist, st = sample_light_direction(DIRECTIONAL, d, ONES, NO_ENV_MAP, *p, state)
    assert [lx, ly, lz] == (-d).tolist() and value == 1.0 and math.isinf(pdf) and math.isinf(dist)
    assert st == state
    assert delta_light_direction(ENVIRONMENT, d, *p)[3] == 0.0  # not a delta light: the ray marcher skips it


def test_environment_direct_light_samples_are_uniform_on_the_sphere() -> None:
    states = stream_states(4, 0, N)
    first = states[0]
    out = _environment_nee_batch(states)
    st, _ = next_float(first)
    st, _ = next_float(st)
    assert int(states[0]) == int(st) % 2**64  # two random numbers per sample (numba returns the state signed)
    np.testing.assert_array_equal(out[:, 3], 1.0)
    np.testing.assert_array_equal(out[:, 4], 1.0 / (4.0 * math.pi))  # ENVIRONMENT_PDF, the path tracer's MIS pdf
    w = out[:, :3]
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), 1.0, atol=1e-12)
    axis = np.array([0.48, 0.0, 0.8]) / np.linalg.norm([0.48, 0.0, 0.8])
    x = np.minimum((1.0 - w @ axis) / 2.0, np.nextafter(1.0, 0.0))
    assert joint_uniform_p(x, azimuth01(w, axis)) > P_MIN


def test_environment_index() -> None:
    assert environment_index(np.array([POINT, DIRECTIONAL])) == -1
    assert environment_index(np.array([POINT, ENVIRONMENT])) == 1


# --- unknown kinds -----------------------------------------------------------------------------------


def test_unknown_light_kind_is_refused_by_every_branch(medium: Medium) -> None:
    """pack_lights refuses unknown light classes; the kernels refuse an unknown kind number too, instead of
    treating it as one of the others."""
    v = np.array([0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="unknown light kind"):
        emission_fluxes(medium, np.array([POINT, UNKNOWN]), np.stack([v, v]), np.ones((2, 3)))
    with pytest.raises(ValueError, match="unknown light kind"):
        emit_photon(UNKNOWN, v, NO_ENV_MAP, -1.0, 0.0, 0.0, 0.0, 1.0, 0.1, 0.2, 0.3, 0.4)
    with pytest.raises(ValueError, match="unknown light kind"):
        delta_light_direction(UNKNOWN, v, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="unknown light kind"):
        sample_light_direction(UNKNOWN, v, ONES, NO_ENV_MAP, 0.0, 0.0, 0.0, np.uint64(1))
    with pytest.raises(ValueError, match="unknown light kind"):
        direct_light_batch(medium, np.array([UNKNOWN]), v[None], np.ones((1, 3)), NO_ENV_MAP, 0.0, np.zeros((3, 4)),
                           np.ones((3, 4)), np.arange(4, dtype=np.uint64))
