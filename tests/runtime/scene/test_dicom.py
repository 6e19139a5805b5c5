"""Tests for DICOM series (runtime/scene/readers/dicom_series.py) through load_volume: folders of single-slice
files written by pydicom, with shuffled file names and InstanceNumbers so that only the positions can order
them; orientation (columns x, rows y, slices along the normal), spacing, rescale, series choice and
one-line errors."""

from __future__ import annotations

import builtins
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from volume_helpers import expected_norm, one_line_error

from photon_fields.runtime.scene.readers.dicom_series import MISSING_PYDICOM
from photon_fields.runtime.scene.volume_io import load_volume

pydicom = pytest.importorskip("pydicom", reason="pydicom is the optional extra 'formats'")
from pydicom.dataset import Dataset, FileMetaDataset  # noqa: E402
from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid  # noqa: E402

NX, NY, NZ = 5, 7, 6  # columns, rows, slices
AXIAL = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)
SAGITTAL = (0.0, 1.0, 0.0, 0.0, 0.0, -1.0)  # rows along +y, columns along -z: the normal is -x
SHUFFLE = [3, 0, 5, 1, 4, 2]  # file / InstanceNumber label of slice k: neither name nor number order is position order


def pattern(nz: int = NZ) -> np.ndarray:
    """Indexed [x, y, z]: value = x + 10 y + 100 z."""
    x, y, z = np.meshgrid(np.arange(NX), np.arange(NY), np.arange(nz), indexing="ij")
    return (x + 10 * y + 100 * z).astype(np.uint16)


def write_slice(path: Path, image: np.ndarray, position: Sequence[float], orientation: Sequence[float] = AXIAL,
                pixel_spacing: Sequence[float] = (0.7, 0.4), series_uid: str = "1.2.3.1", number: int = 0,
                slope: float | None = None, intercept: float | None = None, series_number: int = 3,
                description: str = "axial", pixels: bool = True) -> None:
    """One CT slice ``image`` ([row, col]) as a PS3.10 file, written by pydicom."""
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = CTImageStorage
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
    ds.StudyInstanceUID, ds.SeriesInstanceUID = "1.2.3", series_uid
    ds.Modality, ds.SeriesNumber, ds.SeriesDescription, ds.InstanceNumber = "CT", series_number, description, number
    ds.Rows, ds.Columns = image.shape
    ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
    ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
    ds.ImagePositionPatient = [f"{v:.6g}" for v in position]
    ds.ImageOrientationPatient = [f"{v:.6g}" for v in orientation]
    ds.PixelSpacing = [f"{v:.6g}" for v in pixel_spacing]
    if slope is not None:
        ds.RescaleSlope, ds.RescaleIntercept = f"{slope:.6g}", f"{intercept or 0:.6g}"
    if pixels:
        ds.PixelData = np.ascontiguousarray(image, dtype="<u2").tobytes()
    ds.save_as(path, enforce_file_format=True)


def write_series(folder: Path, data: np.ndarray, orientation: Sequence[float] = AXIAL, step: float = 2.5,
                 origin: Sequence[float] = (-10.0, 20.0, 30.0), suffix: str = ".dcm", **kwargs: Any) -> Path:
    """``data`` ([x, y, z]) as slices at ``origin + k * step * normal``, slice k in file ``IM<SHUFFLE[k]>``."""
    folder.mkdir(exist_ok=True)
    n = np.cross(orientation[:3], orientation[3:])
    for k in range(data.shape[2]):
        label = SHUFFLE[k] if data.shape[2] == NZ else k
        write_slice(folder / f"IM{label}{suffix}", data[:, :, k].T, np.asarray(origin) + k * step * n, orientation,
                    number=label, **kwargs)
    return folder


# ----------------------------------------------------------------------------------------------------------
# Round trips


@pytest.mark.parametrize("orientation", [AXIAL, SAGITTAL], ids=["axial", "sagittal"])
def test_order_orientation_and_spacing(tmp_path: Path, orientation: tuple[float, ...]) -> None:
    folder = write_series(tmp_path / "ct", pattern(), orientation)
    vol = load_volume(folder)
    assert vol.dims == (NX, NY, NZ) and vol.name == "ct"
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    top = float(pattern().max())  # spelled out: column x, row y, slice z (the one nearest the origin first)
    assert vol.data[4, 0, 0] == pytest.approx(4 / top) and vol.data[0, 6, 0] == pytest.approx(60 / top)
    assert vol.data[0, 0, 5] == pytest.approx(500 / top)
    assert vol.spacing == pytest.approx((0.4, 0.7, 2.5))  # PixelSpacing is (row spacing = y, column spacing = x)


