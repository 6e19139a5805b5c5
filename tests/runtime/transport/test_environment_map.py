"""The environment map's importance sampling and lookup (runtime.transport.environment_map).

- the sampler against its own pdf: a chi-square test of 240k samples binned in *world* coordinates (cos theta,
  phi about +y: 12 x 16 cells, independent of the map's parametrization) against the cells' probabilities
  integrated from ``env_map_eval``'s pdf on a fine grid (dw = dz dphi), for a rotated map (yaw 30, pitch 20, so
  cells and pixels do not line up); the pdf returned by a sample equals the lookup's;
- the pdf integrates to 1 over the sphere (Monte Carlo with uniform directions, 1M: +-0.3 %);
- the density follows luminance x solid angle: at every pixel centre p_w * int lum dw / lum = 1 up to the
  sin(theta) variation inside a row (0.2 % at H = 16);
- the convention (top row +y, u = 0 -> -z, u = 1/4 -> +x) and the rotation (yaw 90 == the image rolled by 3W/4);
- the integral int L dw is exact (4 pi L for a constant map).

Planted bugs these kill (bench/mutants.py): ``env_pdf_without_sin_theta`` (the lookup's Jacobian 2 pi^2 without
sin theta), ``env_sample_pdf_without_sin_theta`` (the same in the sample's pdf), ``env_weights_without_sin_theta``
(the tables weighted by luminance alone: still self-consistent, so only the luminance-x-solid-angle test sees
it), ``env_row_offset_from_column_number`` (the row's continuous offset taken from the column's random number),
``env_rotation_not_inverted`` (the lookup rotating by R instead of R^T).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit
from scipy import stats

from photon_fields.runtime.transport.environment_map import (
    LUMINANCE,
    EnvMap,
    build_env_map,
    env_map_eval,
    env_map_eval_batch,
    env_map_sample,
    rotation_matrix,
    sphere_integral,
)
from photon_fields.runtime.transport.rng import stream_states, uniform_batch

N = 240_000
P_MIN = 1e-3


def sky_map(h: int = 16, seed: int = 0) -> np.ndarray:
    """A 2:1 map with a sky gradient, a bright sun patch, coloured pixels and a black band: (h, 2h, 3)."""
    rng = np.random.default_rng(seed)
    w = 2 * h
    v = (np.arange(h) + 0.5) / h
    img = np.empty((h, w, 3))
    img[:] = (0.2 + 1.5 * (1 - v))[:, None, None] * np.array([0.6, 0.8, 1.0])
    img *= rng.uniform(0.5, 1.5, (h, w, 1))
    img[h // 4: h // 4 + 2, w // 3: w // 3 + 2] = [40.0, 30.0, 20.0]  # the sun
    img[h - 2:, :] = 0.0  # a black band near the bottom pole
    return img


@njit
def _sample_batch(env: EnvMap, u: np.ndarray) -> np.ndarray:
    out = np.empty((u.shape[0], 7))
    for i in range(u.shape[0]):
        r = env_map_sample(env, u[i, 0], u[i, 1])
        for k in range(7):
            out[i, k] = r[k]
    return out


@njit
def _eval_batch(env: EnvMap, d: np.ndarray) -> np.ndarray:
    out = np.empty((d.shape[0], 4))
    for i in range(d.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = env_map_eval(env, d[i, 0], d[i, 1], d[i, 2])
    return out


def world_coordinates(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cos theta about +y mapped to [0, 1), phi in [0, 1)) of directions (n, 3)."""
    z01 = np.minimum((d[:, 1] + 1.0) / 2.0, np.nextafter(1.0, 0.0))
    return z01, (np.arctan2(d[:, 2], d[:, 0]) / (2 * math.pi)) % 1.0


def cell_probabilities(env: EnvMap, bins: tuple[int, int], sub: int = 100) -> np.ndarray:
    """Probability of each (cos theta, phi) cell: the lookup's pdf integrated by the midpoint rule."""
    nz, nphi = bins[0] * sub, bins[1] * sub
    z = -1.0 + 2.0 * (np.arange(nz) + 0.5) / nz
    phi = 2 * math.pi * (np.arange(nphi) + 0.5) / nphi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1 - zz**2)
    d = np.stack([s * np.cos(pp), zz, s * np.sin(pp)]).reshape(3, -1)
    _, pdf = env_map_eval_batch(env, d)
    dw = (2.0 / nz) * (2 * math.pi / nphi)
    return (pdf.reshape(nz, nphi) * dw).reshape(bins[0], sub, bins[1], sub).sum(axis=(1, 3))


def test_sampler_matches_its_own_pdf_chi_square() -> None:
    env = build_env_map(sky_map(), rotation_matrix(30.0, 20.0))
    s = _sample_batch(env, uniform_batch(stream_states(7, 0, N), 2))
    d = s[:, :3]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert np.all(s[:, 6] > 0)
    bins = (12, 16)
    counts, _, _ = np.histogram2d(*world_coordinates(d), bins=bins, range=((0, 1), (0, 1)))
    expected = cell_probabilities(env, bins)
    assert abs(expected.sum() - 1.0) < 2e-3
    keep = expected.ravel() * N >= 5
    obs, exp = counts.ravel()[keep], expected.ravel()[keep] * N
    assert counts.ravel()[~keep].sum() <= 5 * max(1, int((~keep).sum()))
    assert stats.chisquare(obs, exp * obs.sum() / exp.sum()).pvalue > P_MIN


