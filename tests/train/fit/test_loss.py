"""The training losses: which mean each one converges to under noisy targets (the reason "linear" is the
default), scale invariance, and tcnn's relative L2 as the paper's."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from photon_fields.models_spec.encoding import DEFAULT_PSI, encode_radiance  # noqa: E402
from photon_fields.train.fit.loss import field_loss, linear_relative_l2_loss, relative_l2_loss  # noqa: E402


def _noisy_targets(n: int = 20000, sigma: float = 0.8) -> np.ndarray:
    """Lognormal radiance samples with mean 0.2: what noisy KNN targets at one point look like."""
    rng = np.random.default_rng(3)
    return 0.2 * rng.lognormal(-0.5 * sigma**2, sigma, size=(n, 3))


def _gradient_at(name: str, radiance: float, q: np.ndarray) -> float:
    """d loss / d (encoded prediction), the prediction being the same radiance at every sample."""
    pred = torch.full(q.shape, float(encode_radiance(np.array([radiance]))[0]), requires_grad=True)
    target = torch.from_numpy(encode_radiance(q))
    field_loss(name, pred, target, DEFAULT_PSI).backward()
    return float(pred.grad.sum())


def test_linear_loss_is_stationary_at_the_arithmetic_mean() -> None:
    q = _noisy_targets()
    mean, geometric = float(q.mean()), float(np.exp(np.log(q).mean()))
    assert geometric < 0.8 * mean  # the noise is large enough for the two means to differ clearly
    scale = abs(_gradient_at("linear", 2 * mean, q))
    assert abs(_gradient_at("linear", mean, q)) < 0.02 * scale
    # Encoded output decreases with radiance: too dark -> positive gradient on L' ... and the sign flips at the mean.
    assert _gradient_at("linear", 0.9 * mean, q) * _gradient_at("linear", 1.1 * mean, q) < 0


def test_log_loss_is_stationary_at_the_geometric_mean() -> None:
    q = _noisy_targets()
    mean, geometric = float(q.mean()), float(np.exp(np.log(q).mean()))
    assert _gradient_at("log", 0.97 * geometric, q) * _gradient_at("log", 1.03 * geometric, q) < 0
    assert abs(_gradient_at("log", mean, q)) > 10 * abs(_gradient_at("log", geometric, q))


def test_linear_loss_is_scale_free() -> None:
    rng = np.random.default_rng(5)
    pred_l, q = rng.uniform(0.05, 0.5, (64, 3)), rng.uniform(0.05, 0.5, (64, 3))
    losses = []
    for k in (1.0, 100.0):
        pred = torch.from_numpy(encode_radiance(k * pred_l))
        target = torch.from_numpy(encode_radiance(k * q))
        losses.append(float(linear_relative_l2_loss(pred, target, DEFAULT_PSI)))
    assert losses[0] == pytest.approx(losses[1], rel=1e-4)


def test_log_loss_is_tcnn_relative_l2() -> None:
    pred, target = torch.tensor([[0.5, 0.2, 0.0]]), torch.tensor([[0.4, 0.3, 0.1]])
    expected = np.mean([(0.1**2) / (0.25 + 0.01), (0.1**2) / (0.04 + 0.01), (0.1**2) / 0.01])
    assert float(relative_l2_loss(pred, target)) == pytest.approx(expected, rel=1e-6)
    with pytest.raises(ValueError, match="unknown loss"):
        field_loss("l1", pred, target, DEFAULT_PSI)
