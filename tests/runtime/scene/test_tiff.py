"""Tests for TIFF stacks (runtime/scene/readers/tiff_stack.py) through load_volume: files written by
``tifffile.imwrite`` (multi-page, ImageJ and OME spacing metadata, compressed), folders of slices (natural
order), orientation (pages = z, rows = y, columns = x), memory mapping and one-line errors."""

from __future__ import annotations

import builtins
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from volume_helpers import expected_norm, one_line_error

import photon_fields.runtime.scene.volume_io as vio
from photon_fields.runtime.scene.readers.tiff_stack import MISSING_TIFFFILE, natural_key
from photon_fields.runtime.scene.volume_io import load_volume

tifffile = pytest.importorskip("tifffile", reason="tifffile is the optional extra 'formats'")

NX, NY, NZ = 5, 7, 9


def pattern(dtype: Any = np.uint16) -> np.ndarray:
    """Indexed [x, y, z]: value = x + 10 y + 100 z (0 .. 864)."""
    x, y, z = np.meshgrid(np.arange(NX), np.arange(NY), np.arange(NZ), indexing="ij")
    return (x + 10 * y + 100 * z).astype(dtype)


def as_stack(data: np.ndarray) -> np.ndarray:
    """[x, y, z] -> [z, y, x]: page z, row y, column x (how the test files are written)."""
    return np.ascontiguousarray(data.transpose(2, 1, 0))


# ----------------------------------------------------------------------------------------------------------
# Multi-page files


def test_multipage_orientation(tmp_path: Path) -> None:
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, as_stack(pattern()))
    vol = load_volume(path)
    assert vol.dims == (NX, NY, NZ) and vol.name == "stack"
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    # spelled out: column x, row y, page z
    assert vol.data[4, 0, 0] == pytest.approx(4 / 864)
    assert vol.data[0, 6, 0] == pytest.approx(60 / 864)
    assert vol.data[0, 0, 8] == pytest.approx(800 / 864)
    assert vol.spacing == (1.0, 1.0, 1.0)  # no ImageJ/OME metadata


def test_imagej_spacing(tmp_path: Path) -> None:
    path = tmp_path / "ij.tiff"
    tifffile.imwrite(path, as_stack(pattern(np.float32)), imagej=True, resolution=(1 / 0.25, 1 / 0.5),
                     metadata={"spacing": 2.0, "unit": "um", "axes": "ZYX"})
    vol = load_volume(path)
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    assert vol.spacing == pytest.approx((0.25, 0.5, 2.0))
    assert load_volume(path, spacing=(1, 1, 3)).spacing == (1.0, 1.0, 3.0)  # the user's spacing wins


def test_ome_spacing(tmp_path: Path) -> None:
    path = tmp_path / "cells.ome.tif"
    tifffile.imwrite(path, as_stack(pattern()), metadata={"axes": "ZYX", "PhysicalSizeX": 0.3,
                                                          "PhysicalSizeY": 0.4, "PhysicalSizeZ": 1.5})
    vol = load_volume(path)
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    assert vol.spacing == pytest.approx((0.3, 0.4, 1.5))


