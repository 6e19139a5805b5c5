"""Tests for runtime.scene.volume_io: round trips per format, orientation, windowing, mmap and bad input."""

from __future__ import annotations

import gzip
import json
import pickle
from pathlib import Path
from typing import Any

import nibabel
import nrrd
import numpy as np
import pytest
from volume_helpers import expected_norm

import photon_fields.runtime.scene.volume_io as vio
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.volume import Volume
from photon_fields.runtime.scene.volume_io import load_volume, save_volume_raw

NX, NY, NZ = 8, 6, 5


def pattern(dtype: Any = np.float32) -> np.ndarray:
    """Asymmetric test grid indexed [x, y, z]: value = x + 10*y + 100*z (0 .. 457)."""
    x, y, z = np.meshgrid(np.arange(NX), np.arange(NY), np.arange(NZ), indexing="ij")
    return (x + 10 * y + 100 * z).astype(dtype)


def check_volume(vol: Volume, raw: np.ndarray, spacing: tuple[float, float, float]) -> None:
    assert isinstance(vol, Volume)
    assert vol.data.dtype == np.float32
    assert vol.dims == (NX, NY, NZ)
    np.testing.assert_array_equal(vol.data, expected_norm(raw))
    assert vol.spacing == pytest.approx(spacing, rel=1e-6)


def raw_bytes(data: np.ndarray, dtype: str) -> bytes:
    """x-fastest dump of an [x, y, z] array, written independently of save_volume_raw."""
    return np.ascontiguousarray(data.transpose(2, 1, 0)).astype(dtype).tobytes()


def assert_one_line_error(excinfo: pytest.ExceptionInfo[InputError], path: Path) -> str:
    msg = str(excinfo.value)
    assert "\n" not in msg and "\r" not in msg
    assert path.name in msg
    return msg


# ----------------------------------------------------------------------------------------------------------
# Round trips


def test_npy_roundtrip_xyz(tmp_path: Path) -> None:
    data = pattern()
    path = tmp_path / "grid.npy"
    np.save(path, data)
    vol = load_volume(path)
    check_volume(vol, data, (1.0, 1.0, 1.0))
    assert vol.name == "grid"
    # orientation, spelled out: voxel (x, y, z) holds x + 10y + 100z (normalized by 457)
    assert vol.data[7, 0, 0] == pytest.approx(7 / 457)
    assert vol.data[0, 5, 0] == pytest.approx(50 / 457)
    assert vol.data[0, 0, 4] == pytest.approx(400 / 457)


def test_npy_roundtrip_zyx_is_transposed(tmp_path: Path) -> None:
    data = pattern(np.int16)
    path = tmp_path / "grid_zyx.npy"
    np.save(path, np.ascontiguousarray(data.transpose(2, 1, 0)))  # stored [z, y, x]
    vol = load_volume(path, axes="zyx", spacing=(1, 2, 3), name="custom")
    check_volume(vol, data, (1.0, 2.0, 3.0))
    assert vol.name == "custom"


def test_npy_fortran_order(tmp_path: Path) -> None:
    data = np.asfortranarray(pattern(np.float64))
    path = tmp_path / "f.npy"
    np.save(path, data)
    check_volume(load_volume(path), data, (1.0, 1.0, 1.0))


def test_raw_roundtrip_with_sidecar(tmp_path: Path) -> None:
    data = pattern(np.uint16)
    path = tmp_path / "head.raw"
    path.write_bytes(raw_bytes(data, "<u2"))
    (tmp_path / "head.raw.json").write_text(
        json.dumps({"dims": [NX, NY, NZ], "dtype": "uint16", "endian": "little", "spacing": [0.5, 0.5, 2.0]})
    )
    vol = load_volume(path)
    check_volume(vol, data, (0.5, 0.5, 2.0))
    assert vol.name == "head"


def test_raw_sidecar_with_stem_name_and_window(tmp_path: Path) -> None:
    data = pattern(np.float32)
    path = tmp_path / "scan.dat"
    path.write_bytes(raw_bytes(data, "<f4"))
    meta = {"dims": [NX, NY, NZ], "dtype": "float32", "window": [100, 300]}
    (tmp_path / "scan.json").write_text(json.dumps(meta))
    vol = load_volume(path)
    np.testing.assert_array_equal(vol.data, expected_norm(data, (100.0, 300.0)))
    assert vol.spacing == (1.0, 1.0, 1.0)


