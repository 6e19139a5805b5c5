"""The progress file: what a writer records is what a reader sees; anything else is refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.progress import PROGRESS_KEYS, ProgressFile, read_progress


def test_round_trip_and_overall_fraction(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    assert read_progress(path) is None  # not started yet
    pf = ProgressFile(path, ("trace", "fit", "export"), min_interval=0.0)
    pf.update("trace", 50, 100)
    p = read_progress(path)
    assert (p.stage, p.done, p.total, p.status, p.stages) == ("trace", 50, 100, "running", ("trace", "fit", "export"))
    assert p.fraction == pytest.approx(0.5 / 3)
    pf.update("fit", 250, 1000)
    assert read_progress(path).fraction == pytest.approx((1 + 0.25) / 3)
    pf.finish("done", "bundle  x.pfn\nsecond line")
    p = read_progress(path)
    assert p.status == "done" and p.fraction == 1.0 and p.done == p.total == 1000
    assert p.message == "bundle x.pfn second line"  # one line


def test_updates_are_throttled_but_stage_changes_and_the_end_are_not(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    pf = ProgressFile(path, ("trace", "fit"), min_interval=3600.0)
    pf.update("trace", 1, 10)
    pf.update("trace", 9, 10)  # within the interval: not written
    assert read_progress(path).done == 1
    pf.update("fit", 0, 5)  # a new stage: written at once
    assert read_progress(path).stage == "fit"
    pf.finish("failed", "error: x: broke")
    p = read_progress(path)
    assert p.status == "failed" and p.message == "error: x: broke" and p.stage == "fit"


@pytest.mark.parametrize("change", [
    {"extra": 1}, {"done": -1}, {"done": 11}, {"total": 1.5}, {"status": "paused"}, {"stages": "trace"},
    {"message": 3}, {"done": True},
])
def test_a_reader_refuses_what_is_not_a_progress_object(tmp_path: Path, change: dict) -> None:
    d = {"stage": "trace", "done": 1, "total": 10, "stages": ["trace"], "elapsed_s": 0.5, "status": "running",
         "message": None}
    assert set(d) == set(PROGRESS_KEYS)
    path = tmp_path / "p.json"
    path.write_text(json.dumps({**d, **change}))
    with pytest.raises(InputError, match="progress file"):
        read_progress(path)


def test_a_reader_refuses_a_missing_key_and_non_json(tmp_path: Path) -> None:
    path = tmp_path / "p.json"
    path.write_text(json.dumps({"stage": "trace"}))
    with pytest.raises(InputError, match="missing"):
        read_progress(path)
    path.write_text("{not json")
    with pytest.raises(InputError, match="not JSON"):
        read_progress(path)
