"""DICOM series via ``pydicom`` (the optional extra ``formats``): a folder of single-slice DICOM files.

Specification: DICOM PS3.3 (https://dicom.nema.org/medical/dicom/current/output/html/part03.html), Image Plane
Module C.7.6.2 (``ImagePositionPatient``, ``ImageOrientationPatient``, ``PixelSpacing``) and Modality LUT
Module C.11.1 (``RescaleSlope``, ``RescaleIntercept``); files in the PS3.10 file format (128-byte preamble,
``DICM``, file meta information).

- **Which files.** The folder's regular, non-hidden files named ``*.dcm`` / ``*.dicom`` / ``*.ima`` or
  starting with the PS3.10 ``DICM`` marker (at byte 128), whatever their name; ``DICOMDIR`` and other files
  are ignored. All must belong to one series (``SeriesInstanceUID``): a folder with several is refused in one
  line that lists them (UID, ``SeriesNumber``, ``SeriesDescription``, file count), unless the ``series``
  option picks one by its ``SeriesInstanceUID`` or ``SeriesNumber``.
- **Orientation.** ``ImageOrientationPatient`` gives the direction of a row (``r``, the first three values:
  along it the column index grows) and of a column (``c``, the last three: along it the row index grows).
  Our array is ``[x, y, z]`` with **x = the column index** (along ``r``), **y = the row index** (along ``c``)
  and **z = the slice, in increasing order of ``ImagePositionPatient`` projected on the normal
  ``n = r x c``** (never by file name or ``InstanceNumber``, which scanners do not order consistently). The
  grid ``(x, y, z)`` is thus right-handed in patient space; for the usual axial series (``r`` = +x, ``c`` =
  +y of the LPS patient frame) x runs to the patient's left, y to posterior and z to superior (feet to head).
  This is the voxel index order of ITK / SimpleITK's series reader. A pixel array, stored ``[row, col]`` =
  ``[y, x]``, is transposed into its slice.
- **Spacing.** x: ``PixelSpacing[1]`` (the column spacing), y: ``PixelSpacing[0]`` (the row spacing), z: the
  step between consecutive slice positions along ``n`` (``SliceThickness`` is not the spacing and is not
  used). The steps must be uniform (within 1 % of their mean); uneven steps (a missing file, a mixed
  acquisition) are refused, naming the files around the largest gap. Slices must share orientation, size and
  pixel spacing, and sit on one line along ``n`` (an in-plane drift of more than half a pixel, e.g. a CT
  gantry tilt, is refused: the grid would be sheared). Two files at one position (several echoes or time
  points in one series) are refused.
- **Values.** Stored values times ``RescaleSlope`` plus ``RescaleIntercept`` of each file (e.g. CT Hounsfield
  units; PET slices each have their own slope). The result is float32 when any file has a non-identity
  rescale, else the stored type. Greyscale single-frame images only (``SamplesPerPixel`` 1, one frame);
  compressed transfer syntaxes decode when pydicom has a decoder for them, else a one-line refusal.
- **Memory.** Headers are read first without pixel data (``stop_before_pixels``); then each file's pixels are
  decoded into the one output array, one file at a time.
- **Errors.** A corrupt, truncated or non-DICOM file, or one without pixel data, is one line naming it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.readers.params import ReadResult, fmt

#: The one line a user without pydicom sees.
MISSING_PYDICOM = "reading DICOM needs the optional package pydicom: pip install 'photon-fields[formats]'"
DICOM_SUFFIXES = (".dcm", ".dicom", ".ima")
_MAGIC_OFFSET = 128
#: Relative tolerance on slice steps (uniform spacing) and on orientation / spacing agreement between files.
STEP_TOLERANCE = 0.01
_ORIENTATION_TOLERANCE = 1e-3


def _pydicom(what: str) -> Any:
    try:
        import pydicom  # imported lazily: an optional dependency, only needed for DICOM input
    except ImportError:
        raise InputError(what, MISSING_PYDICOM) from None
    return pydicom


def _has_magic(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            f.seek(_MAGIC_OFFSET)
            return f.read(4) == b"DICM"
    except OSError:
        return False


def dicom_files(folder: Path) -> list[Path]:
    """The folder's DICOM files (see the module docstring), sorted by name (only for stable messages: slice
    order comes from the headers)."""
    files = []
    for p in sorted(folder.iterdir()):
        if p.name.startswith(".") or p.name.upper() == "DICOMDIR" or not p.is_file():
            continue
        if p.suffix.lower() in DICOM_SUFFIXES or _has_magic(p):
            files.append(p)
    return files


def is_dicom_folder(folder: Path) -> bool:
    """True when the folder holds DICOM files and no TIFF slices (a TIFF folder stays a TIFF folder)."""
    from photon_fields.runtime.scene.readers.tiff_stack import TIFF_SUFFIXES

    names = [p for p in folder.iterdir() if not p.name.startswith(".")]
    if any(p.suffix.lower() in TIFF_SUFFIXES for p in names):
        return False
    return bool(dicom_files(folder))


@dataclass(frozen=True)
class _Slice:
    """What the header pass keeps of one file."""

    path: Path
    rows: int
    cols: int
    position: np.ndarray  # ImagePositionPatient, mm
    orientation: np.ndarray  # ImageOrientationPatient: row direction (3), column direction (3)
    pixel_spacing: tuple[float, float] | None  # (row spacing, column spacing), mm
    rescale: tuple[float, float]  # RescaleSlope, RescaleIntercept


def _floats(ds: Any, key: str, n: int, file: Path, what: str, required: bool = True) -> np.ndarray | None:
    value = ds.get(key)
    if value is None:
        if required:
            raise InputError(what, f"file {file.name} has no {key}; slice order and spacing come from it (a 3-D "
                             "series needs ImagePositionPatient and ImageOrientationPatient)")
        return None
    try:
        values = np.array([float(v) for v in (value if isinstance(value, Sequence) else [value])])
    except (TypeError, ValueError):
        values = np.array([])
    if len(values) != n or not np.all(np.isfinite(values)):
        raise InputError(what, f"file {file.name}: {key} must be {n} numbers, got {fmt(value)}")
    return values


def read_dicom_folder(folder: Path, what: str, series: str | int | None, spacing_given: bool) -> ReadResult:
    """The reader interface of :mod:`photon_fields.runtime.scene.volume_io`: the series of ``folder``
    (the one ``series`` names when there are several) indexed ``[x, y, z]``, with its spacing."""
    pydicom = _pydicom(what)
    files = dicom_files(folder)
    if not files:
        raise InputError(what, "folder has no DICOM files")
    headers = [(f, _read_header(pydicom, f, what)) for f in files]
    headers = _one_series(headers, what, series)
    if len(headers) < 2:
        raise InputError(what, f"the series has one slice ({headers[0][0].name}); a volume needs at least two")
    slices = [_checked_slice(f, ds, what) for f, ds in headers]
    ordered, step = _order(slices, what)
    spacing = None
    if not spacing_given:
        first = ordered[0]
        if first.pixel_spacing is None:
            raise InputError(what, f"file {first.path.name} has no PixelSpacing; pass spacing=(sx, sy, sz)")
        spacing = (first.pixel_spacing[1], first.pixel_spacing[0], step)
    return _read_pixels(pydicom, ordered, what).transpose(2, 1, 0), spacing, None


def _read_header(pydicom: Any, file: Path, what: str) -> Any:
    try:
        ds = pydicom.dcmread(file, stop_before_pixels=True)
    except Exception as err:  # InvalidDicomError, EOF in a truncated header, bad value lengths...
        why = "no DICM marker and file meta header" if type(err).__name__ == "InvalidDicomError" \
            else f"{type(err).__name__}: {err}"
        raise InputError(what, f"cannot read DICOM file {file.name} (corrupt, truncated or not DICOM): "
                         f"{why}") from None
    # pydicom stops quietly at the end of a file cut between two elements: a missing type 1 attribute of the
    # General Series module (PS3.3 C.7.3.1) is how such a file shows.
    if not ds.get("SeriesInstanceUID"):
        raise InputError(what, f"DICOM file {file.name} has no SeriesInstanceUID (truncated, or not part of an "
                         "image series)")
    return ds


def _series_label(uid: str, group: list[tuple[Path, Any]]) -> str:
    ds = group[0][1]
    number = ds.get("SeriesNumber")
    description = ds.get("SeriesDescription")
    parts = [uid or "(no SeriesInstanceUID)"]
    if number is not None and str(number) != "":
        parts.append(f"#{number}")
    if description:
        parts.append(repr(str(description)))
    return f"{' '.join(parts)} ({len(group)} file{'s' if len(group) > 1 else ''})"


def _one_series(headers: list[tuple[Path, Any]], what: str, series: str | int | None) -> list[tuple[Path, Any]]:
    """The files of the one series in the folder, or of the series chosen by UID or SeriesNumber."""
    groups: dict[str, list[tuple[Path, Any]]] = {}
    for f, ds in headers:
        groups.setdefault(str(ds.get("SeriesInstanceUID", "")), []).append((f, ds))
    listing = "; ".join(_series_label(uid, g) for uid, g in list(groups.items())[:6])
    if len(groups) > 6:
        listing += f"; ... ({len(groups)} series in all)"
    if series is None:
        if len(groups) > 1:
            raise InputError(what, f"folder holds {len(groups)} DICOM series: {listing}; choose one with the "
                             "series option (its SeriesInstanceUID or SeriesNumber)")
        return next(iter(groups.values()))
    key = str(series).strip()
    chosen = [g for uid, g in groups.items() if uid == key]
    if not chosen:
        chosen = [g for g in groups.values() if str(g[0][1].get("SeriesNumber", "")).strip() == key]
    if len(chosen) != 1:
        problem = "matches several series" if chosen else "is not in the folder"
        raise InputError(what, f"series {fmt(series)} {problem}; the folder holds: {listing}")
    return chosen[0]


def _checked_slice(file: Path, ds: Any, what: str) -> _Slice:
    """:func:`_slice`, with a malformed header value (e.g. a non-numeric ``Rows``) named by its file."""
    try:
        return _slice(file, ds, what)
    except InputError:
        raise
    except (TypeError, ValueError) as err:
        raise InputError(what, f"file {file.name} has a malformed header value: {type(err).__name__}: {err}") from None


def _slice(file: Path, ds: Any, what: str) -> _Slice:
    frames = ds.get("NumberOfFrames")
    if frames is not None and int(frames) > 1:
        raise InputError(what, f"file {file.name} is a multi-frame image ({int(frames)} frames); only series of "
                         "single-slice files are read")
    samples = int(ds.get("SamplesPerPixel", 1))
    if samples != 1:
        raise InputError(what, f"file {file.name} has {samples} samples per pixel (colour); only greyscale "
                         "series are read")
    rows, cols = ds.get("Rows"), ds.get("Columns")
    if rows is None or cols is None:
        raise InputError(what, f"file {file.name} has no Rows/Columns: not an image (no pixel data?)")
    orientation = _floats(ds, "ImageOrientationPatient", 6, file, what)
    position = _floats(ds, "ImagePositionPatient", 3, file, what)
    assert orientation is not None and position is not None
    spacing = _floats(ds, "PixelSpacing", 2, file, what, required=False)
    if spacing is not None and not np.all(spacing > 0):
        raise InputError(what, f"file {file.name}: PixelSpacing must be positive, got {fmt(spacing)}")
    ps = None if spacing is None else (float(spacing[0]), float(spacing[1]))
    return _Slice(file, int(rows), int(cols), position, orientation, ps, _rescale(ds, file, what))


def _order(slices: list[_Slice], what: str) -> tuple[list[_Slice], float]:
    """The slices sorted along the normal, and the (uniform) step between them; refuses what a regular grid
    cannot hold (see the module docstring)."""
    first = slices[0]
    r, c = first.orientation[:3], first.orientation[3:]
    if not (math.isclose(np.linalg.norm(r), 1, abs_tol=0.01) and math.isclose(np.linalg.norm(c), 1, abs_tol=0.01)
            and abs(float(r @ c)) < 0.01):
        raise InputError(what, f"file {first.path.name}: ImageOrientationPatient {fmt(first.orientation)} is not "
                         "two orthogonal unit vectors")
    for s in slices[1:]:
        if not np.allclose(s.orientation, first.orientation, atol=_ORIENTATION_TOLERANCE):
            raise InputError(what, f"files {first.path.name} and {s.path.name} have different "
                             "ImageOrientationPatient; one series must have one orientation")
        if (s.rows, s.cols) != (first.rows, first.cols):
            raise InputError(what, f"file {s.path.name} is {s.cols}x{s.rows} pixels but {first.path.name} is "
                             f"{first.cols}x{first.rows}; all slices must have the same size")
        if (s.pixel_spacing is None) != (first.pixel_spacing is None) or (
                s.pixel_spacing is not None and first.pixel_spacing is not None
                and not np.allclose(s.pixel_spacing, first.pixel_spacing, rtol=STEP_TOLERANCE)):
            raise InputError(what, f"files {first.path.name} and {s.path.name} have different PixelSpacing "
                             f"({fmt(first.pixel_spacing)} and {fmt(s.pixel_spacing)})")
    r, c = r / np.linalg.norm(r), c / np.linalg.norm(c)
    n = np.cross(r, c)
    n /= np.linalg.norm(n)
    depth = np.array([float(s.position @ n) for s in slices])
    order = np.argsort(depth, kind="stable")
    ordered = [slices[i] for i in order]
    depth = depth[order]
    steps = np.diff(depth)
    tiny = 1e-4 * max(1.0, float(np.abs(depth).max()))
    dup = int(np.argmin(steps))
    if steps[dup] <= tiny:
        raise InputError(what, f"files {ordered[dup].path.name} and {ordered[dup + 1].path.name} are at the same "
                         f"slice position ({depth[dup]:g} mm along the normal); several acquisitions (echoes, "
                         "time points) in one series are not read")
    mean = float(steps.mean())
    gap = int(np.argmax(np.abs(steps - mean)))
    if abs(steps[gap] - mean) > STEP_TOLERANCE * mean:
        raise InputError(what, f"slice positions are not evenly spaced: steps from {steps.min():g} to "
                         f"{steps.max():g} mm (the most uneven between {ordered[gap].path.name} and "
                         f"{ordered[gap + 1].path.name}: a missing file?); a volume needs uniform spacing")
    pixel = min(first.pixel_spacing) if first.pixel_spacing is not None else 1.0
    origin = ordered[0].position
    for s in ordered[1:]:
        offset = s.position - origin
        drift = float(np.linalg.norm(offset - (offset @ n) * n))
        if drift > 0.5 * pixel:
            raise InputError(what, f"slices are sheared: {s.path.name} lies {drift:g} mm off the line through "
                             f"{ordered[0].path.name} along the slice normal (gantry tilt?); resample the series "
                             "to a regular grid first")
    return ordered, mean


def _rescale(ds: Any, file: Path, what: str) -> tuple[float, float]:
    try:
        slope = float(ds.get("RescaleSlope", 1.0))
        intercept = float(ds.get("RescaleIntercept", 0.0))
    except (TypeError, ValueError):
        raise InputError(what, f"file {file.name}: RescaleSlope/RescaleIntercept are not numbers") from None
    if not (math.isfinite(slope) and math.isfinite(intercept)):
        raise InputError(what, f"file {file.name}: RescaleSlope/RescaleIntercept are not finite")
    return slope, intercept


def _read_pixels(pydicom: Any, ordered: list[_Slice], what: str) -> np.ndarray:
    """The slices' pixels in order, ``[z, row, col]``, rescaled (float32) when any file says so."""
    out: np.ndarray | None = None
    for k, s in enumerate(ordered):
        try:
            ds = pydicom.dcmread(s.path)
        except Exception as err:
            raise InputError(what, f"cannot read DICOM file {s.path.name} (corrupt or truncated): "
                             f"{type(err).__name__}: {err}") from None
        if not any(key in ds for key in ("PixelData", "FloatPixelData", "DoubleFloatPixelData")):
            raise InputError(what, f"file {s.path.name} has no pixel data")
        try:
            image = np.asarray(ds.pixel_array)
        except MemoryError:
            raise
        except Exception as err:  # truncated pixel data, no decoder for a compressed transfer syntax...
            raise InputError(what, f"cannot decode the pixels of DICOM file {s.path.name}: "
                             f"{type(err).__name__}: {err}") from None
        if image.shape != (s.rows, s.cols):
            raise InputError(what, f"file {s.path.name}: pixel data of shape {image.shape} does not match Rows x "
                             f"Columns {s.rows} x {s.cols}")
        if out is None:
            identity = all(o.rescale == (1.0, 0.0) for o in ordered)
            out = np.empty((len(ordered), s.rows, s.cols), dtype=image.dtype if identity else np.float32)
        if out.dtype == np.float32:
            out[k] = image * np.float64(s.rescale[0]) + np.float64(s.rescale[1])
        elif image.dtype != out.dtype:
            raise InputError(what, f"file {s.path.name} stores {image.dtype} pixels but {ordered[0].path.name} "
                             f"stores {out.dtype}; all slices must have one pixel type")
        else:
            out[k] = image
    assert out is not None
    return out