def test_raw_kwargs_big_endian_uint16(tmp_path: Path) -> None:
    data = pattern(np.uint16) * 100  # up to 45700: both bytes matter, so a byte-order mix-up shows
    path = tmp_path / "big.bin"
    path.write_bytes(raw_bytes(data, ">u2"))
    vol = load_volume(path, dims=(NX, NY, NZ), dtype="uint16", endian="big", spacing=(1.0, 2.0, 4.0))
    check_volume(vol, data, (1.0, 2.0, 4.0))


def test_raw_kwargs_override_sidecar(tmp_path: Path) -> None:
    data = pattern(np.int16)
    path = tmp_path / "ov.raw"
    path.write_bytes(raw_bytes(data, ">i2"))
    (tmp_path / "ov.raw.json").write_text(
        json.dumps({"dims": [NZ, NY, NX], "dtype": "uint16", "endian": "little", "spacing": [9, 9, 9]})
    )
    vol = load_volume(path, dims=[NX, NY, NZ], dtype="int16", endian="big", spacing=(1, 1, 2))
    check_volume(vol, data, (1.0, 1.0, 2.0))


def test_raw_transposed_reader_would_fail(tmp_path: Path) -> None:
    # Reading the x-fastest dump as C order of (nx, ny, nz) gives a different array: guard the convention.
    data = pattern(np.float32)
    path = tmp_path / "o.raw"
    path.write_bytes(raw_bytes(data, "<f4"))
    vol = load_volume(path, dims=(NX, NY, NZ), dtype="float32")
    wrong = np.frombuffer(path.read_bytes(), dtype="<f4").reshape(NX, NY, NZ)
    assert not np.array_equal(vol.data, expected_norm(wrong))
    np.testing.assert_array_equal(vol.data, expected_norm(data))


def test_save_volume_raw_roundtrip(tmp_path: Path) -> None:
    data = pattern(np.float64)
    path = tmp_path / "saved.raw"
    side = save_volume_raw(path, data, (0.25, 0.5, 1.0), "uint16", endian="big", window=(0, 457))
    assert side == tmp_path / "saved.raw.json"
    meta = json.loads(side.read_text())
    assert meta["dims"] == [NX, NY, NZ] and meta["dtype"] == "uint16" and meta["endian"] == "big"
    assert path.read_bytes() == raw_bytes(data, ">u2")
    check_volume(load_volume(path), data, (0.25, 0.5, 1.0))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["saved.raw", "saved.raw.json"]


def test_save_volume_raw_rejects_out_of_range(tmp_path: Path) -> None:
    path = tmp_path / "o.raw"
    with pytest.raises(InputError) as ei:
        save_volume_raw(path, pattern(np.float32), (1, 1, 1), "uint8")
    assert_one_line_error(ei, path)
    assert list(tmp_path.iterdir()) == []


def test_nrrd_roundtrip_spacings(tmp_path: Path) -> None:
    data = pattern(np.int16)
    path = tmp_path / "vol.nrrd"
    nrrd.write(str(path), data, header={"spacings": [0.5, 1.0, 3.0]}, index_order="F")
    check_volume(load_volume(path), data, (0.5, 1.0, 3.0))


def test_nrrd_roundtrip_space_directions(tmp_path: Path) -> None:
    data = pattern(np.float32)
    path = tmp_path / "dirs.nrrd"
    header = {"space": "left-posterior-superior", "space directions": np.diag([0.7, 0.7, 2.5])}
    nrrd.write(str(path), data, header=header, index_order="F")
    check_volume(load_volume(path), data, (0.7, 0.7, 2.5))
    check_volume(load_volume(path, spacing=(1, 1, 1)), data, (1.0, 1.0, 1.0))


def test_nhdr_detached(tmp_path: Path) -> None:
    data = pattern(np.uint16)
    path = tmp_path / "det.nhdr"
    nrrd.write(str(path), data, header={"spacings": [1.0, 2.0, 2.0]}, detached_header=True, index_order="F")
    check_volume(load_volume(path), data, (1.0, 2.0, 2.0))


@pytest.mark.parametrize("suffix", [".nii", ".nii.gz"])
def test_nifti_roundtrip(tmp_path: Path, suffix: str) -> None:
    data = pattern(np.int16)
    path = tmp_path / f"brain{suffix}"
    nibabel.save(nibabel.Nifti1Image(data, np.diag([0.8, 0.9, 2.0, 1.0])), str(path))
    vol = load_volume(path)
    check_volume(vol, data, (0.8, 0.9, 2.0))
    assert vol.name == "brain"


