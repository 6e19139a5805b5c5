"""``.npy`` reader: a 3-D numeric numpy array, memory-mapped, indexed ``[x, y, z]`` (or ``[z, y, x]`` with
``axes="zyx"``). Pickled objects and ``.npz`` archives are refused before numpy would unpickle anything."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.readers.params import ReadResult


def read_npy(path: Path, what: str, axes: str) -> ReadResult:
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
