"""``pfn-train pvrt`` and ``pfn-render --method pvrt``: a transfer file from the command line, its bytes (same
seed, same bytes, whatever the thread count; another seed, other bytes), a render from it, and one-line exit-2
errors for a missing, unreadable or foreign transfer.

Everything is tiny (16^3 ball, 4^3 transfer grid, 12 DSF basis lights x 300 paths, 12x12 pixels): a few seconds
on 2 cores once the numba cache is warm.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from photon_fields.runtime.cli.render import _main as render_main
from photon_fields.runtime.io.images import read_exr
from photon_fields.train.cli.train import _main as train_main

TINY_TRANSFER = ["--grid", "4", "--order", "0", "--paths", "300", "--clusters", "4", "--quiet"]


def _scene(folder: Path, name: str, density_scale: float) -> Path:
    x = (np.arange(16) + 0.5) / 16
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    np.save(folder / "ball.npy", np.exp(-((X - 0.5) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2) / 0.04))
    scene = {"name": name, "volume": {"path": "ball.npy"},
             "transfer_function": {"preset": "grey_ramp", "density_scale": density_scale},
             "lights": [{"type": "directional", "direction": [-1, -1, -0.5], "power": 3},
                        {"type": "environment", "color": [0.2, 0.3, 0.5], "power": 0.5}],
             "camera": {"eye": [1.2, 0.7, 1.5], "target": [0, 0, 0], "fov": 40, "width": 12, "height": 12},
             "phase": {"g": 0.4}}
    path = folder / f"{name}.json"
    path.write_text(json.dumps(scene))
    return path


def _one_error_line(stderr: str) -> str:
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr
    return lines[0]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The ball scene, a denser variant (another transfer function), and the ball's transfer (seed 0)."""
    folder = tmp_path_factory.mktemp("pvrt_cli")
    ball = _scene(folder, "ball", 20)
    dense = _scene(folder, "dense", 40)
    out = folder / "ball.pvrt"
    assert train_main(["pvrt", str(ball), "--out", str(out), "--seed", "0", *TINY_TRANSFER]) == 0
    return {"folder": folder, "ball": ball, "dense": dense, "transfer": out}


def test_same_seed_same_bytes_any_threads_other_seed_differs(made: dict[str, Path],
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    folder = made["folder"]
    again, other = folder / "again.pvrt", folder / "other.pvrt"
    assert train_main(["pvrt", str(made["ball"]), "--out", str(again), "--seed", "0", "--threads", "1",
                       *TINY_TRANSFER]) == 0
    assert train_main(["pvrt", str(made["ball"]), "--out", str(other), "--seed", "1", *TINY_TRANSFER]) == 0
    assert _sha(again) == _sha(made["transfer"])
    assert _sha(other) != _sha(made["transfer"])
    printed = capsys.readouterr().out
    assert "precomputed 12 dsf basis lights x 300 paths on a 4x4x4 grid" in printed and str(again) in printed


def test_render_from_transfer(made: dict[str, Path]) -> None:
    out = made["folder"] / "relit.exr"
    assert render_main(["--method", "pvrt", "--transfer", str(made["transfer"]), "--scene", str(made["ball"]),
                        "--spp", "1", "--quiet", "--out", str(out)]) == 0
    layers, meta = read_exr(out)
    assert meta["photon_fields.method"] == "pvrt"
    for name in ("L_d", "L_i", "L_e"):
        assert np.all(np.isfinite(layers[name])) and layers[name].mean() > 0, name
    np.testing.assert_allclose(layers["L"], layers["L_d"] + layers["L_i"] + layers["L_e"], rtol=1e-4, atol=1e-6)
    report = json.loads(out.with_suffix(".json").read_text())
    from photon_fields.runtime.pvrt.constants import DEFAULT_LIGHT_GRID

    assert report["options"] == {"direct": "nee", "light_grid": DEFAULT_LIGHT_GRID}
    assert report["transfer"]["scene_name"] == "ball" and report["transfer"]["grid"] == [4, 4, 4]
    assert "NEE" in report["stats"]["notes"]


def _render_error(made: dict[str, Path], capsys: pytest.CaptureFixture[str], *args: str) -> str:
    capsys.readouterr()
    out = made["folder"] / "never.exr"
    assert render_main(["--method", "pvrt", "--spp", "1", "--quiet", "--out", str(out), *args]) == 2
    assert not out.exists()
    return _one_error_line(capsys.readouterr().err)


def test_render_refuses_missing_foreign_or_unreadable_transfer(made: dict[str, Path],
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    ball, dense, transfer = str(made["ball"]), str(made["dense"]), str(made["transfer"])
    assert "--transfer: --method pvrt needs a PVRT transfer" in _render_error(made, capsys, "--scene", ball)
    missing = str(made["folder"] / "missing.pvrt")
    assert "transfer file not found" in _render_error(made, capsys, "--scene", ball, "--transfer", missing)
    line = _render_error(made, capsys, "--scene", dense, "--transfer", transfer)
    assert "precomputed for another scene ('ball')" in line and "transfer function differ" in line
    assert "phase g = 0.4" in _render_error(made, capsys, "--scene", ball, "--g", "0", "--transfer", transfer)
    junk = made["folder"] / "junk.pvrt"
    junk.write_text("not a zip")
    assert "not a PVRT transfer" in _render_error(made, capsys, "--scene", ball, "--transfer", str(junk))
    line = _render_error(made, capsys, "--transfer", transfer)  # no --scene: the transfer's is not a builtin
    assert "--scene" in line and "'ball', not a builtin" in line
    assert "--direct: must be one of nee, transfer" in _render_error(made, capsys, "--scene", ball, "--transfer",
                                                                     transfer, "--direct", "sharp")


def test_train_pvrt_refusals(made: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    ball, folder = str(made["ball"]), made["folder"]
    before = _sha(made["transfer"])
    cases = [(["--out", str(made["transfer"])], "pass --force"),
             (["--out", str(folder / "t.npz")], "must end in .pvrt"),
             (["--out", str(folder / "t.pvrt"), "--order", "7"], "must be an integer in [0, 3]"),
             (["--out", str(folder / "t.pvrt"), "--grid", "2"], "grid"),
             (["--out", str(folder / "t.pvrt"), "--paths", "lots"], "--paths")]
    for extra, match in cases:
        capsys.readouterr()
        assert train_main(["pvrt", ball, "--quiet", *extra]) == 2, extra
        assert match in _one_error_line(capsys.readouterr().err), extra
    assert _sha(made["transfer"]) == before and not (folder / "t.pvrt").exists()
