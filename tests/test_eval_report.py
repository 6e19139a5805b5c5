"""pfn-eval in its --quick form: every section of docs/results.md is generated, with its figures."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")

from train.eval_report import _main  # noqa: E402


def test_quick_evaluation_writes_every_section_and_figure(tmp_path) -> None:  # noqa: ANN001
    out, work = tmp_path / "docs", tmp_path / "work"
    assert _main(["--quick", "--out", str(out), "--work", str(work), "--quiet"]) == 0
    md = (out / "results.md").read_text()
    for title in ("1. Training", "2. Photon tracing", "3. Render timings", "4. Image quality", "5. Noise",
                  "6. Phase awareness"):
        assert f"## {title}" in md
    for png in ("training.png", "images_blobs.png", "noise.png", "phases.png"):
        assert (out / "results" / png).stat().st_size > 5_000 and f"results/{png}" in md
    data = json.loads((out / "results.json").read_text())
    assert data["seed"] == 0 and set(data["phases"]["per_g"]) == {"-0.75", "-0.35", "0", "0.35", "0.75"}
    assert data["timings"]["blobs"]["neural"]["L_s"] > 0


def test_eval_refuses_unknown_scenes_and_impossible_settings_in_one_line(tmp_path, capsys) -> None:  # noqa: ANN001
    for argv, word in ((["--scenes", "vortex,nowhere"], "nowhere"), (["--spp", "0"], "--spp"),
                       (["--size", "0"], "--size")):
        assert _main(["--quick", *argv, "--out", str(tmp_path / "d"), "--work", str(tmp_path / "w")]) == 2
        err = capsys.readouterr().err
        assert word in err and err.count("\n") == 1
    assert not (tmp_path / "d").exists() and not (tmp_path / "w").exists()
