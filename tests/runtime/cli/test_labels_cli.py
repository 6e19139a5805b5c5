"""``pfn-render`` on label scenes: a labels transfer function renders; a bad one is one line and exit 2."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from photon_fields.runtime.cli.render import _main
from photon_fields.runtime.io.images import read_exr

TINY = ["--size", "12x12", "--spp", "1", "--quiet"]
RED = [0.9, 0.1, 0.1]


def write_scene(folder: Path, tf: object, volume: dict | None = None, name: str = "seg") -> Path:
    a = np.zeros((10, 10, 10), dtype=np.uint8)
    a[2:5, 2:8, 2:8] = 3
    a[5:8, 2:8, 2:8] = 7
    np.save(folder / "seg.npy", a)
    scene = {"name": name, "volume": volume or {"path": "seg.npy"}, "transfer_function": tf,
             "lights": [{"type": "directional", "direction": [-1, -1, -0.5], "power": 3}],
             "camera": {"eye": [1.2, 0.7, 1.5], "target": [0, 0, 0], "fov": 40, "width": 12, "height": 12}}
    path = folder / f"{name}.json"
    path.write_text(json.dumps(scene))
    return path


def one_error_line(stderr: str) -> str:
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in stderr, stderr
    return lines[0]


@pytest.mark.parametrize("tf", [{"preset": "labels", "visible": [7]},
                                {"labels": {"3": {"albedo": RED, "opacity": 1}}, "density_scale": 40}])
def test_label_scene_renders(tmp_path: Path, tf: dict) -> None:
    out = tmp_path / "render.exr"
    assert _main(["--scene", str(write_scene(tmp_path, tf)), *TINY, "--out", str(out)]) == 0
    layers, _ = read_exr(out)
    assert layers["L"].max() > 0 and np.all(np.isfinite(layers["L"]))
    report = json.loads(out.with_suffix(".json").read_text())
    assert "labels" in json.dumps(report)


@pytest.mark.parametrize(("tf", "volume", "needle"), [
    ({"labels": {"3": {"albedo": RED, "opacity": 1}, "9": {"albedo": RED, "opacity": 1}}}, None,
     r"seg.json transfer_function: label 9 not in volume 'seg' \(its labels: 0, 3, 7\)"),
    ({"labels": {"3": {"albedo": RED, "opacity": 1}}}, {"builtin": "blobs", "resolution": 8},
     "seg.json transfer_function: volume 'blobs' is not a label volume: voxel"),
    ({"labels": {"3": {"albedo": RED, "opacity": 1, "opacty": 1}}}, None, "unknown key 'opacty'"),
    ({"preset": "labels", "visible": [4]}, None, "visible: label 4 not in volume 'seg'"),
    ({"labels": {"3": {"albedo": RED, "opacity": 1}}}, {"path": "seg.npy", "window": [0, 5]},
     r"window \[0, 5\] clips the raw values"),
])
def test_bad_label_input_exits_2_with_one_line(tmp_path: Path, tf: dict, volume: dict | None, needle: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    scene = write_scene(tmp_path, tf, volume)
    assert _main(["--scene", str(scene), *TINY, "--out", str(tmp_path / "r.exr")]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert re.search(needle, line), line
    assert not (tmp_path / "r.exr").exists()
