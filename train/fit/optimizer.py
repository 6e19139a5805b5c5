"""tiny-cuda-nn's Adam (what the paper trained with, Sec. 3.5) and its learning-rate schedule.

:class:`TcnnAdam`: beta1 0.9, beta2 0.99 (paper), epsilon 1e-15 (tcnn's setting in its own examples), no L2
regularization (paper), bias correction per parameter, and the hash tables ("non-matrix" parameters in tcnn)
updated *lazily*: an entry whose gradient is exactly 0 in a step (no sample touched it) keeps its value and
moments and does not advance its step count, so rarely touched table entries are not dragged by stale
momentum. The MLP matrices always step. The update runs in a numba kernel, elementwise in float32, so the
result does not depend on the thread count.

:func:`lr_at`: ``lr`` until a share ``start`` of the run (the paper: 70 %), then x0.92 at that step and every
``every`` steps after it (the paper: 25; tcnn's ExponentialDecay semantics, Sec. 3.5.1). The ``cpu`` preset
anneals harder (from 50 %, every 10 steps: the last step's rate is ~4 % of the first's), so that the
parameters' SGD fluctuation around the fit to noisy targets, which the log-encoded output turns into a bias of
the decoded radiance, is small when the run ends (docs/training.md).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

ADAM_BETAS = (0.9, 0.99)
ADAM_EPS = 1e-15
LR_DECAY = 0.92
LR_DECAY_EVERY = 25
LR_DECAY_START = 0.7


@njit(cache=True, parallel=True)
def _adam_kernel(param: np.ndarray, grad: np.ndarray, m: np.ndarray, v: np.ndarray, steps: np.ndarray,
                 corr: np.ndarray, lr: np.float32, b1: np.float32, b2: np.float32, one_b1: np.float32,
                 one_b2: np.float32, eps: np.float32, lazy: bool) -> None:
    # tcnn's adam_step, float32, elementwise (so the result does not depend on the thread count).
    for i in prange(param.shape[0]):
        gi = grad[i]
        if lazy and gi == 0.0:
            continue
        mi = b1 * m[i] + one_b1 * gi
        vi = b2 * v[i] + one_b2 * (gi * gi)
        m[i] = mi
        v[i] = vi
        t = steps[i] + 1
        steps[i] = t
        param[i] = param[i] - (lr * corr[t]) / (np.sqrt(vi) + eps) * mi


class TcnnAdam:
    """tiny-cuda-nn's Adam (module docstring): lazy on the hash tables, dense on the MLP matrices.

    ``step(lr)`` applies one update with learning rate ``lr`` from the gradients in ``.grad`` and then
    drops them (``.grad = None``: the hash-grid backward allocates lazily zeroed pages, cheaper than
    zeroing). State: float32 first/second moments and int32 per-entry step counts."""

    def __init__(self, matrix: list[torch.nn.Parameter], tables: list[torch.nn.Parameter], *,
                 betas: tuple[float, float] = ADAM_BETAS, eps: float = ADAM_EPS) -> None:
        self.groups = [(p, False) for p in matrix] + [(p, True) for p in tables]
        self.b1, self.b2, self.eps = float(betas[0]), float(betas[1]), float(eps)
        self.state = [(np.zeros(p.numel(), np.float32), np.zeros(p.numel(), np.float32),
                       np.zeros(p.numel(), np.int32)) for p, _ in self.groups]
        self._corr = np.zeros(1, np.float32)

    def _correction(self, max_step: int) -> np.ndarray:
        # sqrt(1 - b2^t) / (1 - b1^t) for t = 1..max_step (tcnn computes it per entry with powf).
        if self._corr.shape[0] <= max_step:
            t = np.arange(max(2 * max_step, 64) + 1, dtype=np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                c = np.sqrt(1.0 - self.b2**t) / (1.0 - self.b1**t)
            c[0] = 0.0
            self._corr = c.astype(np.float32)
        return self._corr

    def step(self, lr: float, step_index: int) -> None:
        corr = self._correction(step_index + 1)
        f32 = np.float32
        for (p, lazy), (m, v, steps) in zip(self.groups, self.state, strict=True):
            if p.grad is None:
                continue
            g = p.grad.detach().to(torch.float32).contiguous().view(-1).numpy()
            _adam_kernel(p.detach().view(-1).numpy(), g, m, v, steps, corr, f32(lr), f32(self.b1), f32(self.b2),
                         f32(1.0 - self.b1), f32(1.0 - self.b2), f32(self.eps), lazy)
            p.grad = None


def lr_at(step: int, total: int, lr: float, start: float = LR_DECAY_START, every: int = LR_DECAY_EVERY) -> float:
    """Learning rate at 0-based ``step``: x0.92 at ``round(start total)`` and every ``every`` steps after it."""
    first = int(math.floor(start * total + 0.5))
    if step < first:
        return lr
    return lr * LR_DECAY ** ((step - first) // every + 1)
