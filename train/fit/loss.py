"""The training loss: tiny-cuda-nn's relative L2 (paper Sec. 3.5).

Per output value ``(pred - target)^2 / (pred.detach()^2 + 0.01)``, averaged over the batch and the 3
channels (the paper's "relative mean square error ... applied to each set of outputs individually"); the
denominator is a constant for the gradient, as in tcnn.
"""

from __future__ import annotations

import torch

RELATIVE_L2_EPS = 0.01  # tcnn RelativeL2: prediction^2 + 1e-2


def relative_l2_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """tcnn's RelativeL2: mean of (pred - target)^2 / (pred.detach()^2 + 0.01)."""
    return ((pred - target) ** 2 / (pred.detach() ** 2 + RELATIVE_L2_EPS)).mean()
