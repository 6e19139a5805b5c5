"""Zarr arrays and OME-Zarr images via ``zarr`` (the optional extra ``formats``): a folder (usually named
``*.zarr``) that is a Zarr array, a Zarr group holding one array, or an OME-Zarr image (a group with
``multiscales`` metadata).

Specifications: Zarr v2 (https://zarr-specs.readthedocs.io/en/latest/v2/v2.0.html: ``.zarray`` / ``.zgroup`` /
``.zattrs``) and v3 (https://zarr-specs.readthedocs.io/en/latest/v3/core/index.html: ``zarr.json``), both read
by zarr-python 3 (zarr-python 2.18 reads v2 stores only); OME-NGFF 0.4 (https://ngff.openmicroscopy.org/0.4/:
``multiscales`` in the group attributes of a Zarr v2 store) and 0.5 (https://ngff.openmicroscopy.org/0.5/: the
same under ``attributes.ome`` of a Zarr v3 group); 0.1 - 0.3 files (no ``axes``, or axes as bare names) too.

- **What is read.** An OME-Zarr image: ``multiscales[0]`` (the first, as the spec's default), level
  ``level`` of its ``datasets`` (0 = full resolution, the spec orders datasets from highest to lowest
  resolution), i.e. the array at ``datasets[level].path``. Only that array is opened and read: the other
  levels are never touched. A group without ``multiscales`` holding exactly one array reads that array; with
  several arrays, or none (only subgroups, e.g. a ``bioformats2raw`` layout with images ``0``, ``1``, ...),
  it is refused in one line that lists what the group holds, so that the user can give the array's (or the
  image's) folder instead.
- **Axes and orientation.** OME-Zarr ``axes`` name each array dimension, in the spec's order ``(t, c,) z, y, x``
  (the array is C order, x fastest). The three ``space`` axes become our ``[x, y, z]``: by name when they are
  ``x``, ``y`` and ``z``, else by position (the last is x, then y, then z), i.e. the stored ``[z, y, x]`` is
  transposed. Other axes (``time``, ``channel``, custom) must have size 1 and are dropped (index 0); a time
  series or several channels are refused, naming the axis, since which channel to render is the user's
  choice (extract it first). Before 0.3 the axes were implicitly ``t, c, z, y, x``. A plain array (no
  OME metadata) uses its dimension names when they name x, y and z (Zarr v3 ``dimension_names``, or
  xarray's ``_ARRAY_DIMENSIONS`` attribute in v2); unnamed, its singleton dimensions are dropped and the
  remaining three are taken as ``[z, y, x]`` (C order with x fastest: the OME-Zarr, napari and dask
  convention), and transposed the same way. Write ``dimension_names=("x", "y", "z")`` for an ``[x, y, z]``
  array.
- **Spacing.** OME-Zarr: the ``scale`` of the level's ``coordinateTransformations`` (times the multiscale's
  own ``scale``, when it has one) for the three space axes; translations are ignored as the other readers
  ignore origins. When the space axes have different ``unit`` values they are converted to one length
  unit (micrometer and friends: the NGFF unit list); one unknown unit among different ones is refused. A
  plain array has no spacing (the caller's default, ``(1, 1, 1)``). A ``spacing`` given by the user
  overrides all of this, and then bad scale metadata is not an error.
- **Memory.** Zarr chunks are compressed, so nothing is memory-mapped: the chosen level is decoded into one
  array of its own type (the dispatcher then normalizes it to float32). Chunks absent from the store read
  as the array's fill value, as the spec says.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.readers.params import ReadResult, Spacing, fmt

#: The one line a user without zarr sees.
MISSING_ZARR = "reading Zarr needs the optional package zarr: pip install 'photon-fields[formats]'"
#: Files whose presence makes a folder a Zarr array or group (v2: .zarray / .zgroup, v3: zarr.json).
ZARR_MARKERS = (".zarray", ".zgroup", "zarr.json")
#: Axes of OME-NGFF 0.1 / 0.2, which had no ``axes`` metadata: always 5-D t, c, z, y, x.
_IMPLICIT_AXES = ("t", "c", "z", "y", "x")
_TYPE_OF_NAME = {"x": "space", "y": "space", "z": "space", "t": "time", "c": "channel"}
#: Length units of the NGFF spec (UDUNITS-2 names), in meters, to convert axes of different units.
_LENGTH_UNITS = {
    "angstrom": 1e-10, "attometer": 1e-18, "centimeter": 1e-2, "decimeter": 1e-1, "exameter": 1e18,
    "femtometer": 1e-15, "foot": 0.3048, "gigameter": 1e9, "hectometer": 1e2, "inch": 0.0254, "kilometer": 1e3,
    "megameter": 1e6, "meter": 1.0, "micrometer": 1e-6, "mile": 1609.344, "millimeter": 1e-3, "nanometer": 1e-9,
    "parsec": 3.0856775814913673e16, "petameter": 1e15, "picometer": 1e-12, "terameter": 1e12, "yard": 0.9144,
    "yoctometer": 1e-24, "yottameter": 1e24, "zeptometer": 1e-21, "zettameter": 1e21,
}  # fmt: skip


def _zarr(what: str) -> Any:
    try:
        import zarr  # imported lazily: an optional dependency, only needed for Zarr input
    except ImportError:
        raise InputError(what, MISSING_ZARR) from None
    return zarr


def is_zarr_folder(folder: Path) -> bool:
    """True when ``folder`` is named ``*.zarr`` or holds Zarr metadata (``.zarray``, ``.zgroup``, ``zarr.json``)."""
    return folder.suffix.lower() == ".zarr" or any((folder / m).is_file() for m in ZARR_MARKERS)


def read_zarr(path: Path, what: str, level: int | None, spacing_given: bool) -> ReadResult:
    """The reader interface of :mod:`photon_fields.runtime.scene.volume_io`: the array of ``path`` (level
    ``level`` of an OME-Zarr image, default 0) indexed ``[x, y, z]``, with the OME-Zarr spacing."""
    zarr = _zarr(what)
    if not path.is_dir():
        raise InputError(what, "is a file; a Zarr store is a folder (zipped stores are not read: unzip it)")
    try:
        node = zarr.open(store=str(path), mode="r")
    except Exception as err:  # no metadata, or metadata that is not valid JSON / not Zarr
        raise InputError(what, f"not a readable Zarr array or group (no valid .zarray, .zgroup or zarr.json "
                         f"metadata): {type(err).__name__}: {err}") from None
    if isinstance(node, zarr.Array):
        if level:
            raise InputError(what, f"level {level} applies to OME-Zarr multiscale images; this is a plain Zarr "
                             "array (one level)")
        return _read_plain(node, what, "Zarr array")
    multiscales = _multiscales(dict(node.attrs))
    if multiscales is None:
        if level:
            raise InputError(what, f"level {level} applies to OME-Zarr multiscale images; this Zarr group has no "
                             "multiscales metadata")
        arrays = sorted(node.array_keys())
        if len(arrays) == 1:
            return _read_plain(node[arrays[0]], what, f"Zarr array {arrays[0]!r}")
        groups = sorted(node.group_keys())
        if not arrays:
            inside = f"only subgroups ({_names(groups)}; give one of their folders, e.g. {path.name}/{groups[0]})" \
                if groups else "nothing"
            raise InputError(what, f"Zarr group without arrays and without OME-Zarr multiscales metadata: it holds "
                             f"{inside}")
        raise InputError(what, f"Zarr group holds {len(arrays)} arrays ({_names(arrays)}) and no OME-Zarr "
                         f"multiscales metadata; give the folder of the one to read, e.g. {path.name}/{arrays[0]}")
    return _read_ome(node, multiscales, what, level or 0, spacing_given, zarr)


def _names(names: Sequence[str], most: int = 8) -> str:
    shown = ", ".join(names[:most])
    return shown + (f", ... ({len(names)} in all)" if len(names) > most else "")


# ----------------------------------------------------------------------------------------------------------
# Plain arrays


def _dimension_names(arr: Any) -> list[str] | None:
    """Zarr v3 ``dimension_names`` or xarray's v2 ``_ARRAY_DIMENSIONS``, lower case, when every dimension has
    one; else None."""
    names = getattr(getattr(arr, "metadata", None), "dimension_names", None)
    if names is None:
        names = dict(arr.attrs).get("_ARRAY_DIMENSIONS")
    if not isinstance(names, (list, tuple)) or len(names) != arr.ndim or not all(isinstance(n, str) for n in names):
        return None
    return [n.lower() for n in names]


def _read_plain(arr: Any, what: str, label: str) -> ReadResult:
    names = _dimension_names(arr)
    if names is not None and {"x", "y", "z"} <= set(names):
        axes = [(n, _TYPE_OF_NAME.get(n, "other")) for n in names]
        return _read_axes(arr, axes, what, label), None, None
    shape = tuple(arr.shape)
    kept = [i for i, n in enumerate(shape) if n > 1]
    if len(kept) != 3:
        raise InputError(what, f"{label} has shape {shape}; expected three non-singleton dimensions "
                         "(z, y, x), or dimension names x, y and z")
    index = tuple(slice(None) if n > 1 else 0 for n in shape)
    data = _decode(arr, index, what, label)
    return data.transpose(2, 1, 0), None, None


# ----------------------------------------------------------------------------------------------------------
# OME-Zarr


def _multiscales(attrs: dict[str, Any]) -> Any:
    """``multiscales`` of an OME-NGFF 0.5 group (under ``ome``) or of 0.1 - 0.4 (top level), else None."""
    ome = attrs.get("ome")
    if isinstance(ome, dict) and "multiscales" in ome:
        return ome["multiscales"]
    return attrs.get("multiscales")


def _scale(transforms: Any, ndim: int, what: str, where: str) -> list[float] | None:
    """The ``scale`` vector of a ``coordinateTransformations`` list, or None when there is none."""
    if transforms is None:
        return None
    if not isinstance(transforms, list):
        raise InputError(what, f"OME-Zarr {where} coordinateTransformations must be a list, got {fmt(transforms)}")
    for t in transforms:
        if isinstance(t, dict) and t.get("type") == "scale" and "scale" in t:
            s = t["scale"]
            try:
                values = [float(v) for v in s]
            except (TypeError, ValueError):
                values = []
            if len(values) != ndim:
                raise InputError(what, f"OME-Zarr {where} scale must be {ndim} numbers (one per axis), got {fmt(s)}")
            return values
    return None


def _read_ome(group: Any, multiscales: Any, what: str, level: int, spacing_given: bool, zarr: Any) -> ReadResult:
    if not isinstance(multiscales, list) or not multiscales or not isinstance(multiscales[0], dict):
        raise InputError(what, f"OME-Zarr multiscales metadata must be a non-empty list of objects, got "
                         f"{fmt(multiscales)}")
    ms = multiscales[0]
    datasets = ms.get("datasets")
    if not isinstance(datasets, list) or not datasets or not all(isinstance(d, dict) for d in datasets):
        raise InputError(what, "OME-Zarr multiscales has no datasets (resolution levels)")
    if level >= len(datasets):
        raise InputError(what, f"level {level} does not exist: this OME-Zarr image has {len(datasets)} resolution "
                         f"level{'s' if len(datasets) > 1 else ''} (0 .. {len(datasets) - 1}, 0 = full resolution)")
    sub = datasets[level].get("path")
    label = f"OME-Zarr level {level} (array {sub!r})"
    try:
        arr = group[str(sub)]
    except Exception:  # KeyError, or a store error for a missing path
        arr = None
    if not isinstance(arr, zarr.Array):
        raise InputError(what, f"{label}: no such array in the store (multiscales datasets[{level}].path)")
    axes = _ome_axes(ms.get("axes"), arr.ndim, what)
    data = _read_axes(arr, axes, what, label)
    spacing = _ome_spacing(ms, datasets[level], axes, what, level) if not spacing_given else None
    return data, spacing, None


def _ome_axes(raw: Any, ndim: int, what: str) -> list[tuple[str, str]]:
    """``(name, type)`` per array dimension from the ``axes`` metadata (objects in 0.4+, names in 0.3, absent
    before: t, c, z, y, x)."""
    if raw is None:
        raw = list(_IMPLICIT_AXES[-ndim:]) if ndim <= 5 else None
    if not isinstance(raw, list) or len(raw) != ndim:
        raise InputError(what, f"OME-Zarr axes {fmt(raw)} do not match the array's {ndim} dimensions")
    axes = []
    for ax in raw:
        name = ax.get("name") if isinstance(ax, dict) else ax
        if not isinstance(name, str):
            raise InputError(what, f"OME-Zarr axis {fmt(ax)} has no name")
        kind = ax.get("type") if isinstance(ax, dict) else None
        axes.append((name, str(kind) if kind is not None else _TYPE_OF_NAME.get(name.lower(), "other")))
    return axes


def _space_order(axes: list[tuple[str, str]], what: str, label: str) -> list[int]:
    """Dimension indices of x, y, z: by name when the space axes are x, y, z, else the last space axis is x."""
    space = [i for i, (_n, t) in enumerate(axes) if t == "space"]
    names = [n.lower() for n, _t in axes]
    if len(space) != 3:
        shown = ", ".join(f"{n} ({t})" for n, t in axes)
        raise InputError(what, f"{label} has {len(space)} space axes ({shown}); a volume needs 3 (z, y, x)")
    if sorted(names[i] for i in space) == ["x", "y", "z"]:
        return [names.index(a) for a in "xyz"]
    return space[::-1]


def _read_axes(arr: Any, axes: list[tuple[str, str]], what: str, label: str) -> np.ndarray:
    """Read ``arr`` with named axes: other than the three space axes, each must have size 1 (index 0)."""
    shape = tuple(arr.shape)
    order = _space_order(axes, what, label)
    for i, (name, kind) in enumerate(axes):
        if i not in order and shape[i] > 1:
            one = {"channel": "channel", "time": "time point"}.get(kind, f"index of axis {name!r}")
            raise InputError(what, f"{label} has {shape[i]} {one}s (axis {name!r} of shape {shape}); only a single "
                             f"3-D volume is read: extract one {one} first")
    index = tuple(slice(None) if i in order else 0 for i in range(len(shape)))
    data = _decode(arr, index, what, label)
    kept = [i for i in range(len(shape)) if i in order]  # the remaining dimensions, in stored order
    return data.transpose([kept.index(i) for i in order])


def _decode(arr: Any, index: tuple[Any, ...], what: str, label: str) -> np.ndarray:
    """Decode the selection: a corrupt or truncated chunk is one line naming the array."""
    try:
        return np.asarray(arr[index])
    except MemoryError:
        raise
    except Exception as err:
        raise InputError(what, f"{label}: cannot decode its chunks (corrupt or truncated store?): "
                         f"{type(err).__name__}: {err}") from None


def _ome_spacing(ms: dict[str, Any], dataset: dict[str, Any], axes: list[tuple[str, str]], what: str,
                 level: int) -> Spacing | None:
    """x, y, z voxel size from the level's scale (times the multiscale's), in one length unit."""
    ndim = len(axes)
    scale = _scale(dataset.get("coordinateTransformations"), ndim, what, f"datasets[{level}]")
    outer = _scale(ms.get("coordinateTransformations"), ndim, what, "multiscales")
    if scale is None and outer is None:
        return None
    values = [a * b for a, b in zip(scale or [1.0] * ndim, outer or [1.0] * ndim, strict=True)]
    order = _space_order(axes, what, "OME-Zarr image")
    raw_units = ms.get("axes") if isinstance(ms.get("axes"), list) else []
    units = [ax.get("unit") if isinstance(ax, dict) else None for ax in raw_units] or [None] * ndim
    space_units = {units[i] for i in order}
    sizes = [values[i] for i in order]
    if len(space_units) > 1:
        unknown = [u for u in space_units if u not in _LENGTH_UNITS]
        if unknown:
            raise InputError(what, f"OME-Zarr space axes have different units ({', '.join(map(str, space_units))}) "
                             "that cannot be converted; pass spacing=(sx, sy, sz)")
        to_x_unit = [_LENGTH_UNITS[units[i]] / _LENGTH_UNITS[units[order[0]]] for i in order]
        sizes = [s * f for s, f in zip(sizes, to_x_unit, strict=True)]
    if not all(math.isfinite(s) and s > 0 for s in sizes):
        raise InputError(what, f"OME-Zarr scale {fmt(values)} gives voxel sizes that are not positive; pass "
                         "spacing=(sx, sy, sz)")
    return sizes[0], sizes[1], sizes[2]
