"""Volume readers (and a raw writer): files on disk -> :class:`photon_fields.runtime.scene.volume.Volume`.

:func:`load_volume` picks a reader from the file suffix and always returns a normalized volume built
by :func:`photon_fields.runtime.scene.volume.make_volume` (float32 in [0, 1], indexed ``[x, y, z]``).

.. list-table:: Parameters of :func:`load_volume`
   :header-rows: 1
   :widths: 12 24 64

   * - Parameter
     - Type
     - Description
   * - ``path``
     - str | PathLike
     - The file. Suffix decides the format: ``.npy``; ``.raw`` / ``.bin`` / ``.dat`` (headerless raw);
       ``.nrrd`` / ``.nhdr`` (pynrrd); ``.nii`` / ``.nii.gz`` (nibabel). Case-insensitive.
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
       otherwise ``(1, 1, 1)``.
   * - ``window``
     - (float, float)
     - Raw values mapped to 0 and 1 (outside values clip). Default: raw sidecar ``window``, else the
       data min/max.
   * - ``axes``
     - str
     - ``.npy`` only: index order of the stored array, ``"xyz"`` (default) or ``"zyx"`` (transposed on
       load).
   * - ``name``
     - str
     - Volume name. Default: the file name without its format suffix.

Conventions:

- **Orientation.** The result is indexed ``[x, y, z]``. ``.npy`` arrays are taken as ``[x, y, z]``
  unless ``axes="zyx"``. Raw files are stored x-fastest (the usual ``nx ny nz`` dump: C order of shape
  ``(nz, ny, nx)``), read with that shape and transposed. NRRD is read with ``index_order='F'`` (first
  NRRD axis = x); NIfTI arrays are ``[i, j, k]`` = ``[x, y, z]``. Only voxel *sizes* are taken from
  the headers: direction cosines, flips and origins are ignored (the volume sits in a centred box).
- **Raw sidecar.** ``<file>.json`` (e.g. ``head.raw.json``), else ``<stem>.json`` (``head.json``, unless
  that is a scene file, i.e. has a ``volume`` entry),
  a JSON object with keys ``dims``, ``dtype``, ``endian``, ``spacing`` and optionally ``window`` and
  ``layout`` (which, if present, must be the one layout read: :data:`RAW_LAYOUT`); any other key is
  refused, naming the sidecar and the key. Keyword arguments override the sidecar. The file size must be exactly
  ``nx * ny * nz * itemsize``.
- **Memory.** Raw and ``.npy`` files (and uncompressed NIfTI, via nibabel) are memory-mapped; the
  normalization in :func:`make_volume` streams through them in chunks, so the only full-size
  allocation is the float32 result. ``.npy`` files are loaded with ``allow_pickle=False``.
- **Errors.** Every problem is a :class:`photon_fields.runtime.errors.InputError` whose ``what`` is the file path (the
  sidecar path for a bad sidecar) and whose problem is one line: missing file, unreadable or corrupt
  file, wrong dims/dtype for a raw file, unknown dtype name, non-3-D data, NaN/inf voxels, ...
  Exceptions from numpy/pynrrd/nibabel are converted; no traceback reaches the user.

:func:`save_volume_raw` writes a raw file plus its ``<file>.json`` sidecar (each atomically), the
inverse of the raw reader.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.io.atomic import atomic_path, atomic_write_text
from photon_fields.runtime.scene.volume import Volume, make_volume

__all__ = ["RAW_DTYPES", "RAW_LAYOUT", "SIDECAR_KEYS", "load_volume", "save_volume_raw", "find_sidecar"]

#: dtype names accepted for raw files (native numpy names, byte order given separately by ``endian``).
RAW_DTYPES: tuple[str, ...] = (
    "uint8", "int8", "uint16", "int16", "uint32", "int32", "uint64", "int64", "float16", "float32", "float64",
)  # fmt: skip
_ENDIAN = {"little": "<", "big": ">"}
#: Keys of a raw file's sidecar JSON (anything else is refused); ``layout`` is written by
#: :func:`save_volume_raw` for people reading the file and must say what the reader does.
SIDECAR_KEYS: tuple[str, ...] = ("dims", "dtype", "endian", "spacing", "window", "layout")
RAW_LAYOUT = "x fastest, then y, then z (C order of shape [nz, ny, nx])"
_RAW_SUFFIXES = (".raw", ".bin", ".dat")
_FORMATS = {".npy": "npy", ".nrrd": "nrrd", ".nhdr": "nrrd", ".nii": "nifti", ".nii.gz": "nifti"}
_FORMATS.update({s: "raw" for s in _RAW_SUFFIXES})

Spacing = tuple[float, float, float]
Window = tuple[float, float]


def _format_suffix(path: Path) -> str:
    name = path.name.lower()
    return ".nii.gz" if name.endswith(".nii.gz") else path.suffix.lower()


def _default_name(path: Path) -> str:
    suffix = _format_suffix(path)
    name = path.name
    return name[: len(name) - len(suffix)] if suffix and len(name) > len(suffix) else name


def _fmt(value: Any) -> str:
    """Short one-line rendering of a user value for messages."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 80 else text[:77] + "..."


