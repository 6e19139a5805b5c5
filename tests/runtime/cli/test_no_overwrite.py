"""Nothing already on disk is lost: every command that writes a map, run, bundle, image or report refuses
to replace an earlier one unless ``--force`` is given, in one line naming what exists, before any work,
and leaves the earlier bytes untouched."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("torch")

from conftest import TINY_FIT  # noqa: E402

from photon_fields.runtime.cli.render import _main as render_main  # noqa: E402
from photon_fields.train.cli.demo import _main as demo_main  # noqa: E402
from photon_fields.train.cli.train import _main as train_main  # noqa: E402
from photon_fields.train.eval.report import _main as eval_main  # noqa: E402

FIT = TINY_FIT


@pytest.fixture(scope="module")
def scene_file(tiny_scene_file: Path) -> Path:
    return tiny_scene_file


def refused(capsys: pytest.CaptureFixture[str], *names: str) -> str:
    """The single error line, which must name each existing file and the way out."""
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "--force" in err[0], err
    assert all(n in err[0] for n in names), err
    return err[0]


def test_trace_keeps_an_existing_map(tmp_path: Path, scene_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "map.npz"
    out.write_bytes(b"earlier map")
    args = ["trace", str(scene_file), "--photons", "3k", "--quiet", "--out", str(out)]
    assert train_main(args) == 2
    refused(capsys, str(out))
    assert out.read_bytes() == b"earlier map"
    assert train_main([*args, "--force"]) == 0
    assert out.read_bytes()[:2] == b"PK"  # an npz replaced it


@pytest.mark.parametrize("existing", ["checkpoint.pt", "log.json", "loss.png", "domain.json", "field.pfn"])
def test_fit_keeps_an_earlier_run(tmp_path: Path, scene_file: Path, existing: str,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / existing).write_bytes(b"earlier")
    # fit checks its inputs (the map) first, then the run folder: a real map, so the refusal is the run's.
    pmap = tmp_path / "map.npz"
    assert train_main(["trace", str(scene_file), "--photons", "3k", "--quiet", "--out", str(pmap)]) == 0
    assert train_main(["fit", str(scene_file), "--map", str(pmap), *FIT, "--out", str(run)]) == 2
    refused(capsys, existing)
    assert sorted(p.name for p in run.iterdir()) == [existing] and (run / existing).read_bytes() == b"earlier"


@pytest.mark.parametrize("existing", ["map.npz", "checkpoint.pt", "field.pfn"])
def test_all_keeps_an_earlier_run(tmp_path: Path, scene_file: Path, existing: str,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / existing).write_bytes(b"earlier")
    args = ["all", str(scene_file), "--photons", "3k", *FIT, "--out", str(run)]
    assert train_main(args) == 2
    refused(capsys, existing)
    assert sorted(p.name for p in run.iterdir()) == [existing] and (run / existing).read_bytes() == b"earlier"


def test_all_with_force_replaces_the_whole_run(tmp_path: Path, scene_file: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    for name in ("map.npz", "checkpoint.pt", "log.json"):
        (run / name).write_bytes(b"earlier")
    assert train_main(["all", str(scene_file), "--photons", "3k", *FIT, "--out", str(run), "--force"]) == 0
    assert all((run / name).read_bytes() != b"earlier" for name in ("map.npz", "checkpoint.pt", "log.json"))
    assert (run / "field.pfn" / "manifest.json").is_file()


def test_orbit_keeps_earlier_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Checked before the bundle is even opened: a missing bundle is not reported, the frame is."""
    frame = tmp_path / "f_0002.png"
    frame.write_bytes(b"earlier")
    assert render_main(["--method", "field", "--bundle", str(tmp_path / "none.pfn"), "--scene", "blobs",
                        "--orbit", "4", "--out", str(tmp_path / "f.exr")]) == 2
    refused(capsys, "f_0002.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_0002.png"]


def test_denoised_orbit_keeps_earlier_noisy_previews(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--denoise wrls also writes NAME_0000_noisy.png per frame: an earlier one is refused like a frame."""
    noisy = tmp_path / "f_0001_noisy.png"
    noisy.write_bytes(b"earlier")
    assert render_main(["--scene", "blobs", "--size", "16x16", "--spp", "1", "--quiet", "--orbit", "3",
                        "--denoise", "wrls", "--out", str(tmp_path / "f.exr")]) == 2
    refused(capsys, "f_0001_noisy.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_0001_noisy.png"]


def test_demo_keeps_an_earlier_demo(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "summary.txt").write_text("earlier")
    assert demo_main(["--scene", "blobs", "--photons", "3k", "--preset", "tiny", "--steps", "2", "--quiet",
                      "--out", str(tmp_path)]) == 2
    refused(capsys, "summary.txt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.txt"]


def test_eval_keeps_an_earlier_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "results.md").write_text("earlier")
    assert eval_main(["--quick", "--out", str(docs), "--work", str(tmp_path / "w")]) == 2
    refused(capsys, "results.md")
    assert (docs / "results.md").read_text() == "earlier" and not (tmp_path / "w").exists()
