"""Polyak-Ruppert averaging of the parameters (train.fit.averaging)."""

from __future__ import annotations

import pytest
import torch

from photon_fields.runtime.errors import InputError
from photon_fields.train.fit.averaging import ParameterAverage, averaging_start
from photon_fields.train.fit.settings import FitSettings


def test_averaging_start() -> None:
    assert averaging_start(800, 0.0) == 800  # no step is averaged: the last iterate
    assert averaging_start(800, 0.25) == 600
    assert averaging_start(10, 0.99) == 0


def test_mean_of_the_added_iterates_replaces_the_parameters() -> None:
    lin = torch.nn.Linear(3, 2)
    seen = []
    avg = ParameterAverage(lin)
    avg.apply()  # nothing added yet: unchanged
    with torch.no_grad():
        for i in range(5):
            for p in lin.parameters():
                p.add_(float(i) + 0.5)
            seen.append([p.detach().clone() for p in lin.parameters()])
            avg.add()
    avg.apply()
    for j, p in enumerate(lin.parameters()):
        expected = torch.stack([s[j] for s in seen]).mean(dim=0)
        torch.testing.assert_close(p.detach(), expected, rtol=0, atol=1e-6)


def test_average_of_sgd_iterates_removes_the_target_noise() -> None:
    # 400 independent scalar "fields" fitted by SGD to noisy targets of mean 1 (sd 0.5), constant lr 0.1: the
    # last iterate keeps a spread of sqrt(lr / (2 - lr)) * 0.5 = 0.11, the mean of the last 500 iterates
    # about 0.5 * sqrt(2 / (lr * 500)) ~ 0.03 (correlated iterates: 2 / lr of them per independent sample).
    gen = torch.Generator().manual_seed(3)
    w = torch.nn.Parameter(torch.zeros(400))
    module = torch.nn.Module()
    module.w = w
    avg = ParameterAverage(module)
    for step in range(1000):
        target = 1.0 + 0.5 * torch.randn(400, generator=gen)
        with torch.no_grad():
            w -= 0.1 * (w - target)
        if step >= 500:
            avg.add()
    last_sd = float((w.detach() - 1.0).pow(2).mean().sqrt())
    avg.apply()
    avg_sd = float((w.detach() - 1.0).pow(2).mean().sqrt())
    assert 0.08 < last_sd < 0.14
    assert avg_sd < 0.05 and avg_sd < last_sd / 2.5


@pytest.mark.parametrize("bad", [-0.1, 1.0, float("nan")])
def test_average_share_is_checked(bad: float) -> None:
    with pytest.raises(InputError, match="--average"):
        FitSettings.from_preset("tiny", average=bad).validate()