# ----------------------------------------------------------------------------------------------------------
# Parameter validation


def _parse_dims(value: Any, what: str) -> tuple[int, int, int]:
    problem = f"dims must be three positive integers (nx, ny, nz), got {_fmt(value)}"
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        raise InputError(what, problem)
    items = list(value)
    if len(items) != 3:
        raise InputError(what, problem)
    dims = []
    for v in items:
        if isinstance(v, (bool, np.bool_)):
            raise InputError(what, problem)
        integral = isinstance(v, (int, np.integer))
        if not (integral or (isinstance(v, (float, np.floating)) and float(v).is_integer())):
            raise InputError(what, problem)
        n = int(v)
        if n < 1:
            raise InputError(what, problem)
        dims.append(n)
    return dims[0], dims[1], dims[2]


def _parse_dtype(value: Any, what: str) -> np.dtype:
    """A native-order dtype from a name in :data:`RAW_DTYPES` (or a numpy dtype / scalar type)."""
    allowed = ", ".join(RAW_DTYPES)
    if isinstance(value, str):
        name = value.strip().lower()
        if name not in RAW_DTYPES:
            raise InputError(what, f"unknown dtype name {value!r}; expected one of {allowed}")
        return np.dtype(name)
    try:
        dt = np.dtype(value)
    except (TypeError, ValueError):
        raise InputError(what, f"unknown dtype {_fmt(value)}; expected one of {allowed}") from None
    if dt.name not in RAW_DTYPES:
        raise InputError(what, f"unsupported dtype {dt}; expected one of {allowed}")
    return np.dtype(dt.name)


def _parse_endian(value: Any, what: str) -> str:
    key = value.strip().lower() if isinstance(value, str) else None
    if key not in _ENDIAN:
        raise InputError(what, f"endian must be 'little' or 'big', got {_fmt(value)}")
    return key  # type: ignore[return-value]


def _parse_spacing(value: Any, what: str) -> Spacing:
    problem = f"spacing must be three positive finite numbers (sx, sy, sz), got {_fmt(value)}"
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        raise InputError(what, problem)
    try:
        sp = [float(v) for v in value]
    except (TypeError, ValueError):
        raise InputError(what, problem) from None
    if len(sp) != 3 or not all(math.isfinite(s) and s > 0 for s in sp):
        raise InputError(what, problem)
    return sp[0], sp[1], sp[2]


def _parse_window(value: Any, what: str) -> Window:
    problem = f"window must be two finite numbers [low, high] with low < high, got {_fmt(value)}"
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        raise InputError(what, problem)
    try:
        w = [float(v) for v in value]
    except (TypeError, ValueError):
        raise InputError(what, problem) from None
    if len(w) != 2 or not all(math.isfinite(v) for v in w) or w[1] <= w[0]:
        raise InputError(what, problem)
    return w[0], w[1]


# ----------------------------------------------------------------------------------------------------------
# Readers: each returns (array indexed [x, y, z], spacing from the file or None, window from the file or None)

_ReadResult = tuple[np.ndarray, Spacing | None, Window | None]


