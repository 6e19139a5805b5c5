"""Volume files on disk -> :class:`photon_fields.runtime.scene.volume.Volume`: the format dispatch.

:func:`load_volume` picks a reader from the file suffix (or, for a folder, the Zarr, DICOM or TIFF slice
reader) and always
returns a normalized volume built by :func:`photon_fields.runtime.scene.volume.make_volume` (float32 in [0, 1],
indexed ``[x, y, z]``). The readers live in :mod:`photon_fields.runtime.scene.readers`, one module per format.

.. list-table:: Parameters of :func:`load_volume`
   :header-rows: 1
   :widths: 12 24 64

   * - Parameter
     - Type
     - Description
   * - ``path``
     - str | PathLike
     - The file. Suffix decides the format: ``.npy``; ``.raw`` / ``.bin`` / ``.dat`` (headerless raw);
       ``.nrrd`` / ``.nhdr`` (pynrrd); ``.nii`` / ``.nii.gz`` (nibabel); ``.vti`` (VTK XML ImageData);
       ``.tif`` / ``.tiff`` (a multi-page TIFF, needs the ``formats`` extra). Case-insensitive. A folder is
       a Zarr array / OME-Zarr image when named ``*.zarr`` or holding ``.zarray`` / ``.zgroup`` /
       ``zarr.json``; else a DICOM series when it holds DICOM files and no TIFF; else a stack of 2-D TIFF
       slices (all three need the ``formats`` extra).
   * - ``dims``
     - (int, int, int)
     - Raw only: grid size ``(nx, ny, nz)``. Default: from the sidecar JSON (required from one or the other).
   * - ``dtype``
     - str
     - Raw only: voxel type by numpy name: ``uint8``, ``int8``, ``uint16``, ``int16``, ``uint32``,
       ``int32``, ``uint64``, ``int64``, ``float16``, ``float32``, ``float64``. Default: from the sidecar
       (required from one or the other).
   * - ``endian``
     - str
     - Raw only: ``"little"`` or ``"big"``. Default: sidecar, else ``"little"``.
   * - ``spacing``
     - (float, float, float)
     - Voxel size along x, y, z (any unit; only ratios matter). Overrides what the file says. Default:
       NRRD ``spacings`` or norms of ``space directions``; NIfTI ``get_zooms()[:3]``; raw sidecar;
       ``.vti`` ``Spacing``; TIFF OME or ImageJ metadata; OME-Zarr ``coordinateTransformations`` scale;
       DICOM ``PixelSpacing`` and slice position steps; otherwise ``(1, 1, 1)``.
   * - ``window``
     - (float, float)
     - Raw values mapped to 0 and 1 (outside values clip). Default: raw sidecar ``window``, else the
       data min/max.
   * - ``axes``
     - str
     - ``.npy`` only: index order of the stored array, ``"xyz"`` (default) or ``"zyx"`` (transposed on
       load).
   * - ``array``
     - str
     - ``.vti`` only: name of the data array to read. Default: PointData's ``Scalars`` array, else its
       first array, else the same in CellData.
   * - ``level``
     - int
     - Zarr only: OME-Zarr resolution level, the index into ``multiscales[0].datasets`` (0 = full
       resolution, the default; only that level is read).
   * - ``series``
     - str | int
     - DICOM folders only: the series to read (``SeriesInstanceUID`` or ``SeriesNumber``) when the folder
       holds several. Default: the folder's only series (several are refused, listing them).
   * - ``name``
     - str
     - Volume name. Default: the file (or folder) name without its format suffix.

Conventions:

- **Orientation.** The result is indexed ``[x, y, z]``. ``.npy`` arrays are taken as ``[x, y, z]``
  unless ``axes="zyx"``. Raw files are stored x-fastest (the usual ``nx ny nz`` dump: C order of shape
  ``(nz, ny, nx)``), read with that shape and transposed. NRRD is read with ``index_order='F'`` (first
  NRRD axis = x); NIfTI arrays are ``[i, j, k]`` = ``[x, y, z]``; ``.vti`` points are x fastest (a
  Fortran-order reshape); TIFF pages (or slices) are z, rows y, columns x; Zarr arrays are ``[z, y, x]``
  (OME-Zarr axes by name, see :mod:`~photon_fields.runtime.scene.readers.zarr_store`); DICOM columns are x,
  rows y and slices z in order along the slice normal (see
  :mod:`~photon_fields.runtime.scene.readers.dicom_series`). Only voxel *sizes* are taken
  from the headers: direction cosines, flips and origins are ignored (the volume sits in a centred box).
- **Raw sidecar.** ``<file>.json`` (e.g. ``head.raw.json``), else ``<stem>.json`` (``head.json``, unless
  that is a scene file, i.e. has a ``volume`` entry),
  a JSON object with keys ``dims``, ``dtype``, ``endian``, ``spacing`` and optionally ``window`` and
  ``layout`` (which, if present, must be the one layout read: :data:`RAW_LAYOUT`); any other key is
  refused, naming the sidecar and the key. Keyword arguments override the sidecar. The file size must be exactly
  ``nx * ny * nz * itemsize``.
- **Memory.** Raw and ``.npy`` files, uncompressed NIfTI (via nibabel), appended raw uncompressed ``.vti``
  data and uncompressed contiguous TIFF files are memory-mapped; the normalization in :func:`make_volume`
  streams through them in chunks, so the only full-size allocation is the float32 result. ``.npy`` files are
  loaded with ``allow_pickle=False``.
- **Errors.** Every problem is a :class:`photon_fields.runtime.errors.InputError` whose ``what`` is the file path (the
  sidecar path for a bad sidecar) and whose problem is one line: missing file, unreadable or corrupt
  file, wrong dims/dtype for a raw file, unknown dtype name, non-3-D data, NaN/inf voxels, ...
  Exceptions from numpy/pynrrd/nibabel/tifffile/zarr/pydicom are converted; no traceback reaches the user.

:func:`save_volume_raw` writes a raw file plus its ``<file>.json`` sidecar (each atomically), the
inverse of the raw reader.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.readers.npy_file import read_npy
from photon_fields.runtime.scene.readers.params import RAW_DTYPES, fmt, parse_spacing, parse_window
from photon_fields.runtime.scene.readers.raw_file import (
    RAW_LAYOUT,
    RAW_SUFFIXES,
    SIDECAR_KEYS,
    find_sidecar,
    read_raw,
    save_volume_raw,
)
from photon_fields.runtime.scene.volume import Volume, make_volume

__all__ = ["RAW_DTYPES", "RAW_LAYOUT", "SIDECAR_KEYS", "load_volume", "save_volume_raw", "find_sidecar"]

_FORMATS = {".npy": "npy", ".nrrd": "nrrd", ".nhdr": "nrrd", ".nii": "nifti", ".nii.gz": "nifti", ".vti": "vti",
            ".tif": "tiff", ".tiff": "tiff"}
_FORMATS.update({s: "raw" for s in RAW_SUFFIXES})
_FORMATS[".zarr"] = "zarr"  # a folder; named here so that a file called *.zarr is refused by the Zarr reader
_LABELS = {"npy": ".npy", "raw": "raw", "nrrd": "NRRD", "nifti": "NIfTI", "vti": ".vti", "tiff": "TIFF",
           "tiff_folder": "TIFF", "zarr": "Zarr", "dicom": "DICOM"}


def _format_suffix(path: Path) -> str:
    name = path.name.lower()
    return ".nii.gz" if name.endswith(".nii.gz") else path.suffix.lower()


def _default_name(path: Path) -> str:
    suffix = _format_suffix(path)
    name = path.name
    return name[: len(name) - len(suffix)] if suffix and len(name) > len(suffix) else name


def _kind(p: Path, what: str) -> str:
    """The reader for ``p``: a folder is a Zarr store, a DICOM series or a stack of TIFF slices (in that order
    of checks), a file goes by its suffix."""
    if not p.exists():
        raise InputError(what, "file not found")
    if p.is_dir():
        from photon_fields.runtime.scene.readers.dicom_series import is_dicom_folder
        from photon_fields.runtime.scene.readers.zarr_store import is_zarr_folder

        return "zarr" if is_zarr_folder(p) else "dicom" if is_dicom_folder(p) else "tiff_folder"
    if not p.is_file():
        raise InputError(what, "is not a regular file")
    suffix = _format_suffix(p)
    kind = _FORMATS.get(suffix)
    if kind is None:
        known = ", ".join(sorted(_FORMATS))
        raise InputError(
            what,
            f"unknown volume file type {repr(suffix) if suffix else '(no suffix)'}; expected one of {known} "
            "(or a Zarr folder, a DICOM series folder or a folder of TIFF slices)",
        )
    return kind


def load_volume(
    path: str | os.PathLike[str],
    *,
    dims: Sequence[int] | None = None,
    dtype: str | np.dtype | None = None,
    endian: str | None = None,
    spacing: Sequence[float] | None = None,
    window: Sequence[float] | None = None,
    axes: str = "xyz",
    array: str | None = None,
    level: int | None = None,
    series: str | int | None = None,
    name: str | None = None,
) -> Volume:
    """Read a scalar volume file (or folder: Zarr, DICOM series, TIFF slices) and return it normalized (see the module
    docstring for parameters).

    Raises :class:`InputError` (one line, naming the file) for every problem with the file or arguments.
    """
    p = Path(path)
    what = str(p)
    kind = _kind(p, what)
    suffix = {"tiff_folder": "TIFF folder", "zarr": "Zarr store", "dicom": "DICOM folder"}.get(
        kind, f"{_format_suffix(p)} file")
    if axes not in ("xyz", "zyx"):
        raise InputError(what, f"axes must be 'xyz' or 'zyx', got {fmt(axes)}")
    if axes != "xyz" and kind != "npy":
        raise InputError(what, "axes only applies to .npy files (other formats define their own index order)")
    if kind != "raw":
        given = [k for k, v in (("dims", dims), ("dtype", dtype), ("endian", endian)) if v is not None]
        if given:
            raise InputError(what, f"{', '.join(given)} only apply to raw files; this is a {suffix}")
    if array is not None and kind != "vti":
        raise InputError(what, f"array only applies to .vti files; this is a {suffix}")
    if array is not None and not isinstance(array, str):
        raise InputError(what, f"array must be the name of a data array (a string), got {fmt(array)}")
    if level is not None and kind != "zarr":
        raise InputError(what, f"level only applies to Zarr / OME-Zarr stores; this is a {suffix}")
    if level is not None and (isinstance(level, bool) or not isinstance(level, int) or level < 0):
        raise InputError(what, f"level must be a resolution level number (0 = full resolution), got {fmt(level)}")
    if series is not None and kind != "dicom":
        raise InputError(what, f"series only applies to DICOM folders; this is a {suffix}")
    if series is not None and (isinstance(series, bool) or not isinstance(series, (str, int))):
        raise InputError(what, f"series must be a SeriesInstanceUID or SeriesNumber, got {fmt(series)}")
    sp = parse_spacing(spacing, what) if spacing is not None else None
    win = parse_window(window, what) if window is not None else None
    vol_name = name if name is not None else _default_name(p)

    try:
        if kind == "npy":
            arr, file_sp, file_win = read_npy(p, what, axes)
        elif kind == "raw":
            arr, file_sp, file_win = read_raw(p, what, dims, dtype, endian, spacing, window)
        elif kind == "nrrd":
            from photon_fields.runtime.scene.readers.nrrd_file import read_nrrd

            arr, file_sp, file_win = read_nrrd(p, what, sp is not None)
        elif kind == "nifti":
            from photon_fields.runtime.scene.readers.nifti_file import read_nifti

            arr, file_sp, file_win = read_nifti(p, what, sp is not None)
        elif kind == "vti":
            from photon_fields.runtime.scene.readers.vti_file import read_vti

            arr, file_sp, file_win = read_vti(p, what, array, sp is not None)
        elif kind == "zarr":
            from photon_fields.runtime.scene.readers.zarr_store import read_zarr

            arr, file_sp, file_win = read_zarr(p, what, level, sp is not None)
        elif kind == "dicom":
            from photon_fields.runtime.scene.readers.dicom_series import read_dicom_folder

            arr, file_sp, file_win = read_dicom_folder(p, what, series, sp is not None)
        else:
            from photon_fields.runtime.scene.readers.tiff_stack import read_tiff_file, read_tiff_folder

            reader = read_tiff_folder if kind == "tiff_folder" else read_tiff_file
            arr, file_sp, file_win = reader(p, what)
    except InputError:
        raise
    except MemoryError:
        raise InputError(what, "not enough memory to read this file") from None
    except Exception as err:  # any parser failure (corrupt header, bad compression, I/O error...)
        raise InputError(what, f"cannot read {_LABELS[kind]} file: {type(err).__name__}: {err}") from err

    try:
        return make_volume(arr, sp or file_sp or (1.0, 1.0, 1.0), win or file_win, name=vol_name)
    except InputError as err:  # re-label: make_volume names the volume, users need the file
        raise InputError(what, err.problem) from None
    except OSError as err:  # I/O error while streaming a memory-mapped file
        raise InputError(what, f"read error: {err}") from err
