"""NIfTI reader (``.nii`` / ``.nii.gz``) via nibabel: arrays ``[i, j, k]`` = ``[x, y, z]``, spacing from
``get_zooms()[:3]``; a 4-D file with one volume is squeezed. Uncompressed files are memory-mapped by nibabel."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.readers.params import ReadResult, fmt, spacing_or_none


def read_nifti(path: Path, what: str, spacing_given: bool) -> ReadResult:
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
    file_spacing = spacing_or_none(zooms)
    if file_spacing is None and not spacing_given:
        raise InputError(
            what, f"NIfTI voxel sizes {fmt(list(zooms))} are not positive; pass spacing=(sx, sy, sz)"
        )
    return arr, file_spacing, None
