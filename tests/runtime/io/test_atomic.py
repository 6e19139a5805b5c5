"""Tests for photon_fields.runtime.io.atomic: outputs appear complete or not at all."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest

from photon_fields.runtime.io.atomic import atomic_path, atomic_write_bytes, atomic_write_text


def _leftovers(directory: Path, keep: set[str]) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name not in keep)


def test_write_bytes_creates_file_and_no_temp(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"
    atomic_write_bytes(target, b"\x00\x01hello")
    assert target.read_bytes() == b"\x00\x01hello"
    assert _leftovers(tmp_path, {"out.bin"}) == []


def test_write_bytes_replaces_existing(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    target.write_text("old")
    atomic_write_text(target, '{"new": true}\n')
    assert target.read_text() == '{"new": true}\n'
    assert _leftovers(tmp_path, {"out.json"}) == []


def test_exception_keeps_existing_file_and_removes_temp(tmp_path: Path) -> None:
    target = tmp_path / "image.png"
    target.write_bytes(b"good old image")
    seen: list[Path] = []
    with pytest.raises(RuntimeError, match="boom"), atomic_path(target) as tmp:
        seen.append(tmp)
        tmp.write_bytes(b"half-writ")
        raise RuntimeError("boom")
    assert target.read_bytes() == b"good old image"
    assert not seen[0].exists()
    assert _leftovers(tmp_path, {"image.png"}) == []


def test_exception_without_existing_file_leaves_nothing(tmp_path: Path) -> None:
    target = tmp_path / "report.json"
    with pytest.raises(ValueError), atomic_path(target) as tmp:
        tmp.write_text("{")
        raise ValueError("bad")
    assert list(tmp_path.iterdir()) == []


def test_keyboard_interrupt_cleans_up(tmp_path: Path) -> None:
    target = tmp_path / "a.exr"
    target.write_bytes(b"keep")
    with pytest.raises(KeyboardInterrupt), atomic_path(target) as tmp:
        tmp.write_bytes(b"partial")
        raise KeyboardInterrupt
    assert target.read_bytes() == b"keep"
    assert _leftovers(tmp_path, {"a.exr"}) == []


def test_exception_in_helper_writer_keeps_existing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "x.bin"
    target.write_bytes(b"old")

    def failing_replace(src: str, dst: str) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_bytes(target, b"new")
    monkeypatch.undo()
    assert target.read_bytes() == b"old"
    assert _leftovers(tmp_path, {"x.bin"}) == []


def test_temp_path_same_dir_hidden_and_keeps_suffix(tmp_path: Path) -> None:
    for name, suffix in [("img.png", ".png"), ("vol.nii.gz", ".nii.gz"), ("noext", ""), ("b.npz", ".npz")]:
        target = tmp_path / name
        with atomic_path(target) as tmp:
            assert tmp.parent == tmp_path
            assert tmp.name.startswith(".")
            assert tmp.name.endswith(suffix)
            assert tmp.exists()  # created empty, writers may overwrite it
            assert tmp != target
            tmp.write_bytes(b"x")
        assert target.read_bytes() == b"x"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.npz", "img.png", "noext", "vol.nii.gz"]


def test_suffix_override(tmp_path: Path) -> None:
    with atomic_path(tmp_path / "a.dat", suffix=".npy") as tmp:
        assert tmp.name.endswith(".npy")
        tmp.write_bytes(b"1")
    assert (tmp_path / "a.dat").read_bytes() == b"1"


def test_works_with_numpy_savez(tmp_path: Path) -> None:
    # np.savez appends ".npz" to names without it: the temp name must keep the suffix.
    target = tmp_path / "bundle.npz"
    with atomic_path(target) as tmp:
        np.savez(tmp, a=np.arange(3))
    with np.load(target) as z:
        assert z["a"].tolist() == [0, 1, 2]
    assert _leftovers(tmp_path, {"bundle.npz"}) == []


def test_missing_parent_directory_raises(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        atomic_write_bytes(tmp_path / "nope" / "f.bin", b"x")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permissions")
def test_permissions_follow_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        atomic_write_bytes(tmp_path / "f.bin", b"x")
    finally:
        os.umask(old)
    assert (tmp_path / "f.bin").stat().st_mode & 0o777 == 0o644