def test_nifti_4d_single_volume_squeezed(tmp_path: Path) -> None:
    data = pattern(np.float32)
    path = tmp_path / "t.nii"
    nibabel.save(nibabel.Nifti1Image(data[..., None], np.diag([1.0, 1.0, 2.0, 1.0])), str(path))
    check_volume(load_volume(path), data, (1.0, 1.0, 2.0))


# ----------------------------------------------------------------------------------------------------------
# Window normalization


def test_window_clips_outside_values(tmp_path: Path) -> None:
    data = pattern(np.float32)
    path = tmp_path / "w.npy"
    np.save(path, data)
    vol = load_volume(path, window=(100, 200))
    np.testing.assert_array_equal(vol.data, expected_norm(data, (100.0, 200.0)))
    assert np.all(vol.data[data <= 100] == 0.0)
    assert np.all(vol.data[data >= 200] == 1.0)
    assert vol.data[5, 0, 1] == pytest.approx(0.05)  # 105 -> (105 - 100) / 100


# ----------------------------------------------------------------------------------------------------------
# Memory mapping


@pytest.fixture
def spy_make_volume(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    seen: list[Any] = []
    real = vio.make_volume

    def spy(raw: np.ndarray, *args: Any, **kwargs: Any) -> Volume:
        seen.append(raw)
        return real(raw, *args, **kwargs)

    monkeypatch.setattr(vio, "make_volume", spy)
    return seen


def _is_file_backed(arr: np.ndarray) -> bool:
    """True if ``arr`` is a np.memmap view (not an in-memory copy of the file)."""
    return isinstance(arr, np.memmap) and arr.base is not None


@pytest.mark.parametrize("axes", ["xyz", "zyx"])
def test_npy_is_memory_mapped(tmp_path: Path, spy_make_volume: list[Any], axes: str) -> None:
    path = tmp_path / "m.npy"
    np.save(path, pattern())
    load_volume(path, axes=axes)
    assert len(spy_make_volume) == 1 and _is_file_backed(spy_make_volume[0])
    assert not spy_make_volume[0].flags.writeable  # mode "r": the user's file cannot be modified


def test_raw_is_memory_mapped(tmp_path: Path, spy_make_volume: list[Any]) -> None:
    path = tmp_path / "m.raw"
    save_volume_raw(path, pattern(np.uint16), (1, 1, 1), "uint16")
    vol = load_volume(path)
    assert len(spy_make_volume) == 1 and _is_file_backed(spy_make_volume[0])
    assert spy_make_volume[0].shape == (NX, NY, NZ)
    assert not np.shares_memory(vol.data, spy_make_volume[0])


# ----------------------------------------------------------------------------------------------------------
# Bad input: InputError, one line, naming the file


def _expect_error(path: Path, match: str | None = None, **kwargs: Any) -> str:
    with pytest.raises(InputError) as ei:
        load_volume(path, **kwargs)
    msg = assert_one_line_error(ei, path)
    if match is not None:
        assert match.lower() in msg.lower(), msg
    return msg


@pytest.mark.parametrize("name", ["missing.npy", "missing.raw", "missing.nrrd", "missing.nii.gz"])
def test_missing_file(tmp_path: Path, name: str) -> None:
    _expect_error(tmp_path / name, "not found")


def test_truncated_raw(tmp_path: Path) -> None:
    path = tmp_path / "short.raw"
    path.write_bytes(raw_bytes(pattern(), "<f4")[:-10])
    n = NX * NY * NZ * 4
    msg = f"truncated: expected {n} bytes, file has {n - 10}"
    _expect_error(path, msg, dims=(NX, NY, NZ), dtype="float32")


def test_too_long_raw(tmp_path: Path) -> None:
    path = tmp_path / "long.raw"
    path.write_bytes(raw_bytes(pattern(), "<f4"))
    msg = _expect_error(path, "wrong dims or dtype", dims=(NX, NY, NZ), dtype="uint16")
    assert str(NX * NY * NZ * 4) in msg


def test_raw_without_dims(tmp_path: Path) -> None:
    """Issue 11: the message is phrased for what users write (the scene's volume entry, the sidecar JSON),
    not for the Python keywords, and says exactly which sidecar names the reader looks for."""
    path = tmp_path / "nodims.raw"
    path.write_bytes(raw_bytes(pattern(), "<f4"))
    msg = _expect_error(path, "its dimensions must be given", dtype="float32")
    assert 'add "dims": [nx, ny, nz] to the scene\'s volume entry' in msg, msg
    assert "nodims.raw.json (or nodims.json)" in msg and '"dtype" (' not in msg, msg
    assert "dims=" not in msg and "pass" not in msg, msg  # no Python-call phrasing
    msg = _expect_error(path, "its dimensions and data type must be given")
    assert '"dims": [nx, ny, nz] and "dtype" (one of ' + ", ".join(vio.RAW_DTYPES) + ")" in msg, msg
    # A sidecar that lacks dims is the place named.
    (tmp_path / "nodims.json").write_text(json.dumps({"dtype": "float32"}))
    msg = _expect_error(path, 'add "dims": [nx, ny, nz] to its sidecar nodims.json or to the scene\'s volume entry')


def test_sidecar_refuses_unknown_keys(tmp_path: Path) -> None:
    """A misspelt sidecar key ("spacng") used to be ignored, rendering with spacing (1, 1, 1)."""
    path = tmp_path / "sc.raw"
    path.write_bytes(raw_bytes(pattern(), "<f4"))
    side = tmp_path / "sc.raw.json"
    side.write_text(json.dumps({"dims": [NX, NY, NZ], "dtype": "float32", "spacng": [1, 1, 3]}))
    with pytest.raises(InputError) as ei:
        load_volume(path)
    msg = assert_one_line_error(ei, side)
    assert "unknown key 'spacng' (did you mean 'spacing'?)" in msg and "'window'" in msg, msg
    side.write_text(json.dumps({"dims": [NX, NY, NZ], "dtype": "float32", "layout": "z fastest"}))
    with pytest.raises(InputError) as ei:
        load_volume(path)
    assert "layout 'z fastest' is not read" in assert_one_line_error(ei, side)
    side.write_text(json.dumps({"dims": [NX, NY, NZ], "dtype": "float32", "layout": vio.RAW_LAYOUT}))
    check_volume(load_volume(path), pattern(np.float32), (1.0, 1.0, 1.0))


def test_scene_file_beside_its_raw_volume_is_not_a_sidecar(tmp_path: Path) -> None:
    """engine.json (a scene) next to engine.raw: the stem-named JSON is the scene, not the raw sidecar (the
    strict sidecar reader would otherwise refuse the scene's keys)."""
    from photon_fields.runtime.scene.scene import load_scene

    data = pattern(np.uint16)
    (tmp_path / "engine.raw").write_bytes(raw_bytes(data, "<u2"))
    scene = {"volume": {"path": "engine.raw", "dims": [NX, NY, NZ], "dtype": "uint16"},
             "transfer_function": {"preset": "grey_ramp"},
             "lights": [{"type": "directional", "direction": [0, -1, 0]}],
             "camera": {"eye": [2, 0, 0], "target": [0, 0, 0]}}
    (tmp_path / "engine.json").write_text(json.dumps(scene))
    check_volume(load_scene(tmp_path / "engine.json").volume, data, (1.0, 1.0, 1.0))


def test_raw_bad_dims_value(tmp_path: Path) -> None:
    path = tmp_path / "bd.raw"
    path.write_bytes(b"\0" * 64)
    _expect_error(path, "dims must be three positive integers", dims=(4, 4), dtype="uint8")
    _expect_error(path, "dims must be three positive integers", dims=(4, 4, 0), dtype="uint8")


def test_bad_dtype_name(tmp_path: Path) -> None:
    path = tmp_path / "bt.raw"
    path.write_bytes(raw_bytes(pattern(), "<f4"))
    _expect_error(path, "unknown dtype name 'float33'", dims=(NX, NY, NZ), dtype="float33")


def test_bad_dtype_in_sidecar_names_sidecar(tmp_path: Path) -> None:
    path = tmp_path / "bs.raw"
    path.write_bytes(raw_bytes(pattern(), "<f4"))
    (tmp_path / "bs.raw.json").write_text(json.dumps({"dims": [NX, NY, NZ], "dtype": "real"}))
    msg = _expect_error(path, "unknown dtype name")
    assert "bs.raw.json" in msg


def test_bad_endian(tmp_path: Path) -> None:
    path = tmp_path / "be.raw"
    path.write_bytes(raw_bytes(pattern(), "<f4"))
    _expect_error(path, "endian", dims=(NX, NY, NZ), dtype="float32", endian="middle")


def test_corrupt_sidecar(tmp_path: Path) -> None:
    path = tmp_path / "cs.raw"
    path.write_bytes(raw_bytes(pattern(), "<f4"))
    (tmp_path / "cs.raw.json").write_text('{"dims": [8, 6,')
    _expect_error(path, "sidecar")


def test_nan_voxel(tmp_path: Path) -> None:
    data = pattern()
    data[3, 2, 1] = np.nan
    path = tmp_path / "nan.npy"
    np.save(path, data)
    msg = _expect_error(path, "non-finite")
    assert "(3, 2, 1)" in msg


def test_inf_voxel_raw(tmp_path: Path) -> None:
    data = pattern()
    data[1, 4, 2] = np.inf
    path = tmp_path / "inf.raw"
    save_volume_raw(path, data, (1, 1, 1), "float32")
    msg = _expect_error(path, "non-finite")
    assert "(1, 4, 2)" in msg  # index reported in [x, y, z] order


def test_nan_voxel_nifti(tmp_path: Path) -> None:
    data = pattern()
    data[0, 0, 0] = np.nan
    path = tmp_path / "nan.nii.gz"
    nibabel.save(nibabel.Nifti1Image(data, np.eye(4)), str(path))
    _expect_error(path, "non-finite")


def test_2d_npy(tmp_path: Path) -> None:
    path = tmp_path / "flat.npy"
    np.save(path, np.zeros((8, 6), np.float32))
    _expect_error(path, "3-D")


def test_pickled_object_npy(tmp_path: Path) -> None:
    path = tmp_path / "obj.npy"
    arr = np.empty((2, 2, 2), dtype=object)
    arr[...] = "x"
    np.save(path, arr, allow_pickle=True)
    _expect_error(path, "python objects")


def test_plain_pickle_named_npy(tmp_path: Path) -> None:
    path = tmp_path / "pick.npy"
    path.write_bytes(pickle.dumps({"a": 1}))
    _expect_error(path, "pickled")


def test_npz_named_npy(tmp_path: Path) -> None:
    path = tmp_path / "arch.npy"
    with open(path, "wb") as f:
        np.savez(f, a=pattern())
    _expect_error(path, "npz")


def test_truncated_npy(tmp_path: Path) -> None:
    path = tmp_path / "cut.npy"
    np.save(path, pattern())
    path.write_bytes(path.read_bytes()[:-40])
    _expect_error(path, "truncated")


def test_corrupt_nrrd(tmp_path: Path) -> None:
    path = tmp_path / "bad.nrrd"
    path.write_bytes(b"this is not an NRRD file\x00\x01\x02")
    _expect_error(path, "cannot read NRRD")
    path2 = tmp_path / "bad2.nrrd"
    path2.write_bytes(b"NRRD0004\ntype: float\ndimension: 3\nsizes: 8 6 5\nencoding: raw\n\n" + b"\0" * 17)
    _expect_error(path2, "cannot read NRRD")


@pytest.mark.parametrize("name", ["bad.nii", "bad.nii.gz"])
def test_corrupt_nifti(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_bytes(b"\x00garbage" * 50)
    _expect_error(path, "cannot read NIfTI")


def test_truncated_nifti_gz(tmp_path: Path) -> None:
    path = tmp_path / "cut.nii.gz"
    nibabel.save(nibabel.Nifti1Image(pattern(), np.eye(4)), str(path))
    raw = gzip.decompress(path.read_bytes())
    path.write_bytes(gzip.compress(raw[:-100]))
    _expect_error(path, "cannot read NIfTI")


def test_nifti_4d_multi_volume_rejected(tmp_path: Path) -> None:
    path = tmp_path / "series.nii"
    nibabel.save(nibabel.Nifti1Image(np.zeros((NX, NY, NZ, 2), np.float32), np.eye(4)), str(path))
    _expect_error(path, "3-D")


@pytest.mark.parametrize("name", ["vol.xyz", "vol.gz", "volume", "vol.vtk"])
def test_unknown_suffix(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_bytes(b"\0" * 16)
    _expect_error(path, "unknown volume file type")


def test_raw_only_arguments_rejected_for_other_formats(tmp_path: Path) -> None:
    path = tmp_path / "a.npy"
    np.save(path, pattern())
    _expect_error(path, "only apply to raw", dims=(NX, NY, NZ))
    _expect_error(path, "axes", axes="yxz")


def test_bad_spacing_and_window_arguments(tmp_path: Path) -> None:
    path = tmp_path / "s.npy"
    np.save(path, pattern())
    _expect_error(path, "spacing", spacing=(1, 0, 1))
    _expect_error(path, "spacing", spacing=(1, 1))
    _expect_error(path, "window", window=(5, 5))
