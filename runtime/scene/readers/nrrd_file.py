"""NRRD reader (``.nrrd`` / ``.nhdr``) via pynrrd, read with ``index_order='F'`` (first NRRD axis = x); the
spacing is ``spacings`` or the norms of ``space directions`` (directions and origin are ignored)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.readers.params import ReadResult, spacing_or_none


def read_nrrd(path: Path, what: str, spacing_given: bool) -> ReadResult:
    import nrrd  # imported lazily: only needed for NRRD input

    data, header = nrrd.read(str(path), index_order="F")
    if data.ndim != 3:
        raise InputError(what, f"expected a 3-D scalar grid, got shape {tuple(data.shape)}")
    file_spacing = None
    if header.get("spacings") is not None:
        file_spacing = spacing_or_none(header["spacings"])
    if file_spacing is None and header.get("space directions") is not None:
        dirs = np.asarray(header["space directions"], dtype=np.float64)
        if dirs.ndim == 2 and dirs.shape[0] == 3:
            file_spacing = spacing_or_none(np.linalg.norm(dirs, axis=1))
    has_spacing = header.get("spacings") is not None or header.get("space directions") is not None
    if file_spacing is None and has_spacing and not spacing_given:
        raise InputError(
            what, "NRRD header has no valid voxel spacing for the 3 axes; pass spacing=(sx, sy, sz)"
        )
    return data, file_spacing, None