def _read_npy(path: Path, what: str, axes: str) -> _ReadResult:
    with open(path, "rb") as f:
        head = f.read(6)
        if head[:4] == b"PK\x03\x04":
            raise InputError(what, "is an .npz archive, not a .npy array; extract the array with numpy first")
        if head != b"\x93NUMPY":
            raise InputError(
                what, "not a .npy array file (pickled or unknown data); save a numeric array with numpy.save"
            )
        f.seek(0)
        header = None
        try:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                header = np.lib.format.read_array_header_1_0(f)
            elif version == (2, 0):
                header = np.lib.format.read_array_header_2_0(f)
        except ValueError as err:
            raise InputError(what, f"corrupt .npy header ({err})") from None
        data_offset = f.tell()
    if header is not None:
        shape, _fortran, dtype = header
        if dtype.hasobject:
            raise InputError(
                what, "array holds Python objects (pickled data), which is refused; save a numeric array"
            )
        if len(shape) != 3:
            raise InputError(what, f"expected a 3-D scalar grid, got shape {tuple(shape)}")
        expected = data_offset + math.prod(shape) * dtype.itemsize
        size = path.stat().st_size
        if size < expected:
            raise InputError(what, f"truncated: expected {expected} bytes, file has {size}")
    arr = np.load(path, mmap_mode="r", allow_pickle=False)
    if not isinstance(arr, np.ndarray):  # defensive: np.load can return NpzFile for zip data
        raise InputError(what, "not a .npy array file")
    if arr.ndim != 3:
        raise InputError(what, f"expected a 3-D scalar grid, got shape {tuple(arr.shape)}")
    if axes == "zyx":
        arr = arr.transpose(2, 1, 0)
    return arr, None, None


def find_sidecar(path: str | os.PathLike[str]) -> Path | None:
    """The sidecar JSON of a raw file: ``<file>.json`` if it exists, else ``<stem>.json``, else None. A
    ``<stem>.json`` that is a scene file (it has a ``volume`` entry: ``engine.json`` beside ``engine.raw``)
    is not a sidecar."""
    p = Path(path)
    if p.with_name(p.name + ".json").is_file():
        return p.with_name(p.name + ".json")
    stem = p.with_suffix(".json")
    if stem.is_file() and not (isinstance(doc := _json_or_none(stem), dict) and "volume" in doc):
        return stem
    return None


