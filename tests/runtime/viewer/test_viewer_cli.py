"""``pfn-view``'s command line: every bad input stops with one ``error:`` line and exit status 2 before anything
is served; a non-loopback --host warns."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

pytest.importorskip("uvicorn")

from photon_fields.runtime.viewer.cli import _main  # noqa: E402
from photon_fields.runtime.viewer.launch import is_loopback  # noqa: E402


def one_error_line(stderr: str) -> str:
    lines = stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in stderr, stderr
    return lines[0]


@pytest.mark.parametrize(("argv", "needle"), [
    ([], "SCENE"),
    (["nosuchscene"], "nosuchscene"),
    (["blobs", "--size", "abc"], "--size"),
    (["blobs", "--size", "8x8"], "--size"),
    (["blobs", "--size", "4096x4096"], "--size"),
    (["blobs", "--port", "70000"], "--port"),
    (["blobs", "--port", "x"], "--port"),
    (["blobs", "--threads", "99"], "--threads"),
    (["blobs", "--max-spp", "0"], "--max-spp"),
    (["blobs", "--renderer", "neural"], "--renderer"),
    (["blobs", "--renderer", "magic"], "--renderer"),
    (["blobs", "--bundle", "missing.pfn"], "missing.pfn"),
    (["blobs", "--map", "missing.npz"], "missing.npz"),
    (["blobs", "--seed", str(1 << 70)], "--seed"),
    (["blobs", "--bogus"], "command line"),
    (["blobs", "--retrain-photons", "lots"], "--retrain-photons"),
    (["blobs", "--retrain-photons", "0"], "--retrain-photons"),
    (["blobs", "--final-gather-after", "-3"], "--final-gather-after"),
    (["blobs", "--final-gather-after", "soon"], "--final-gather-after"),
    (["blobs", "--interactive-level", "9"], "--interactive-level"),
    (["blobs", "--interactive-level", "fine"], "--interactive-level"),
])
def test_bad_input_is_one_line_and_status_2(argv: list[str], needle: str, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    argv = [a.replace("missing", str(tmp_path / "missing")) for a in argv]
    assert _main([*argv, "--no-browser", "--out", str(tmp_path / "out")]) == 2
    captured = capsys.readouterr()
    assert needle in one_error_line(captured.err)
    assert "http://" not in captured.out
    assert not (tmp_path / "out").exists()


def test_port_in_use_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        assert _main(["blobs", "--port", str(port), "--no-browser", "--out", str(tmp_path / "o")]) == 2
    assert "cannot listen" in one_error_line(capsys.readouterr().err)


def test_out_must_be_a_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "file").write_text("x")
    assert _main(["blobs", "--no-browser", "--out", str(tmp_path / "file")]) == 2
    assert "--out" in one_error_line(capsys.readouterr().err)


def test_loopback_hosts() -> None:
    assert all(is_loopback(h) for h in ("127.0.0.1", "127.1.2.3", "::1", "localhost"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "192.168.1.5", "::", "example.org"))


def test_final_gather_after_takes_a_count_or_never() -> None:
    from photon_fields.runtime.renderers.registry import DEFAULT_GATHER_AFTER
    from photon_fields.runtime.viewer.cli import build_parser

    parse = build_parser().parse_args
    assert parse(["blobs"]).final_gather_after == DEFAULT_GATHER_AFTER
    assert parse(["blobs", "--final-gather-after", "never"]).final_gather_after is None
    assert parse(["blobs", "--final-gather-after", "0"]).final_gather_after == 0


def test_a_label_scene_opens_and_one_with_too_many_labels_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """A label scene loads with its label panel; a volume with more labels than the panel shows is refused in one
    line before anything is served."""
    from viewer_helpers import label_scene_file

    from photon_fields.runtime.viewer import transfer_edit
    from photon_fields.runtime.viewer.launch import load_inputs

    scene = label_scene_file(tmp_path)
    loaded = load_inputs(str(scene), out_dir=tmp_path / "out")
    assert loaded.scene.tf.categorical
    monkeypatch.setattr(transfer_edit, "MAX_PANEL_LABELS", 2)
    assert _main([str(scene), "--no-browser", "--out", str(tmp_path / "out")]) == 2
    assert "its volume has 3 labels; the viewer's label panel shows at most 2" in \
        one_error_line(capsys.readouterr().err)
