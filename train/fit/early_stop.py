"""When a warm-started fine-tune stops improving (the stopping rule of ``pfn-train update``).

A field warm-started from a similar scene's (:mod:`photon_fields.train.fit.update`) needs far fewer steps than
a cold fit, and how many depends on the edit: a small opacity change is absorbed in a few dozen steps, a light
moved by 90 degrees needs many more. So the fine-tune does not run a fixed length: it validates the field every
few steps on a fixed held-out set (:func:`photon_fields.train.fit.loop.validate_field`, the share of the light
that is wrong, ``val_rel_l1``) and stops once ``patience`` validations in a row failed to improve on the best so
far by more than ``min_improvement`` (relative). The validation targets are photon-map estimates (Eq. 5) and
carry their own noise, so the error has a floor the field cannot go below; the relative threshold keeps the
rule from chasing that noise.

:class:`PlateauStop` holds the rule and nothing else (no clock, no model), so it can be tested on synthetic
sequences.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

#: Defaults of the update's rule: stop after 3 validations without a > 1 % relative improvement. The validation
#: error sits near its targets' noise floor after an edit, where a 25-step window rarely improves it by 1 % although
#: the image still does: with 2, shell's density and 10-degree light edits stopped at 100-150 steps with 5-6 s of
#: the 15 s budget left, 1.24x the cold retrain's error; with 3, 1.20x and 1.17x (bench/README.md, bench_update).
DEFAULT_MIN_IMPROVEMENT = 0.01
DEFAULT_PATIENCE = 3


@dataclass
class PlateauStop:
    """Feed validation errors with :meth:`add`; it answers whether to stop (module docstring).

    An error counts as an improvement when ``error < best * (1 - min_improvement)``; ``best`` is the last such
    error. A non-finite error is never an improvement. Which field to keep is the caller's choice (the fine-tune
    keeps its best *trained* field with its own comparison, :mod:`photon_fields.train.fit.update`)."""

    min_improvement: float = DEFAULT_MIN_IMPROVEMENT
    patience: int = DEFAULT_PATIENCE
    best: float = math.inf
    best_index: int = -1
    since_best: int = 0
    history: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_improvement) and 0.0 <= self.min_improvement < 1.0):
            raise ValueError(f"min_improvement must be in [0, 1), got {self.min_improvement!r}")
        if isinstance(self.patience, bool) or not isinstance(self.patience, int) or self.patience < 1:
            raise ValueError(f"patience must be a positive integer, got {self.patience!r}")

    def add(self, error: float) -> bool:
        """Record one validation error; True when the run should stop now."""
        self.history.append(float(error))
        if math.isfinite(error) and error < self.best * (1.0 - self.min_improvement):
            self.best, self.best_index, self.since_best = float(error), len(self.history) - 1, 0
        else:
            self.since_best += 1
        return self.since_best >= self.patience