def test_positions_against_the_normal(tmp_path: Path) -> None:
    """Files listed head to feet (positions decreasing along the normal) still load feet to head: z follows
    the normal, so the volume is the reverse of the listing."""
    folder = write_series(tmp_path / "down", pattern(), step=-3.0)
    vol = load_volume(folder)
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()[:, :, ::-1]))
    assert vol.spacing == pytest.approx((0.4, 0.7, 3.0))


def test_files_found_by_the_dicm_marker(tmp_path: Path) -> None:
    folder = write_series(tmp_path / "nosuffix", pattern(), suffix="")
    (folder / "DICOMDIR").write_bytes(b"\x00" * 128 + b"DICM")  # the index file is never a slice
    (folder / "notes.txt").write_text("not a slice")
    np.testing.assert_array_equal(load_volume(folder).data, expected_norm(pattern()))


def test_rescale_per_file(tmp_path: Path) -> None:
    """Each file's slope and intercept apply to its own slice (PET style); the HU window shows the intercept."""
    folder = tmp_path / "pet"
    folder.mkdir()
    data = pattern()
    slopes = [1.0, 2.0, 0.5, 4.0, 1.5, 3.0]
    for k in range(NZ):
        write_slice(folder / f"s{SHUFFLE[k]}.dcm", data[:, :, k].T, (0, 0, 2.5 * k), slope=slopes[k],
                    intercept=-1000.0)
    real = data * np.array(slopes)[None, None, :] - 1000.0
    np.testing.assert_allclose(load_volume(folder).data, expected_norm(real), atol=1e-6)
    np.testing.assert_allclose(load_volume(folder, window=(-1000, 1000)).data,
                               expected_norm(real, (-1000.0, 1000.0)), atol=1e-6)


