"""Polyak-Ruppert averaging of the field's parameters over the last steps of a fit.

A step of SGD moves the parameters towards the targets of one batch; with photon-map targets (noisy by
construction, more so at small K) the last iterate carries the noise of its last few hundred batches,
and a field trained to the right mean is off by several percent at any one point and any one g. The
running mean of the iterates over the last ``share`` of the steps averages that noise away while the
learning rate is already small (:func:`photon_fields.train.fit.optimizer.lr_at` decays it over the last
30 %), at the cost of one parameter copy and one add per step. The averaged parameters become the field;
the optimizer's state is untouched.
"""

from __future__ import annotations

import torch


def averaging_start(total_steps: int, share: float) -> int:
    """First step (0-based) whose parameters enter the average; ``total_steps`` when ``share`` is 0."""
    return total_steps - int(round(share * total_steps))


class ParameterAverage:
    """Running mean of a module's parameters: :meth:`add` after each step, :meth:`apply` at the end."""

    def __init__(self, module: torch.nn.Module) -> None:
        self.module = module
        self.count = 0
        self.mean: list[torch.Tensor] = []  # allocated by the first add: nothing is copied when nothing is averaged

    @torch.no_grad()
    def add(self) -> None:
        """Fold the module's current parameters into the mean."""
        self.count += 1
        if self.count == 1:
            self.mean = [p.detach().clone() for p in self.module.parameters()]
            return
        for m, p in zip(self.mean, self.module.parameters(), strict=True):
            m.add_(p.detach() - m, alpha=1.0 / self.count)

    @torch.no_grad()
    def apply(self) -> None:
        """Replace the module's parameters by the mean (no-op before the first :meth:`add`)."""
        if self.count == 0:
            return
        for m, p in zip(self.mean, self.module.parameters(), strict=True):
            p.copy_(m)