def _json_or_none(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None


def _read_sidecar(raw_path: Path) -> tuple[dict[str, Any], Path | None]:
    side = find_sidecar(raw_path)
    if side is None:
        return {}, None
    try:
        meta = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(str(side), f"unreadable JSON sidecar of {raw_path.name} ({err})") from None
    if not isinstance(meta, dict):
        raise InputError(
            str(side), f"JSON sidecar of {raw_path.name} must be an object with keys dims, dtype, ..."
        )
    # A misspelt key ("dtyp", "spacng") must not silently fall back to a default or to a guess.
    check_keys(meta, SIDECAR_KEYS, str(side))
    if "layout" in meta and meta["layout"] != RAW_LAYOUT:
        raise InputError(str(side), f"layout {_fmt(meta['layout'])} is not read; raw files are read as "
                         f"{RAW_LAYOUT!r} (remove the key or convert the file)")
    return meta, side


def _raw_needs(path: Path, missing: list[str], side: Path | None) -> str:
    """What to write where when a raw file's dims and/or dtype are unknown: phrased for the scene file and
    the sidecar, which is what users edit (the Python keywords have the same names)."""
    words = {"dims": "dimensions", "dtype": "data type"}
    entries = {"dims": '"dims": [nx, ny, nz]', "dtype": f'"dtype" (one of {", ".join(RAW_DTYPES)})'}
    what = " and ".join(words[k] for k in missing)
    add = " and ".join(entries[k] for k in missing)
    if side is not None:
        where = f"to its sidecar {side.name} or to the scene's volume entry"
    else:
        where = (f"to the scene's volume entry, or to a sidecar JSON {path.name}.json (or "
                 f"{path.with_suffix('.json').name}) beside it")
    return (f"a raw volume has no header, so its {what} must be given: add {add} {where}; e.g. "
            '{"dims": [256, 256, 128], "dtype": "uint16", "endian": "little"}')


def _read_raw(
    path: Path, what: str, dims: Any, dtype: Any, endian: Any, spacing: Any, window: Any
) -> _ReadResult:
    meta, side = _read_sidecar(path)
    side_what = str(side) if side is not None else what

    def pick(key: str, kwarg: Any) -> tuple[Any, str]:
        if kwarg is not None:
            return kwarg, what
        return meta.get(key), side_what

    dims_v, dims_w = pick("dims", dims)
    dtype_v, dtype_w = pick("dtype", dtype)
    missing = [k for k, v in (("dims", dims_v), ("dtype", dtype_v)) if v is None]
    if missing:
        raise InputError(what, _raw_needs(path, missing, side))
    nx, ny, nz = _parse_dims(dims_v, dims_w)
    dt = _parse_dtype(dtype_v, dtype_w)
    endian_v, endian_w = pick("endian", endian)
    order = _ENDIAN[_parse_endian(endian_v, endian_w)] if endian_v is not None else "<"
    dt = dt.newbyteorder(order) if dt.itemsize > 1 else dt

    file_spacing = None
    if spacing is None and meta.get("spacing") is not None:
        file_spacing = _parse_spacing(meta["spacing"], side_what)
    file_window = None
    if window is None and meta.get("window") is not None:
        file_window = _parse_window(meta["window"], side_what)

    expected = nx * ny * nz * dt.itemsize
    size = path.stat().st_size
    if size < expected:
        raise InputError(
            what,
            f"truncated: expected {expected} bytes, file has {size} ({nx}x{ny}x{nz} {dt.name}); "
            "check dims and dtype",
        )
    if size > expected:
        raise InputError(
            what,
            f"file too long: has {size} bytes but {nx}x{ny}x{nz} {dt.name} needs {expected}; "
            "wrong dims or dtype?",
        )
    arr = np.memmap(path, dtype=dt, mode="r", shape=(nz, ny, nx), order="C")
    return arr.transpose(2, 1, 0), file_spacing, file_window


def _spacing_or_none(values: Any) -> Spacing | None:
    try:
        sp = [float(v) for v in values]
    except (TypeError, ValueError):
        return None
    if len(sp) == 3 and all(math.isfinite(s) and s > 0 for s in sp):
        return sp[0], sp[1], sp[2]
    return None


def _read_nrrd(path: Path, what: str, spacing_given: bool) -> _ReadResult:
    import nrrd  # imported lazily: only needed for NRRD input

    data, header = nrrd.read(str(path), index_order="F")
    if data.ndim != 3:
        raise InputError(what, f"expected a 3-D scalar grid, got shape {tuple(data.shape)}")
    file_spacing = None
    if header.get("spacings") is not None:
        file_spacing = _spacing_or_none(header["spacings"])
    if file_spacing is None and header.get("space directions") is not None:
        dirs = np.asarray(header["space directions"], dtype=np.float64)
        if dirs.ndim == 2 and dirs.shape[0] == 3:
            file_spacing = _spacing_or_none(np.linalg.norm(dirs, axis=1))
    has_spacing = header.get("spacings") is not None or header.get("space directions") is not None
    if file_spacing is None and has_spacing and not spacing_given:
        raise InputError(
            what, "NRRD header has no valid voxel spacing for the 3 axes; pass spacing=(sx, sy, sz)"
        )
    return data, file_spacing, None


def _read_nifti(path: Path, what: str, spacing_given: bool) -> _ReadResult:
    import nibabel  # imported lazily: only needed for NIfTI input

    img = nibabel.load(str(path))
    arr = np.asanyarray(img.dataobj)
    if arr.ndim == 4 and arr.shape[3] == 1:
        arr = arr[..., 0]
    if arr.ndim != 3:
        raise InputError(
            what, f"expected a 3-D scalar grid (or 4-D with one volume), got shape {tuple(arr.shape)}"
        )
    zooms = img.header.get_zooms()[:3]
    file_spacing = _spacing_or_none(zooms)
    if file_spacing is None and not spacing_given:
        raise InputError(
            what, f"NIfTI voxel sizes {_fmt(list(zooms))} are not positive; pass spacing=(sx, sy, sz)"
        )
    return arr, file_spacing, None


# ----------------------------------------------------------------------------------------------------------
# Public API


def load_volume(
    path: str | os.PathLike[str],
    *,
    dims: Sequence[int] | None = None,
    dtype: str | np.dtype | None = None,
    endian: str | None = None,
    spacing: Sequence[float] | None = None,
    window: Sequence[float] | None = None,
    axes: str = "xyz",
    name: str | None = None,
) -> Volume:
    """Read a scalar volume file and return it normalized (see the module docstring for parameters).

    Raises :class:`InputError` (one line, naming the file) for every problem with the file or arguments.
    """
    p = Path(path)
    what = str(p)
    if not p.exists():
        raise InputError(what, "file not found")
    if not p.is_file():
        raise InputError(what, "is not a regular file")
    suffix = _format_suffix(p)
    kind = _FORMATS.get(suffix)
    if kind is None:
        known = ", ".join(sorted(_FORMATS))
        raise InputError(
            what,
            f"unknown volume file type {repr(suffix) if suffix else '(no suffix)'}; expected one of {known}",
        )
    if axes not in ("xyz", "zyx"):
        raise InputError(what, f"axes must be 'xyz' or 'zyx', got {_fmt(axes)}")
    if axes != "xyz" and kind != "npy":
        raise InputError(what, "axes only applies to .npy files (other formats define their own index order)")
    if kind != "raw":
        given = [k for k, v in (("dims", dims), ("dtype", dtype), ("endian", endian)) if v is not None]
        if given:
            raise InputError(what, f"{', '.join(given)} only apply to raw files; this is a {suffix} file")
    sp = _parse_spacing(spacing, what) if spacing is not None else None
    win = _parse_window(window, what) if window is not None else None
    vol_name = name if name is not None else _default_name(p)

    try:
        if kind == "npy":
            arr, file_sp, file_win = _read_npy(p, what, axes)
        elif kind == "raw":
            arr, file_sp, file_win = _read_raw(p, what, dims, dtype, endian, spacing, window)
        elif kind == "nrrd":
            arr, file_sp, file_win = _read_nrrd(p, what, sp is not None)
        else:
            arr, file_sp, file_win = _read_nifti(p, what, sp is not None)
    except InputError:
        raise
    except MemoryError:
        raise InputError(what, "not enough memory to read this file") from None
    except Exception as err:  # any parser failure (corrupt header, bad compression, I/O error...)
        label = {"npy": ".npy", "raw": "raw", "nrrd": "NRRD", "nifti": "NIfTI"}[kind]
        raise InputError(what, f"cannot read {label} file: {type(err).__name__}: {err}") from err

    try:
        return make_volume(arr, sp or file_sp or (1.0, 1.0, 1.0), win or file_win, name=vol_name)
    except InputError as err:  # re-label: make_volume names the volume, users need the file
        raise InputError(what, err.problem) from None
    except OSError as err:  # I/O error while streaming a memory-mapped file
        raise InputError(what, f"read error: {err}") from err


def save_volume_raw(
    path: str | os.PathLike[str],
    data: np.ndarray,
    spacing: Sequence[float] = (1.0, 1.0, 1.0),
    dtype: str | np.dtype | None = None,
    *,
    endian: str = "little",
    window: Sequence[float] | None = None,
) -> Path:
    """Write ``data`` (indexed ``[x, y, z]``) as an x-fastest raw file plus ``<file>.json``.

    Returns the sidecar path. ``dtype`` defaults to the array's dtype; floats written to an integer
    dtype are rounded to nearest and must fit its range. Both files are written atomically (temp file in
    the same directory + ``os.replace``); the raw file first, then the sidecar.
    :func:`load_volume` reads the pair back.
    """
    p = Path(path)
    what = str(p)
    arr = np.asanyarray(data)
    if arr.ndim != 3:
        raise InputError(what, f"expected a 3-D scalar grid, got shape {tuple(arr.shape)}")
    dt = _parse_dtype(arr.dtype if dtype is None else dtype, what)
    order = _ENDIAN[_parse_endian(endian, what)]
    dt_out = dt.newbyteorder(order) if dt.itemsize > 1 else dt
    sp = _parse_spacing(spacing, what)
    win = _parse_window(window, what) if window is not None else None
    to_int = np.issubdtype(dt, np.integer)
    if to_int and arr.size:
        if np.issubdtype(arr.dtype, np.floating) and not np.all(np.isfinite(arr)):
            raise InputError(what, f"data has NaN/inf values; cannot store them as {dt.name}")
        info = np.iinfo(dt)
        lo, hi = float(np.min(arr)), float(np.max(arr))
        if np.issubdtype(arr.dtype, np.floating):
            lo, hi = float(np.rint(lo)), float(np.rint(hi))
        if lo < info.min or hi > info.max:
            raise InputError(what, f"data range [{lo}, {hi}] does not fit in {dt.name}")
    round_first = to_int and not np.issubdtype(arr.dtype, np.integer)

    nx, ny, nz = (int(n) for n in arr.shape)
    with atomic_path(p) as tmp, open(tmp, "wb") as f:
        for k in range(nz):  # one z-plane at a time: x fastest, then y
            plane = np.asarray(arr[:, :, k]).T
            if round_first:
                plane = np.rint(plane)
            f.write(np.ascontiguousarray(plane, dtype=dt_out).tobytes())
    meta: dict[str, Any] = {
        "dims": [nx, ny, nz],
        "dtype": dt.name,
        "endian": "little" if order == "<" else "big",
        "spacing": list(sp),
    }
    if win is not None:
        meta["window"] = list(win)
    meta["layout"] = RAW_LAYOUT
    side = p.with_name(p.name + ".json")
    atomic_write_text(side, json.dumps(meta, indent=2) + "\n")
    return side
