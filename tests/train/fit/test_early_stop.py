"""The update's stopping rule (train/fit/early_stop.py): stops exactly after ``patience`` validations without a
relative improvement above the threshold, and never while the error keeps improving."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from photon_fields.train.fit.early_stop import PlateauStop

errors = st.floats(min_value=1e-6, max_value=10.0, allow_nan=False)


def reference_stop(history: list[float], min_improvement: float, patience: int) -> int | None:
    """Index of the validation after which the rule must stop, by its definition (None: never)."""
    best, since = math.inf, 0
    for i, e in enumerate(history):
        if e < best * (1 - min_improvement):
            best, since = e, 0
        else:
            since += 1
        if since >= patience:
            return i
    return None


@given(st.lists(errors, min_size=1, max_size=30), st.sampled_from([0.0, 0.01, 0.05]), st.integers(1, 4))
def test_stops_where_the_definition_says(history: list[float], min_improvement: float, patience: int) -> None:
    rule = PlateauStop(min_improvement, patience)
    stops = [rule.add(e) for e in history]
    want = reference_stop(history, min_improvement, patience)
    first = stops.index(True) if True in stops else None
    assert first == want


@given(st.floats(0.5, 5.0), st.floats(0.02, 0.5), st.integers(2, 25), st.integers(1, 4))
def test_never_stops_while_improving_by_more_than_the_threshold(start: float, drop: float, n: int,
                                                               patience: int) -> None:
    rule = PlateauStop(0.01, patience)
    assert not any(rule.add(start * (1 - drop) ** i) for i in range(n))


@given(st.floats(0.1, 5.0), st.integers(1, 4), st.lists(st.floats(-0.009, 0.5), min_size=8, max_size=8))
def test_stops_on_a_plateau_within_patience(level: float, patience: int, wiggle: list[float]) -> None:
    """A plateau (errors within 1 % below the best, or anywhere above it) stops after ``patience`` validations."""
    rule = PlateauStop(0.01, patience)
    assert not rule.add(level)
    stops = [rule.add(level * (1 + w)) for w in wiggle]
    assert stops.index(True) == patience - 1


def test_a_small_improvement_does_not_reset_the_patience() -> None:
    rule = PlateauStop(0.01, 2)
    assert not rule.add(1.0)
    assert not rule.add(0.995)  # lower, but not 1 % lower: the patience runs
    assert rule.add(0.999) and rule.best == 1.0 and rule.best_index == 0


def test_non_finite_errors_never_count() -> None:
    rule = PlateauStop(0.01, 2)
    assert not rule.add(1.0)
    assert not rule.add(math.nan) and rule.add(math.inf) and rule.best == 1.0


@pytest.mark.parametrize("kwargs", [{"min_improvement": -0.1}, {"min_improvement": 1.0}, {"patience": 0},
                                    {"patience": 1.5}])
def test_bad_parameters_are_refused(kwargs: dict) -> None:
    with pytest.raises(ValueError):
        PlateauStop(**kwargs)
