"""pfn-demo end to end in miniature: every output is written and the summary's numbers are real."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from train.demo import _main  # noqa: E402


def test_demo_writes_renders_figure_and_summary(tmp_path, capsys) -> None:  # noqa: ANN001
    out = tmp_path / "demo"
    assert _main(["--scene", "blobs", "--photons", "30k", "--preset", "tiny", "--steps", "20", "--size", "32x24",
                  "--spp", "2", "--reference-spp", "8", "--out", str(out), "--quiet"]) == 0
    for name in ("neural", "photonmap", "pathtraced", "pathtraced_equal_time"):
        assert (out / f"{name}.exr").exists() and (out / f"{name}.png").exists()
    assert (out / "comparison.png").stat().st_size > 10_000
    assert (out / "run" / "field.pfn" / "manifest.json").exists() and (out / "run" / "loss.png").exists()
    summary = json.loads((out / "summary.json").read_text())
    m = summary["metrics"]
    for key in ("neural_L_vs_reference", "photon_map_L_vs_reference", "neural_L_i_vs_photon_map_L_i"):
        assert np.isfinite(m[key]["rel_l2"]) and -1.0 <= m[key]["ssim"] <= 1.0
    assert summary["total_s"] == pytest.approx(sum(summary["seconds"].values()))
    assert "errors against the path-traced reference" in capsys.readouterr().out


def test_demo_refuses_bad_settings_in_one_line(tmp_path, capsys) -> None:  # noqa: ANN001
    for argv, word in ((["--spp", "0"], "--spp"), (["--size", "0x10"], "--size"), (["--preset", "huge"], "--preset"),
                       (["--scene", "nowhere"], "nowhere")):
        assert _main([*argv, "--out", str(tmp_path / "d")]) == 2
        err = capsys.readouterr().err
        assert word in err and err.count("\n") == 1
    assert not (tmp_path / "d" / "summary.json").exists()
