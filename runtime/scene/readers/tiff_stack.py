"""TIFF stacks via ``tifffile`` (the optional extra ``formats``): a multi-page ``.tif`` / ``.tiff`` file, or a
folder of 2-D slices.

- **Orientation.** Pages (or the folder's slices, sorted naturally by name: ``slice_2`` before ``slice_10``)
  are z, image rows are y, image columns are x: the stack, stored ``[z, y, x]``, is transposed to
  ``[x, y, z]``. Row 0 (the top row as an image viewer shows it) is y = 0 and page 0 is z = 0, with no flip:
  the index-order convention of the other readers (NRRD's and NIfTI's index ``i, j, k`` = ``x, y, z``), so
  a stack exported from ImageJ or Fiji and the same data saved as NRRD load identically.
- **Spacing.** From OME-XML metadata (``Pixels`` ``PhysicalSizeX/Y/Z``; a missing one is 1), else ImageJ
  metadata (x and y from the ``XResolution`` / ``YResolution`` tags, which are pixels per unit, z from the
  ``spacing`` entry, 1 when absent as ImageJ assumes), else none (the caller's default, ``(1, 1, 1)``). A
  folder takes the first slice's metadata. Units are not converted: they must agree across axes. A ``spacing``
  given by the user overrides all of this (the dispatcher does that).
- **Shapes.** Singleton axes are dropped; what remains must be one stack axis (Z, or tifffile's generic I, Q
  or T) over Y and X. Several channels or samples (RGB) are refused, as are a single 2-D image (give the
  folder, or a multi-page file) and a folder of one slice. All slices of a folder must have one size and type.
- **Memory.** An uncompressed contiguous multi-page file is memory-mapped (``tifffile.memmap``); otherwise
  the stack is decoded into one array of the file's type. A folder is read slice by slice into one array.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.readers.params import ReadResult, Spacing, spacing_or_none

TIFF_SUFFIXES = (".tif", ".tiff")
#: The one line a user without tifffile sees.
MISSING_TIFFFILE = "reading TIFF needs the optional package tifffile: pip install 'photon-fields[formats]'"


def _tifffile(what: str) -> Any:
    try:
        import tifffile  # imported lazily: an optional dependency, only needed for TIFF input
    except ImportError:
        raise InputError(what, MISSING_TIFFFILE) from None
    return tifffile


def natural_key(name: str) -> list[Any]:
    """Sort key that orders the digit runs of a name by value: ``slice_2`` before ``slice_10``."""
    return [int(part) if i % 2 else part.lower() for i, part in enumerate(re.split(r"(\d+)", name))]


def _inverse_resolution(tag: Any) -> float | None:
    """Pixel size from an X/YResolution tag (a rational, pixels per unit), or None."""
    try:
        num, den = tag.value
        return float(den) / float(num) if num else None
    except (AttributeError, TypeError, ValueError):
        return None


def file_spacing(tif: Any) -> Spacing | None:
    """Voxel size from a TiffFile's OME or ImageJ metadata (see the module docstring), or None."""
    if tif.is_ome and tif.ome_metadata:
        try:
            root = ET.fromstring(tif.ome_metadata)
        except ET.ParseError:
            root = None
        pixels = None if root is None else next((e for e in root.iter() if e.tag.split("}")[-1] == "Pixels"), None)
        if pixels is not None:
            sizes = [pixels.get(f"PhysicalSize{axis}") for axis in "XYZ"]
            if any(v is not None for v in sizes):
                return spacing_or_none([v if v is not None else 1.0 for v in sizes])
    if tif.is_imagej and tif.imagej_metadata is not None:
        tags = tif.pages[0].tags
        sx = _inverse_resolution(tags.get("XResolution"))
        sy = _inverse_resolution(tags.get("YResolution"))
        sz = tif.imagej_metadata.get("spacing", 1.0)
        return spacing_or_none([sx or 1.0, sy or 1.0, sz])
    return None


