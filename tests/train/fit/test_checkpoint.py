"""``checkpoint.pt``: the field and its metadata round-trip, damaged or foreign checkpoints are one-line errors
naming the file, and a finished run is reused only with the same settings."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from conftest import FP, make_model, small_field_config  # noqa: E402

from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.train.fit.checkpoint import (  # noqa: E402
    CHECKPOINT_FORMAT,
    CHECKPOINT_KEYS,
    CHECKPOINT_VERSION,
    finished_run,
    load_checkpoint,
    save_checkpoint,
)
from photon_fields.train.fit.settings import FitSettings  # noqa: E402


@pytest.fixture
def saved(tmp_path: Path) -> tuple:
    model = make_model(small_field_config(), seed=4)
    path = tmp_path / "checkpoint.pt"
    save_checkpoint(path, model, FP, 12, {"final_loss": 0.5})
    return model, path


def test_round_trip(saved: tuple) -> None:
    model, path = saved
    loaded, data = load_checkpoint(path, FP)
    assert loaded.cfg == model.cfg
    assert all(torch.equal(v, model.state_dict()[k]) for k, v in loaded.state_dict().items())
    assert set(data) == set(CHECKPOINT_KEYS)
    assert (data["format"], data["version"]) == (CHECKPOINT_FORMAT, CHECKPOINT_VERSION)
    assert data["step"] == 12 and data["summary"] == {"final_loss": 0.5} and data["phases"] == list(model.cfg.phases)
    assert not [p for p in path.parent.iterdir() if p != path]  # atomic: no temporary file left behind


def _rewrite(path: Path, change: dict, drop: str | None = None) -> None:
    data = torch.load(path, weights_only=True) | change
    if drop is not None:
        del data[drop]
    torch.save(data, path)


@pytest.mark.parametrize(("damage", "match"), [
    ("foreign scene", "another scene"),
    ("unknown key", "unknown key 'extra'"),
    ("missing key", "summary"),
    ("newer version", "version 2 is not supported"),
    ("other format", "not a photon-field checkpoint"),
    ("truncated", "not a readable checkpoint"),
    ("weights of another field", "field_config or state_dict unusable"),
])
def test_damaged_or_foreign_checkpoints_are_refused_in_one_line(saved: tuple, damage: str, match: str) -> None:
    _, path = saved
    expected = "0" * 64 if damage == "foreign scene" else FP
    if damage == "unknown key":
        _rewrite(path, {"extra": 1})
    elif damage == "missing key":
        _rewrite(path, {}, drop="summary")
    elif damage == "newer version":
        _rewrite(path, {"version": 2})
    elif damage == "other format":
        _rewrite(path, {"format": "something/else"})
    elif damage == "truncated":
        path.write_bytes(path.read_bytes()[:200])
    elif damage == "weights of another field":
        _rewrite(path, {"state_dict": {"w": torch.zeros(3)}})
    with pytest.raises(InputError, match=match) as err:
        load_checkpoint(path, expected)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)


def test_finished_run_is_reused_only_when_done_with_the_same_settings(saved: tuple) -> None:
    _, path = saved
    run = path.parent
    settings = FitSettings.from_preset("tiny", steps=5)
    log = {"status": "done", "settings": settings.to_dict()}
    assert finished_run(run, settings) is None  # no log yet
    (run / "log.json").write_text(json.dumps(log))
    assert finished_run(run, settings) == log
    assert finished_run(run, FitSettings.from_preset("tiny", steps=6)) is None
    (run / "log.json").write_text(json.dumps(log | {"status": "diverged"}))
    assert finished_run(run, settings) is None
    (run / "log.json").write_text(json.dumps(log))
    path.unlink()
    assert finished_run(run, settings) is None
