"""Henyey-Greenstein: normalization, mean cosine, sampling distribution (chi-square), edge cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import equal_probability_edges, hg_cdf
from scipy import integrate, stats

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.transport.phase import check_g, hg_eval, hg_eval_batch, sample_hg_batch
from photon_fields.runtime.transport.rng import stream_states, uniform_batch

G_VALUES = [-0.99, -0.75, -0.3, 0.0, 1e-5, 0.3, 0.75, 0.99]


def _quad_over_mu(g: float, fn) -> float:  # noqa: ANN001
    # Integrate 2 pi * fn(mu) * p(mu) d mu with the peak at mu = sign(g) resolved (points hint).
    val, _ = integrate.quad(lambda mu: 2 * math.pi * fn(mu) * hg_eval(g, mu), -1.0, 1.0,
                            points=[math.copysign(1 - 1e-3, g)] if abs(g) > 0.5 else None, limit=500,
                            epsabs=1e-12, epsrel=1e-10)
    return val


@pytest.mark.parametrize("g", G_VALUES)
def test_pdf_integrates_to_one(g: float) -> None:
    assert _quad_over_mu(g, lambda mu: 1.0) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("g", G_VALUES)
def test_mean_cosine_equals_g(g: float) -> None:
    assert _quad_over_mu(g, lambda mu: mu) == pytest.approx(g, abs=1e-6)


def test_isotropic_value() -> None:
    assert hg_eval(0.0, 0.3) == pytest.approx(1 / (4 * math.pi))


def test_delta_limit() -> None:
    # |g| = 1 is a Dirac delta: no density anywhere, and sampling returns the delta direction with pdf inf.
    assert hg_eval(1.0, 0.5) == 0.0 and hg_eval(-1.0, -0.99) == 0.0
    d = np.array([[0.0], [0.0], [1.0]])
    for g in (1.0, -1.0):
        out = sample_hg_batch(g, d, np.array([[0.37, 0.81]]))
        assert out[2, 0] == pytest.approx(g) and math.isinf(out[3, 0])


def test_cdf_matches_pdf_quadrature() -> None:
    for g in (-0.8, 0.3, 0.95):
        val, _ = integrate.quad(lambda mu, g=g: 2 * math.pi * hg_eval(g, mu), -1.0, 0.2, limit=200)
        assert hg_cdf(g, np.array(0.2)) == pytest.approx(val, rel=1e-8)


def _samples(g: float, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(3, n))
    d /= np.linalg.norm(d, axis=0)
    u = uniform_batch(stream_states(seed, 0, n), 2)
    out = sample_hg_batch(g, d, u)
    return d, out


@pytest.mark.parametrize("g", [-0.9, -0.5, 0.0, 0.4, 0.8, 0.97])
def test_sampling_chi_square(g: float) -> None:
    """Sampled cosines (relative to a random incoming direction) follow p_g: chi-square over 40 bins of
    equal probability under the analytic CDF; azimuths are uniform."""
    n = 200_000
    d, out = _samples(g, n, seed=11)
    w = out[:3]
    assert np.allclose(np.linalg.norm(w, axis=0), 1.0, atol=1e-12)
    mu = np.einsum("ij,ij->j", d, w)
    # Bins of (about) equal probability under the analytic CDF; expected counts from the CDF itself.
    edges = equal_probability_edges(g, 40)
    counts, _ = np.histogram(mu, bins=edges)
    expected = n * np.diff(hg_cdf(g, edges))
    chi2, p = stats.chisquare(counts, expected * counts.sum() / expected.sum())
    assert p > 1e-3, f"chi2={chi2:.1f} p={p:.2e}"
    # Mean cosine of the samples equals g within 5 standard errors.
    assert abs(mu.mean() - g) < 5 * mu.std() / math.sqrt(n)
    # Azimuth around d: uniform.
    t = np.cross(d.T, np.array([0.3, 0.5, 0.81]) / np.linalg.norm([0.3, 0.5, 0.81])).T
    t /= np.linalg.norm(t, axis=0)
    b = np.cross(d.T, t.T).T
    phi = np.arctan2(np.einsum("ij,ij->j", w, b), np.einsum("ij,ij->j", w, t))
    sel = np.abs(mu) < 0.999  # azimuth undefined along the axis
    c2, _ = np.histogram(phi[sel], bins=24, range=(-math.pi, math.pi))
    assert stats.chisquare(c2).pvalue > 1e-3


def test_sampler_pdf_matches_eval() -> None:
    d, out = _samples(0.6, 1000, seed=3)
    mu = np.einsum("ij,ij->j", d, out[:3])
    assert np.allclose(out[3], hg_eval_batch(0.6, mu), rtol=1e-9)


def test_wrong_sampler_is_caught() -> None:
    """Guard that the chi-square test has teeth: samples of g=0.5 fail against g=0.4."""
    n = 100_000
    d, out = _samples(0.5, n, seed=5)
    mu = np.einsum("ij,ij->j", d, out[:3])
    edges = equal_probability_edges(0.4, 40)
    counts, _ = np.histogram(mu, bins=edges)
    expected = n * np.diff(hg_cdf(0.4, edges))
    assert stats.chisquare(counts, expected * counts.sum() / expected.sum()).pvalue < 1e-6


@pytest.mark.parametrize("bad", [1.5, -1.01, float("nan"), "x"])
def test_check_g_rejects(bad: object) -> None:
    with pytest.raises(InputError, match="g"):
        check_g(bad)
