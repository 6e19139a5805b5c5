"""The training points where cameras see the medium (train/fit/visible_points.py): first collisions of uniformly
distributed lines, checked against their analytic density in a homogeneous box."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

pytest.importorskip("torch")

from conftest import constant_tf  # noqa: E402

from photon_fields.runtime.scene.volume import make_volume  # noqa: E402
from photon_fields.runtime.transport.medium import build_medium  # noqa: E402
from photon_fields.train.fit.visible_points import visible_points  # noqa: E402


def _box(sigma: float):  # noqa: ANN202
    return build_medium(make_volume(np.ones((8, 8, 8)), window=(0.0, 1.0)), constant_tf(sigma))


def _face_distance(m, x: np.ndarray) -> np.ndarray:  # noqa: ANN001
    lo = x - m.bmin
    hi = m.bmin + m.bsize - x
    return np.minimum(lo, hi).min(axis=1) / m.bsize.min()


def _expected_face_distance_bins(m, sigma: float, edges: np.ndarray, samples: int = 800_000) -> np.ndarray:  # noqa: ANN001
    """Bin probabilities of the distance to the nearest face under the density of first collisions of uniform
    lines: f(x) proportional to the integral over directions w of sigma T(x - b w -> x) = sigma exp(-sigma b(x, w)),
    b the distance from x back to the box along -w (the measure of lines is dw dA; a line collides at x with pdf
    sigma T from its entry). One direction per uniform point is an unbiased estimate of that integral."""
    rng = np.random.default_rng(99)
    x = m.bmin + rng.random((samples, 3)) * m.bsize
    z = 1.0 - 2.0 * rng.random(samples)
    phi = 2.0 * np.pi * rng.random(samples)
    s = np.sqrt(1.0 - z * z)
    w = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    with np.errstate(divide="ignore"):
        back = np.where(w > 0, (x - m.bmin) / w, (x - m.bmin - m.bsize) / w)  # distance to the entry plane per axis
    b = np.min(np.where(np.isfinite(back), back, np.inf), axis=1)
    weight = np.exp(-sigma * b)
    hist, _ = np.histogram(_face_distance(m, x), edges, weights=weight)
    return hist / hist.sum()


@pytest.mark.parametrize("sigma", [0.7, 4.0])
def test_collisions_follow_the_density_of_first_collisions_of_uniform_lines(sigma: float) -> None:
    """Chi-square of the distance to the nearest face against the analytic density (optically thin and thick
    boxes). A disk radius drawn uniform instead of as sqrt, a ray started inside the box, or collisions taken
    from the far side all move mass between the bins."""
    m = _box(sigma)
    x, d = visible_points(m, np.random.default_rng(5), 20_000)
    edges = np.linspace(0.0, 0.5, 11)
    observed, _ = np.histogram(_face_distance(m, x), edges)
    expected = _expected_face_distance_bins(m, sigma, edges) * x.shape[0]
    chi2 = float(((observed - expected) ** 2 / expected).sum())
    assert stats.chi2.sf(chi2, len(observed) - 1) > 1e-3, (observed, expected.round(1))
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)


def test_a_dense_box_is_seen_at_its_surface_from_outside() -> None:
    """In a box of optical depth 4000 per side every collision lies on the surface, and the ray that found it
    travels into the box there."""
    m = _box(4000.0)
    x, d = visible_points(m, np.random.default_rng(1), 4000)
    rel = (x - m.bmin) / m.bsize
    face = np.argmin(np.minimum(rel, 1.0 - rel), axis=1)
    depth = np.minimum(rel, 1.0 - rel)[np.arange(len(x)), face]
    assert depth.max() < 0.01
    inward = np.where(rel[np.arange(len(x)), face] < 0.5, 1.0, -1.0)
    assert np.all(d[np.arange(len(x)), face] * inward > 0.0)


def test_the_same_generator_state_gives_the_same_points() -> None:
    m = _box(2.0)
    a = visible_points(m, np.random.default_rng(3), 500)
    b = visible_points(m, np.random.default_rng(3), 500)
    assert all(np.array_equal(p, q) for p, q in zip(a, b, strict=True))
