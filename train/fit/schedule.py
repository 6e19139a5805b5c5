"""The staggered KNN radius schedule (paper Sec. 3.5.2, Fig. 6, Table 1).

A schedule is a sequence of stages ``(fraction of the training steps, maximum KNN query radius)`` with
non-decreasing radii: early steps query small balls (cheap, most queries return k < K photons) and the
last stage reaches the target radius r. ``radius_at(step, total)`` gives the r_max of the Eq. 5 query
(:mod:`photon_fields.runtime.photons.knn`) at a training step.

Units
-----
Radii are given in **percent of the volume box's longest side** (the unit of the paper's Table 1) and
returned by :meth:`KnnSchedule.radius_at` in world units, i.e. box units: the world box has longest side 1
(:mod:`photon_fields.runtime.scene.volume`), so Table 1's 1M row ``0.25 / 0.50 / 2.50 / 5.0`` percent is an r_max of
``0.0025 / 0.005 / 0.025 / 0.05``. 0.05 is :data:`photon_fields.runtime.photons.estimate.DEFAULT_RADIUS`, the radius of
the photon-mapping baseline the field is compared with.

Stage boundaries
----------------
With cumulative fractions ``c_0 = 0 < c_1 < ... < c_S = 1``, stage i covers the 0-based steps
``[round(c_i T), round(c_{i+1} T))`` of a T-step run (round half up; an early stage may be empty in very
short runs, the last one always holds at least the last step, so every run ends at the target radius).
Table 1 over 3000 steps: steps 0-1079, 1080-1889, 1890-2699, 2700-2999. Steps at or beyond T
(none in a run) get the last radius.

Defaults
--------
:func:`default_schedule` is Table 1: stage fractions 36/27/27/10 % (the table's columns, 0-36 %,
37-63 %, 64-90 %, 91-100 %; the text mentions a 40/30/30/10 split, the table is what was run) and radii
interpolated linearly in log(photons) between its rows (1M, 3M, 6M, 12M photons in the whole map; rounded
to 4 significant digits), held constant outside them (no extrapolation: fewer than 1M photons get the 1M
row). :func:`naive_schedule` is the paper's "naive" baseline: the target radius for the whole run.

The naive schedule is the ``cpu`` preset's: with Table 1's radii in box units the first two stages find
almost no photons on 1M-photon maps and teach the field little (docs/training.md). The staggered schedule
stays available (``--schedule staggered``) and is the ``paper`` preset's.

Validation: fractions must be positive and sum to 1 (within 1e-9), radii positive, finite and
non-decreasing; anything else is a one-line :class:`photon_fields.runtime.errors.InputError`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError

#: Table 1: photons in the map -> radii (percent of the box's longest side) of the four stages.
TABLE1_PHOTONS: tuple[int, ...] = (1_000_000, 3_000_000, 6_000_000, 12_000_000)
TABLE1_RADII: tuple[tuple[float, float, float, float], ...] = (
    (0.25, 0.50, 2.50, 5.0),
    (0.25, 0.50, 2.00, 4.0),
    (0.25, 0.50, 1.50, 3.0),
    (0.25, 0.50, 1.00, 2.0),
)
TABLE1_FRACTIONS: tuple[float, ...] = (0.36, 0.27, 0.27, 0.10)
_SUM_TOLERANCE = 1e-9


def _round_half_up(v: float) -> int:
    return int(math.floor(v + 0.5))


@dataclass(frozen=True)
class KnnSchedule:
    """Stages ``((fraction, radius_percent), ...)``; see the module docstring."""

    stages: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        what = "KNN schedule"
        try:
            stages = tuple((float(f), float(r)) for f, r in self.stages)
        except (TypeError, ValueError):
            raise InputError(what, f"stages must be (fraction, radius percent) pairs, got {self.stages!r}") from None
        if not stages:
            raise InputError(what, "needs at least one stage")
        fractions = [f for f, _ in stages]
        radii = [r for _, r in stages]
        if not all(math.isfinite(f) and f > 0 for f in fractions):
            raise InputError(what, f"stage fractions must be positive, got {fractions}")
        if abs(math.fsum(fractions) - 1.0) > _SUM_TOLERANCE:
            raise InputError(what, f"stage fractions must sum to 1, got {fractions} (sum {math.fsum(fractions)!r})")
        if not all(math.isfinite(r) and r > 0 for r in radii):
            raise InputError(what, f"radii must be positive and finite (percent of the box side), got {radii}")
        if any(b < a for a, b in zip(radii, radii[1:], strict=False)):
            raise InputError(what, f"radii must not decrease from stage to stage, got {radii}")
        object.__setattr__(self, "stages", stages)

    @property
    def radii_percent(self) -> tuple[float, ...]:
        return tuple(r for _, r in self.stages)

    @property
    def final_radius(self) -> float:
        """Target radius r in box units."""
        return self.stages[-1][1] / 100.0

    def boundaries(self, total: int) -> list[int]:
        """First step of every stage, ``[0, b_1, ..., b_{S-1}]`` for a ``total``-step run."""
        _check_total(total)
        cum = np.cumsum([f for f, _ in self.stages])
        # min(total - 1): the last stage keeps at least the last step, so every run ends at the target radius.
        return [0] + [min(total - 1, _round_half_up(float(c) * total)) for c in cum[:-1]]

    def stage_at(self, step: int, total: int) -> int:
        """Index of the stage that ``step`` (0-based) of a ``total``-step run belongs to."""
        if step < 0:
            raise ValueError(f"step must be >= 0, got {step}")
        starts = self.boundaries(total)
        return int(np.searchsorted(starts, step, side="right")) - 1

    def radius_at(self, step: int, total: int) -> float:
        """r_max (box units) of the KNN queries at ``step`` of a ``total``-step run."""
        return self.stages[self.stage_at(step, total)][1] / 100.0

    def to_dict(self) -> dict[str, Any]:
        return {"unit": "percent of the box's longest side",
                "stages": [{"fraction": f, "radius_percent": r} for f, r in self.stages]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> KnnSchedule:
        try:
            return cls(tuple((s["fraction"], s["radius_percent"]) for s in data["stages"]))
        except (KeyError, TypeError) as exc:
            raise InputError("KNN schedule", f"malformed schedule description ({exc!r})") from None


def _check_total(total: int) -> None:
    if isinstance(total, bool) or not isinstance(total, (int, np.integer)) or total < 1:
        raise ValueError(f"total steps must be a positive integer, got {total!r}")


def table1_radii(photons: int) -> tuple[float, ...]:
    """Table 1's four radii (percent) for ``photons`` in the map, interpolated in log(photons)."""
    if photons < 1:
        raise InputError("photons", f"must be positive, got {photons}")
    lp = math.log(min(max(photons, TABLE1_PHOTONS[0]), TABLE1_PHOTONS[-1]))
    xs = [math.log(p) for p in TABLE1_PHOTONS]
    # 4 significant digits: a traced map overshoots its target a little (1,000,035 records for "1M"),
    # which should give Table 1's row, not 4.99997 %.
    return tuple(float(f"{np.interp(lp, xs, [row[j] for row in TABLE1_RADII]):.4g}") for j in range(4))


def default_schedule(photons: int) -> KnnSchedule:
    """Table 1's four-stage schedule for a map of ``photons`` records (all phases together)."""
    return KnnSchedule(tuple(zip(TABLE1_FRACTIONS, table1_radii(photons), strict=True)))


def naive_schedule(radius_percent: float) -> KnnSchedule:
    """One stage at ``radius_percent`` (percent of the box side) for the whole run (Fig. 7, bottom)."""
    return KnnSchedule(((1.0, radius_percent),))


def schedule_from_pairs(pairs: Iterable[Sequence[float]]) -> KnnSchedule:
    """``[(fraction, radius_percent), ...]`` -> KnnSchedule (validated)."""
    return KnnSchedule(tuple((p[0], p[1]) for p in pairs))