def _stack_shape(shape: tuple[int, ...], axes: str, what: str, label: str) -> tuple[int, ...]:
    """The shape without singleton axes: ``(ny, nx)`` or ``(nz, ny, nx)``; anything else is refused."""
    kept = [(a, n) for a, n in zip(axes, shape, strict=True) if n > 1 or a in "YX"]
    for a, n in kept:
        if a in "CS":
            kind = "samples per pixel (RGB?)" if a == "S" else "channels"
            raise InputError(what, f"{label} has {n} {kind}; only single-channel greyscale stacks are read "
                             "(split the channels, e.g. in Fiji, and load one)")
    if [a for a, _n in kept][-2:] != ["Y", "X"]:
        raise InputError(what, f"{label} has axes {axes!r} of shape {tuple(shape)}; expected greyscale "
                         "images (rows Y, columns X)")
    extra = kept[:-2]
    if len(extra) > 1:
        raise InputError(what, f"{label} has axes {axes!r} of shape {tuple(shape)}; expected one stack of "
                         "2-D images (pages = z)")
    return tuple(n for _a, n in kept)


def read_tiff_file(path: Path, what: str) -> ReadResult:
    """A multi-page TIFF: pages = z."""
    tifffile = _tifffile(what)
    with tifffile.TiffFile(path) as tif:
        if not tif.series:
            raise InputError(what, "TIFF file holds no images (empty or corrupt)")
        series = tif.series[0]
        shape = _stack_shape(tuple(series.shape), series.axes, what, "TIFF")
        if len(shape) == 2:
            raise InputError(what, "is a single 2-D image; a volume needs a multi-page TIFF or a folder of slices "
                             "(give the folder)")
        spacing = file_spacing(tif)
    try:
        arr = tifffile.memmap(path, mode="r", series=0)
    except ValueError:  # compressed or scattered pages: decode instead
        with tifffile.TiffFile(path) as tif:
            arr = tif.series[0].asarray()
    return arr.reshape(shape).transpose(2, 1, 0), spacing, None


def slice_files(folder: Path) -> list[Path]:
    """The folder's ``.tif`` / ``.tiff`` files (hidden ones skipped), in natural name order."""
    files = [p for p in folder.iterdir()
             if p.suffix.lower() in TIFF_SUFFIXES and not p.name.startswith(".") and p.is_file()]
    return sorted(files, key=lambda p: natural_key(p.name))


def read_tiff_folder(folder: Path, what: str) -> ReadResult:
    """A folder of 2-D slices: slice k (in natural name order) = z = k."""
    tifffile = _tifffile(what)
    files = slice_files(folder)
    if not files:
        raise InputError(what, "folder has no .tif/.tiff slices (nor DICOM files, nor Zarr metadata; subfolders "
                         "are not searched: give the folder of the series itself)")
    if len(files) == 1:
        raise InputError(what, f"folder has one slice ({files[0].name}); a volume needs at least two")
    out: np.ndarray | None = None
    spacing = None
    for k, file in enumerate(files):
        try:
            with tifffile.TiffFile(file) as tif:
                if not tif.series:
                    raise InputError(what, f"slice {file.name} holds no image")
                series = tif.series[0]
                shape = _stack_shape(tuple(series.shape), series.axes, what, f"slice {file.name}")
                if len(shape) != 2:
                    raise InputError(what, f"slice {file.name} is a stack of shape {tuple(series.shape)}, not "
                                     "a 2-D image")
                if k == 0:
                    spacing = file_spacing(tif)
                image = series.asarray().reshape(shape)
        except InputError:
            raise
        except Exception as err:  # a corrupt slice: name it
            raise InputError(what, f"cannot read slice {file.name}: {type(err).__name__}: {err}") from err
        if out is None:
            out = np.empty((len(files), *shape), dtype=image.dtype)
        elif image.shape != out.shape[1:] or image.dtype != out.dtype:
            ref = f"{out.shape[2]}x{out.shape[1]} {out.dtype}"
            raise InputError(what, f"slice {file.name} is {shape[1]}x{shape[0]} {image.dtype} but {files[0].name} "
                             f"is {ref}; all slices must have the same size and type")
        out[k] = image
    assert out is not None
    return out.transpose(2, 1, 0), spacing, None
