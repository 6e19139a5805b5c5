"""Headerless raw volumes (``.raw`` / ``.bin`` / ``.dat``): the reader, its JSON sidecar, and the writer.

Raw files are stored x-fastest (the usual ``nx ny nz`` dump: C order of shape ``(nz, ny, nx)``), memory-mapped
with that shape and transposed to ``[x, y, z]``. Dims, dtype, endianness, spacing and window come from the
keyword arguments (the scene's volume entry) or from the sidecar ``<file>.json`` / ``<stem>.json``; the sidecar
refuses unknown keys so a typo never falls back to a default. :func:`save_volume_raw` is the inverse.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.io.atomic import atomic_path, atomic_write_text
from photon_fields.runtime.scene.readers.params import (
    ENDIAN,
    RAW_DTYPES,
    ReadResult,
    fmt,
    parse_dims,
    parse_dtype,
    parse_endian,
    parse_spacing,
    parse_window,
)

#: Keys of a raw file's sidecar JSON (anything else is refused); ``layout`` is written by
#: :func:`save_volume_raw` for people reading the file and must say what the reader does.
SIDECAR_KEYS: tuple[str, ...] = ("dims", "dtype", "endian", "spacing", "window", "layout")
RAW_LAYOUT = "x fastest, then y, then z (C order of shape [nz, ny, nx])"
RAW_SUFFIXES = (".raw", ".bin", ".dat")


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
        raise InputError(str(side), f"layout {fmt(meta['layout'])} is not read; raw files are read as "
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


def read_raw(
    path: Path, what: str, dims: Any, dtype: Any, endian: Any, spacing: Any, window: Any
) -> ReadResult:
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
    nx, ny, nz = parse_dims(dims_v, dims_w)
    dt = parse_dtype(dtype_v, dtype_w)
    endian_v, endian_w = pick("endian", endian)
    order = ENDIAN[parse_endian(endian_v, endian_w)] if endian_v is not None else "<"
    dt = dt.newbyteorder(order) if dt.itemsize > 1 else dt

    file_spacing = None
    if spacing is None and meta.get("spacing") is not None:
        file_spacing = parse_spacing(meta["spacing"], side_what)
    file_window = None
    if window is None and meta.get("window") is not None:
        file_window = parse_window(meta["window"], side_what)

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
    :func:`photon_fields.runtime.scene.volume_io.load_volume` reads the pair back.
    """
    p = Path(path)
    what = str(p)
    arr = np.asanyarray(data)
    if arr.ndim != 3:
        raise InputError(what, f"expected a 3-D scalar grid, got shape {tuple(arr.shape)}")
    dt = parse_dtype(arr.dtype if dtype is None else dtype, what)
    order = ENDIAN[parse_endian(endian, what)]
    dt_out = dt.newbyteorder(order) if dt.itemsize > 1 else dt
    sp = parse_spacing(spacing, what)
    win = parse_window(window, what) if window is not None else None
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
