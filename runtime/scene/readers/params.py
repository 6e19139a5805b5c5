"""Validation of the reader options shared by the volume formats (dims, dtype, endian, spacing, window).

Each parser turns a user value (keyword argument, scene entry or sidecar value) into a checked Python value or
raises a one-line :class:`InputError` naming ``what`` (the file or sidecar the value belongs to).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError

#: dtype names accepted for raw files (native numpy names, byte order given separately by ``endian``).
RAW_DTYPES: tuple[str, ...] = (
    "uint8", "int8", "uint16", "int16", "uint32", "int32", "uint64", "int64", "float16", "float32", "float64",
)  # fmt: skip
ENDIAN = {"little": "<", "big": ">"}

Spacing = tuple[float, float, float]
Window = tuple[float, float]
#: What every reader returns: the array indexed [x, y, z], the file's spacing and window (None if it has none).
ReadResult = tuple[np.ndarray, Spacing | None, Window | None]


def fmt(value: Any) -> str:
    """Short one-line rendering of a user value for messages."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 80 else text[:77] + "..."


def parse_dims(value: Any, what: str) -> tuple[int, int, int]:
    problem = f"dims must be three positive integers (nx, ny, nz), got {fmt(value)}"
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


def parse_dtype(value: Any, what: str) -> np.dtype:
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
        raise InputError(what, f"unknown dtype {fmt(value)}; expected one of {allowed}") from None
    if dt.name not in RAW_DTYPES:
        raise InputError(what, f"unsupported dtype {dt}; expected one of {allowed}")
    return np.dtype(dt.name)


def parse_endian(value: Any, what: str) -> str:
    key = value.strip().lower() if isinstance(value, str) else None
    if key not in ENDIAN:
        raise InputError(what, f"endian must be 'little' or 'big', got {fmt(value)}")
    return key  # type: ignore[return-value]


def parse_spacing(value: Any, what: str) -> Spacing:
    problem = f"spacing must be three positive finite numbers (sx, sy, sz), got {fmt(value)}"
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        raise InputError(what, problem)
    try:
        sp = [float(v) for v in value]
    except (TypeError, ValueError):
        raise InputError(what, problem) from None
    if len(sp) != 3 or not all(math.isfinite(s) and s > 0 for s in sp):
        raise InputError(what, problem)
    return sp[0], sp[1], sp[2]


def parse_window(value: Any, what: str) -> Window:
    problem = f"window must be two finite numbers [low, high] with low < high, got {fmt(value)}"
    if isinstance(value, (str, bytes)) or not isinstance(value, (Sequence, np.ndarray)):
        raise InputError(what, problem)
    try:
        w = [float(v) for v in value]
    except (TypeError, ValueError):
        raise InputError(what, problem) from None
    if len(w) != 2 or not all(math.isfinite(v) for v in w) or w[1] <= w[0]:
        raise InputError(what, problem)
    return w[0], w[1]


def spacing_or_none(values: Any) -> Spacing | None:
    """Three positive finite numbers from a header value, or None when it is not that."""
    try:
        sp = [float(v) for v in values]
    except (TypeError, ValueError):
        return None
    if len(sp) == 3 and all(math.isfinite(s) and s > 0 for s in sp):
        return sp[0], sp[1], sp[2]
    return None
