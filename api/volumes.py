"""What ``photon_fields.render`` accepts as a volume, turned into a
:class:`photon_fields.runtime.scene.volume.Volume`: a numpy array indexed ``[x, y, z]``, a path (anything
:func:`photon_fields.runtime.scene.volume_io.load_volume` reads), a ``pyvista.ImageData`` (duck-typed: pyvista is
never imported, nor a dependency) or a ready Volume. Anything else is one line naming ``volume``."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.volume import Volume, make_volume

WHAT = "volume"


def as_volume(volume: Any, spacing: Any = None) -> tuple[Volume, dict[str, Any] | None]:
    """The volume, and the scene-file entry that rebuilds it (None for one made in memory). ``spacing``
    overrides what a file or an ImageData says (the voxel size along x, y, z; only ratios matter)."""
    if isinstance(volume, Volume):
        if spacing is not None:
            raise InputError("spacing", "cannot override the spacing of a ready Volume")
        return volume, None
    if isinstance(volume, (str, os.PathLike)):
        from pathlib import Path

        from photon_fields.runtime.scene.volume_io import load_volume

        path = Path(volume).expanduser()
        options = {} if spacing is None else {"spacing": _spacing(spacing)}
        return load_volume(path, **options), {"path": str(path.absolute()), **options}
    if _is_image_data(volume):
        data, own_spacing = _image_data_array(volume)
        return _from_array(data, spacing if spacing is not None else own_spacing), None
    if isinstance(volume, np.ndarray) or hasattr(volume, "__array__"):
        return _from_array(np.asarray(volume), spacing), None
    raise InputError(WHAT, f"expected a 3-D numpy array, a volume file path or a pyvista.ImageData, got "
                           f"{type(volume).__name__}")


def _spacing(spacing: Any) -> list[float]:
    try:
        values = [float(s) for s in spacing]
    except (TypeError, ValueError):
        raise InputError("spacing", f"must be three positive numbers, got {spacing!r}") from None
    if len(values) != 3 or not all(np.isfinite(v) and v > 0 for v in values):
        raise InputError("spacing", f"must be three positive numbers, got {spacing!r}")
    return values


def _from_array(data: np.ndarray, spacing: Any) -> Volume:
    if data.ndim != 3:
        raise InputError(WHAT, f"must be a 3-D array indexed [x, y, z], got {data.ndim}-D with shape {data.shape}")
    if data.dtype == bool:
        data = data.astype(np.uint8)
    if not np.issubdtype(data.dtype, np.number) or np.issubdtype(data.dtype, np.complexfloating):
        raise InputError(WHAT, f"must hold real numbers, got dtype {data.dtype}")
    return make_volume(data, spacing=_spacing(spacing) if spacing is not None else (1.0, 1.0, 1.0), name=WHAT)


def _is_image_data(obj: Any) -> bool:
    """pyvista.ImageData (and vtk-like look-alikes): grid dimensions, spacing and point or cell data."""
    return all(hasattr(obj, a) for a in ("dimensions", "spacing", "point_data", "cell_data"))


def _image_data_array(grid: Any) -> tuple[np.ndarray, tuple[float, float, float]]:
    """The grid's active scalars (else its first point array, else its first cell array) as an ``[x, y, z]``
    array: VTK stores points x fastest, so a Fortran-order reshape."""
    dims = tuple(int(n) for n in grid.dimensions)
    for arrays, shape in ((grid.point_data, dims), (grid.cell_data, tuple(max(n - 1, 1) for n in dims))):
        names = list(arrays.keys())
        if not names:
            continue
        active = getattr(arrays, "active_scalars_name", None)
        name = active if active in names else names[0]
        values = np.asarray(arrays[name])
        if values.ndim != 1 or values.size != int(np.prod(shape)):
            raise InputError(WHAT, f"ImageData array {name!r} is not one scalar per "
                                   f"{'point' if shape == dims else 'cell'} (shape {values.shape})")
        return values.reshape(shape, order="F"), tuple(float(s) for s in grid.spacing)  # type: ignore[return-value]
    raise InputError(WHAT, "the ImageData has no point or cell data arrays")