def test_uncompressed_is_memory_mapped_compressed_is_decoded(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[np.ndarray] = []
    real = vio.make_volume
    monkeypatch.setattr(vio, "make_volume", lambda raw, *a, **k: seen.append(raw) or real(raw, *a, **k))
    tifffile.imwrite(tmp_path / "plain.tif", as_stack(pattern()))
    tifffile.imwrite(tmp_path / "packed.tif", as_stack(pattern()), compression="zlib")
    a, b = load_volume(tmp_path / "plain.tif"), load_volume(tmp_path / "packed.tif")
    assert isinstance(seen[0], np.memmap) and not seen[0].flags.writeable
    assert not isinstance(seen[1], np.memmap)
    np.testing.assert_array_equal(a.data, b.data)


# ----------------------------------------------------------------------------------------------------------
# Folders of slices


def write_slices(folder: Path, data: np.ndarray, name: str = "slice_{}.tif", **kwargs: Any) -> Path:
    folder.mkdir()
    for z in range(data.shape[2]):
        tifffile.imwrite(folder / name.format(z), np.ascontiguousarray(data[:, :, z].T), **kwargs)
    return folder


def test_folder_natural_order(tmp_path: Path) -> None:
    """slice_2 before slice_10: with 12 slices, a plain string sort would put slice_10 and slice_11 second."""
    x, y, z = np.meshgrid(np.arange(NX), np.arange(NY), np.arange(12), indexing="ij")
    data = (x + 10 * y + 100 * z).astype(np.uint16)
    folder = write_slices(tmp_path / "slices", data)
    (folder / "notes.txt").write_text("not a slice")
    (folder / ".hidden.tif").write_bytes(b"resource fork")
    vol = load_volume(folder)
    assert vol.dims == (NX, NY, 12) and vol.name == "slices"
    np.testing.assert_array_equal(vol.data, expected_norm(data))
    assert sorted(["s10", "s2", "s1"], key=natural_key) == ["s1", "s2", "s10"]


def test_folder_spacing_from_first_slice(tmp_path: Path) -> None:
    folder = write_slices(tmp_path / "ij", pattern(), imagej=True, resolution=(2.0, 2.0),
                          metadata={"spacing": 3.0, "unit": "um"})
    for z in range(1, NZ):  # the first slice's metadata is the one read
        tifffile.imwrite(folder / f"slice_{z}.tif", np.ascontiguousarray(pattern()[:, :, z].T), imagej=True,
                         resolution=(4.0, 4.0), metadata={"spacing": 9.0, "unit": "um"})
    vol = load_volume(folder)
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    assert vol.spacing == pytest.approx((0.5, 0.5, 3.0))


def test_folder_from_a_scene_file(tmp_path: Path) -> None:
    from photon_fields.runtime.scene.scene import load_scene

    write_slices(tmp_path / "slices", pattern())
    scene = {"volume": {"path": "slices", "spacing": [1, 1, 2]}, "transfer_function": {"preset": "grey_ramp"},
             "lights": [{"type": "directional", "direction": [0, -1, 0]}],
             "camera": {"eye": [2, 0, 0], "target": [0, 0, 0]}}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    vol = load_scene(tmp_path / "scene.json").volume
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    assert vol.spacing == (1.0, 1.0, 2.0)


# ----------------------------------------------------------------------------------------------------------
# Bad input


def test_folder_with_slices_of_different_sizes(tmp_path: Path) -> None:
    folder = write_slices(tmp_path / "mixed", pattern())
    tifffile.imwrite(folder / "slice_4.tif", np.zeros((NY, NX + 1), np.uint16))
    msg = one_line_error(folder, "slice slice_4.tif is 6x7 uint16 but slice_0.tif is 5x7 uint16")
    assert "same size" in msg
    tifffile.imwrite(folder / "slice_4.tif", np.zeros((NY, NX), np.float32))
    one_line_error(folder, "slice slice_4.tif is 5x7 float32")


def test_empty_folder_and_single_slices(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    one_line_error(tmp_path / "empty", "folder has no .tif/.tiff slices")
    (tmp_path / "one").mkdir()
    tifffile.imwrite(tmp_path / "one" / "a.tif", np.zeros((NY, NX), np.uint8))
    one_line_error(tmp_path / "one", "folder has one slice (a.tif)")
    tifffile.imwrite(tmp_path / "flat.tif", np.zeros((NY, NX), np.uint8))
    one_line_error(tmp_path / "flat.tif", "single 2-D image")


def test_rgb_and_corrupt_files(tmp_path: Path) -> None:
    tifffile.imwrite(tmp_path / "rgb.tif", np.zeros((NZ, NY, NX, 3), np.uint8), photometric="rgb")
    one_line_error(tmp_path / "rgb.tif", "3 samples per pixel")
    (tmp_path / "bad.tif").write_bytes(b"II*\x00garbage" * 10)
    one_line_error(tmp_path / "bad.tif", "holds no images (empty or corrupt)")
    (tmp_path / "text.tif").write_text("a text file named .tif")
    one_line_error(tmp_path / "text.tif", "cannot read TIFF file")
    folder = write_slices(tmp_path / "broken", pattern())
    (folder / "slice_3.tif").write_bytes(b"not a tiff at all")
    one_line_error(folder, "cannot read slice slice_3.tif")


def test_missing_tifffile_names_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "s.tif"
    tifffile.imwrite(path, as_stack(pattern()))
    real_import = builtins.__import__

    def no_tifffile(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "tifffile":
            raise ImportError("No module named 'tifffile'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_tifffile)
    assert one_line_error(path, MISSING_TIFFFILE).endswith("pip install 'photon-fields[formats]'")
    one_line_error(tmp_path, MISSING_TIFFFILE)