def test_stored_type_kept_unless_rescaled(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Identity rescale: the stored uint16 reaches the normalization (no float copy); otherwise float32."""
    import photon_fields.runtime.scene.volume_io as vio

    seen: list[np.ndarray] = []
    real = vio.make_volume
    monkeypatch.setattr(vio, "make_volume", lambda raw, *a, **k: seen.append(raw) or real(raw, *a, **k))
    load_volume(write_series(tmp_path / "plain", pattern()))
    load_volume(write_series(tmp_path / "ct", pattern(), slope=1.0, intercept=-1024.0))
    assert seen[0].dtype == np.uint16 and seen[1].dtype == np.float32
    np.testing.assert_array_equal(seen[1], pattern().astype(np.float32) - 1024.0)


def test_series_option_and_scene_entry(tmp_path: Path) -> None:
    from photon_fields.runtime.scene.scene import load_scene

    folder = write_series(tmp_path / "mixed", pattern(), description="axial")
    scout = np.zeros((NY, NX), np.uint16)
    for k in range(3):
        write_slice(folder / f"scout{k}.dcm", scout + k, (0, 0, k), series_uid="1.2.3.9", series_number=1,
                    description="localizer")
    msg = one_line_error(folder, "folder holds 2 DICOM series: 1.2.3.1 #3 'axial' (6 files); 1.2.3.9 #1 "
                                 "'localizer' (3 files); choose one with the series option")
    assert "SeriesInstanceUID or SeriesNumber" in msg
    np.testing.assert_array_equal(load_volume(folder, series="1.2.3.1").data, expected_norm(pattern()))
    assert load_volume(folder, series=1).dims == (NX, NY, 3)
    one_line_error(folder, "series '7' is not in the folder; the folder holds: 1.2.3.1", series="7")
    scene = {"volume": {"path": "mixed", "series": 3}, "transfer_function": {"preset": "grey_ramp"},
             "lights": [{"type": "directional", "direction": [0, -1, 0]}],
             "camera": {"eye": [2, 0, 0], "target": [0, 0, 0]}}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    vol = load_scene(tmp_path / "scene.json").volume
    np.testing.assert_array_equal(vol.data, expected_norm(pattern()))
    assert vol.spacing == pytest.approx((0.4, 0.7, 2.5))


# ----------------------------------------------------------------------------------------------------------
# Bad input


def test_uneven_duplicate_and_sheared_positions(tmp_path: Path) -> None:
    folder = write_series(tmp_path / "gap", pattern())
    (folder / f"IM{SHUFFLE[3]}.dcm").unlink()  # slice 3 missing: steps 2.5 and one 5.0
    one_line_error(folder, f"slice positions are not evenly spaced: steps from 2.5 to 5 mm (the most uneven "
                           f"between IM{SHUFFLE[2]}.dcm and IM{SHUFFLE[4]}.dcm: a missing file?)")
    folder = write_series(tmp_path / "dup", pattern())
    write_slice(folder / "extra.dcm", pattern()[:, :, 0].T, (-10.0, 20.0, 30.0 + 2.5 * 2))
    one_line_error(folder, "are at the same slice position")
    folder = tmp_path / "tilt"
    folder.mkdir()
    for k in range(NZ):  # gantry tilt: each slice moves 1 mm along y (more than half a 0.7 mm pixel)
        write_slice(folder / f"s{k}.dcm", pattern()[:, :, k].T, (0.0, 1.0 * k, 2.5 * k))
    one_line_error(folder, "slices are sheared: s1.dcm lies 1 mm off the line through s0.dcm")


def test_inconsistent_slices(tmp_path: Path) -> None:
    folder = write_series(tmp_path / "size", pattern())
    write_slice(folder / f"IM{SHUFFLE[2]}.dcm", np.zeros((NY, NX + 1), np.uint16), (-10.0, 20.0, 35.0))
    one_line_error(folder, f"file IM{SHUFFLE[2]}.dcm is 6x7 pixels but")
    folder = write_series(tmp_path / "orient", pattern())
    write_slice(folder / "IM9.dcm", pattern()[:, :, 0].T, (-10.0, 20.0, 50.0), orientation=SAGITTAL)
    one_line_error(folder, "have different ImageOrientationPatient")
    folder = write_series(tmp_path / "single", pattern()[:, :, :1])
    one_line_error(folder, "the series has one slice (IM0.dcm)")


def test_corrupt_truncated_and_pixel_less_files(tmp_path: Path) -> None:
    folder = write_series(tmp_path / "corrupt", pattern())
    (folder / "IM2.dcm").write_bytes(b"this is not DICOM")
    one_line_error(folder, "cannot read DICOM file IM2.dcm (corrupt, truncated or not DICOM)")
    folder = write_series(tmp_path / "cut", pattern())
    whole = (folder / "IM4.dcm").read_bytes()
    (folder / "IM4.dcm").write_bytes(whole[: len(whole) - 20])  # pixel data cut short
    one_line_error(folder, "cannot decode the pixels of DICOM file IM4.dcm: ValueError: The number of bytes")
    (folder / "IM4.dcm").write_bytes(whole[:200])  # cut inside the header, between two elements
    one_line_error(folder, "DICOM file IM4.dcm has no SeriesInstanceUID (truncated")
    (folder / "IM4.dcm").write_bytes(whole[:203])  # cut inside an element
    one_line_error(folder, "DICOM file IM4.dcm")
    folder = write_series(tmp_path / "nopix", pattern())
    write_slice(folder / f"IM{SHUFFLE[1]}.dcm", pattern()[:, :, 1].T, (-10.0, 20.0, 32.5), pixels=False)
    one_line_error(folder, f"file IM{SHUFFLE[1]}.dcm has no pixel data")
    folder = write_series(tmp_path / "nopos", pattern())
    ds = pydicom.dcmread(folder / "IM5.dcm")
    del ds.ImagePositionPatient
    ds.save_as(folder / "IM5.dcm")
    one_line_error(folder, "file IM5.dcm has no ImagePositionPatient")


@pytest.mark.filterwarnings("ignore::UserWarning")  # pydicom warns about the invalid IS value it reads
def test_malformed_header_value(tmp_path: Path) -> None:
    from pydicom.dataelem import RawDataElement
    from pydicom.tag import Tag

    folder = write_series(tmp_path / "ct", pattern())
    ds = pydicom.dcmread(folder / "IM2.dcm")
    ds[0x00280008] = RawDataElement(Tag(0x00280008), "IS", 4, b"abc ", 0, False, True)  # NumberOfFrames "abc"
    ds.save_as(folder / "IM2.dcm")
    one_line_error(folder, "file IM2.dcm has a malformed header value: ValueError")


def test_option_and_folder_kind_errors(tmp_path: Path) -> None:
    np.save(tmp_path / "v.npy", pattern())
    one_line_error(tmp_path / "v.npy", "series only applies to DICOM folders; this is a .npy file", series="1")
    folder = write_series(tmp_path / "ct", pattern())
    one_line_error(folder, "level only applies to Zarr / OME-Zarr stores; this is a DICOM folder", level=1)
    one_line_error(folder, "series must be a SeriesInstanceUID or SeriesNumber", series=[1])
    (tmp_path / "study").mkdir()
    folder.rename(tmp_path / "study" / "ct")  # the series one level down
    one_line_error(tmp_path / "study", "nor DICOM files, nor Zarr metadata; subfolders are not searched")


def test_missing_pydicom_names_the_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = write_series(tmp_path / "ct", pattern())
    real_import = builtins.__import__

    def no_pydicom(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "pydicom" or name.startswith("pydicom."):
            raise ImportError("No module named 'pydicom'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_pydicom)
    assert one_line_error(folder, MISSING_PYDICOM).endswith("pip install 'photon-fields[formats]'")
