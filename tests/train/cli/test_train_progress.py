"""``pfn-train --progress-file``: a finished job ends "done" with its result named, having passed through its
stages; a failed one ends "failed" with the error's one line (what pfn-view shows in the page)."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("torch")

from conftest import TINY_FIT  # noqa: E402

from photon_fields.runtime.io.progress import ProgressFile, read_progress  # noqa: E402
from photon_fields.train.cli.train import _main as train_main  # noqa: E402

FIT = TINY_FIT


@pytest.fixture(scope="module")
def scene_file(tiny_scene_file: Path) -> Path:
    return tiny_scene_file


def test_all_records_each_stage_and_ends_done(tmp_path: Path, scene_file: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[tuple[str, int, int]] = []
    original = ProgressFile.update

    def spy(self: ProgressFile, stage: str, done: int, total: int) -> None:
        seen.append((stage, done, total))
        original(self, stage, done, total)

    monkeypatch.setattr(ProgressFile, "update", spy)
    path = tmp_path / "progress.json"
    run = tmp_path / "run"
    assert train_main(["all", str(scene_file), "--photons", "3k", *FIT, "--out", str(run),
                       "--progress-file", str(path)]) == 0
    p = read_progress(path)
    assert p.status == "done" and p.stages == ("trace", "fit", "export") and p.fraction == 1.0
    assert str(run / "field.pfn") in p.message
    stages = [s for s, _, _ in seen]
    assert stages.index("trace") < stages.index("fit") < stages.index("export")
    fit = [(d, t) for s, d, t in seen if s == "fit"]
    assert fit[-1] == (3, 3) and [d for d, _ in fit] == sorted(d for d, _ in fit)
    trace = [(d, t) for s, d, t in seen if s == "trace" and t > 0]
    assert trace and trace[-1][0] == trace[-1][1]  # the quota reached


def test_a_failed_job_ends_failed_with_its_error_line(tmp_path: Path, scene_file: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "progress.json"
    assert train_main(["trace", str(scene_file), "--photons", "3k", "--max-bounces", "1", "--quiet",
                       "--out", str(tmp_path / "m.npz"), "--progress-file", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    p = read_progress(path)
    assert p.status == "failed" and "max_bounces" in p.message and "max_bounces" in err


def test_a_progress_file_in_a_missing_folder_is_refused_before_any_work(tmp_path: Path, scene_file: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "m.npz"
    assert train_main(["trace", str(scene_file), "--photons", "3k", "--quiet", "--out", str(out),
                       "--progress-file", str(tmp_path / "nope" / "p.json")]) == 2
    assert "--progress-file" in capsys.readouterr().err and not out.exists()
