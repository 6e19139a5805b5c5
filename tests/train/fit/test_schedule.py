"""Staggered KNN radius schedule (Sec. 3.5.2, Table 1): stage boundaries, units, interpolation, validation."""

from __future__ import annotations

import math

import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.train.fit.schedule import (
    TABLE1_FRACTIONS,
    KnnSchedule,
    default_schedule,
    naive_schedule,
    schedule_from_pairs,
    table1_radii,
)


def test_table1_at_3000_steps_every_boundary() -> None:
    s = default_schedule(1_000_000)
    assert s.radii_percent == (0.25, 0.5, 2.5, 5.0)
    assert tuple(f for f, _ in s.stages) == TABLE1_FRACTIONS
    # Table 1's columns 0-36 %, 37-63 %, 64-90 %, 91-100 % of 3000 steps; radii in box units.
    assert s.boundaries(3000) == [0, 1080, 1890, 2700]
    expected = {0: 0.0025, 1079: 0.0025, 1080: 0.005, 1889: 0.005, 1890: 0.025, 2699: 0.025, 2700: 0.05, 2999: 0.05}
    for step, r in expected.items():
        assert s.radius_at(step, 3000) == pytest.approx(r, rel=1e-12), step
    assert s.final_radius == pytest.approx(0.05)


@pytest.mark.parametrize("total", [1, 7, 100, 601, 2000, 3001])
def test_radius_changes_exactly_at_the_boundaries(total: int) -> None:
    s = default_schedule(3_000_000)
    starts = s.boundaries(total)
    for i, b in enumerate(starts):
        if b < total and (i + 1 == len(starts) or starts[i + 1] > b):  # non-empty stage
            assert s.radius_at(b, total) == s.stages[i][1] / 100.0
        if 0 < b < total:
            assert s.radius_at(b - 1, total) <= s.radius_at(b, total)
    radii = [s.radius_at(t, total) for t in range(total)]
    assert radii == sorted(radii)
    assert radii[-1] == pytest.approx(s.final_radius)
    assert s.radius_at(total + 5, total) == pytest.approx(s.final_radius)  # beyond the run: last stage


def test_interpolation_in_log_photons_and_clamping() -> None:
    assert table1_radii(12_000_000) == (0.25, 0.5, 1.0, 2.0)
    assert table1_radii(6_000_000) == (0.25, 0.5, 1.5, 3.0)
    t = math.log(2) / math.log(3)  # 2M sits at this fraction between 1M and 3M in log photons
    r = table1_radii(2_000_000)
    assert r[2] == pytest.approx(2.5 - 0.5 * t, rel=1e-3) and r[3] == pytest.approx(5.0 - 1.0 * t, rel=1e-3)
    assert table1_radii(1_000_035) == (0.25, 0.5, 2.5, 5.0)  # a traced "1M" map overshoots a little
    assert table1_radii(50_000) == table1_radii(1_000_000)  # held constant outside the table
    assert table1_radii(100_000_000) == table1_radii(12_000_000)


def test_naive_schedule_is_constant() -> None:
    s = naive_schedule(5.0)
    assert s.boundaries(3000) == [0]
    assert {s.radius_at(t, 3000) for t in range(3000)} == {0.05}


@pytest.mark.parametrize("stages, match", [
    ([(0.5, 1.0), (0.4, 2.0)], "sum to 1"),
    ([(0.5, 1.0), (0.5 + 2e-9, 2.0)], "sum to 1"),
    ([(0.5, 2.0), (0.5, 1.0)], "not decrease"),
    ([(1.0, 0.0)], "positive"),
    ([(1.0, float("inf"))], "positive"),
    ([(1.2, 1.0), (-0.2, 2.0)], "positive"),
    ([], "at least one"),
    ([("a", 1.0)], "pairs"),
])
def test_bad_schedules_are_refused(stages: list, match: str) -> None:
    with pytest.raises(InputError, match=match):
        KnnSchedule(tuple(stages))


def test_tolerance_and_round_trip() -> None:
    s = schedule_from_pairs([(0.3, 1.0), (0.7 - 5e-10, 1.0)])  # equal radii are fine; sum within 1e-9
    assert KnnSchedule.from_dict(s.to_dict()) == s
    assert s.to_dict()["unit"].startswith("percent")