def test_sample_reports_the_lookups_radiance_and_pdf() -> None:
    env = build_env_map(sky_map(), rotation_matrix(-70.0, 10.0, 5.0))
    s = _sample_batch(env, uniform_batch(stream_states(8, 0, 20_000), 2))
    e = _eval_batch(env, np.ascontiguousarray(s[:, :3]))
    same = np.isclose(s[:, 6], e[:, 3], rtol=1e-9) & np.all(np.isclose(s[:, 3:6], e[:, :3], rtol=1e-12), axis=1)
    assert same.mean() > 0.999  # only samples on a pixel border may land in the neighbour


def test_pdf_integrates_to_one_over_the_sphere() -> None:
    env = build_env_map(sky_map(), rotation_matrix(45.0, -30.0))
    rng = np.random.default_rng(3)
    d = rng.normal(size=(3, 1_000_000))
    d /= np.linalg.norm(d, axis=0)
    _, pdf = env_map_eval_batch(env, d)
    est = 4 * math.pi * pdf
    assert abs(est.mean() - 1.0) < 4 * est.std() / math.sqrt(est.size)
    assert abs(est.mean() - 1.0) < 0.01
    # and the table itself is a density on [0, 1]^2
    assert env.pdf_uv.mean() == pytest.approx(1.0, rel=1e-12)


def test_density_follows_luminance_times_solid_angle() -> None:
    """At each pixel centre, p_w = lum / int lum dw up to sin(theta)'s variation within the row (H = 16: the
    row's solid angle / (pi/H sin theta_c) = 0.9984): the sampler is proportional to the radiance, which keeps
    the NEE and photon weights L / p near-constant. Black pixels have p = 0."""
    img = sky_map()
    env = build_env_map(img)
    h, w = img.shape[:2]
    lum = img @ LUMINANCE
    total = float(sphere_integral(np.repeat(lum[..., None], 3, axis=-1))[0])
    v, u = (np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w
    vv, uu = np.meshgrid(v, u, indexing="ij")
    th, ph = math.pi * vv, 2 * math.pi * uu
    d = np.stack([np.sin(th) * np.sin(ph), np.cos(th), -np.sin(th) * np.cos(ph)]).reshape(3, -1)
    _, pdf = env_map_eval_batch(env, d)
    pdf = pdf.reshape(h, w)
    lit = lum > 0
    np.testing.assert_allclose(pdf[lit] * total / lum[lit], 1.0, rtol=3e-3)
    assert np.all(pdf[~lit] == 0.0)


def test_convention_top_row_is_up_and_u_zero_looks_along_minus_z() -> None:
    h, w = 8, 16
    for (i, j), direction in {(0, 0): [0, 1, 0], (h - 1, 0): [0, -1, 0], (h // 2, 0): [0, 0, -1],
                              (h // 2, w // 4): [1, 0, 0], (h // 2, w // 2): [0, 0, 1],
                              (h // 2, 3 * w // 4): [-1, 0, 0]}.items():
        img = np.zeros((h, w, 3))
        img[i, j] = 1.0
        env = build_env_map(img)
        s = _sample_batch(env, uniform_batch(stream_states(1, 0, 2000), 2))
        mean = s[:, :3].mean(axis=0)
        assert np.dot(mean / np.linalg.norm(mean), direction) > 0.9, ((i, j), mean)


def test_yaw_90_equals_the_image_rolled_by_three_quarters() -> None:
    """Yaw 90 turns the map's -z (u = 0) to the world's -x (u = 3/4): the rotated map looks up like the image
    rolled by 3W/4 columns, in every direction (lookup and pdf)."""
    img = sky_map()
    rotated = build_env_map(img, rotation_matrix(90.0))
    rolled = build_env_map(np.roll(img, 3 * img.shape[1] // 4, axis=1))
    rng = np.random.default_rng(5)
    d = rng.normal(size=(3, 20_000))
    d /= np.linalg.norm(d, axis=0)
    a, pa = env_map_eval_batch(rotated, d)
    b, pb = env_map_eval_batch(rolled, d)
    same = np.all(np.isclose(a, b, rtol=1e-12), axis=0) & np.isclose(pa, pb, rtol=1e-9)
    assert same.mean() > 0.999  # directions on a column border may round to either side
    np.testing.assert_allclose(rotation_matrix(90.0) @ [0, 0, -1], [-1, 0, 0], atol=1e-15)


def test_integral_is_exact() -> None:
    const = np.full((16, 32, 3), 1.0) * np.array([0.5, 1.0, 2.0])
    np.testing.assert_allclose(sphere_integral(const), 4 * math.pi * np.array([0.5, 1.0, 2.0]), rtol=1e-12)
    img = sky_map()
    env = build_env_map(img)
    # Monte Carlo over uniform directions agrees with the closed form for a non-constant map.
    rng = np.random.default_rng(9)
    d = rng.normal(size=(3, 400_000))
    d /= np.linalg.norm(d, axis=0)
    rgb, _ = env_map_eval_batch(env, d)
    est = 4 * math.pi * rgb
    se = est.std(axis=1) / math.sqrt(est.shape[1])
    assert np.all(np.abs(est.mean(axis=1) - env.integral) < 4.5 * se)


def test_black_map_still_has_valid_tables() -> None:
    env = build_env_map(np.zeros((4, 8, 3)))
    s = _sample_batch(env, uniform_batch(stream_states(2, 0, 1000), 2))
    assert np.all(np.isfinite(s)) and np.all(s[:, 3:6] == 0.0)
    assert env.integral.tolist() == [0.0, 0.0, 0.0]
