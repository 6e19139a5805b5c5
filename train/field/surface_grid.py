"""The surface input's grid for a scene's medium (:mod:`photon_fields.models_spec.surface` defines it).

The grid's cells hold the mean extinction of the voxels whose centres fall in them (one voxel per cell up to
:data:`photon_fields.models_spec.surface.SURFACE_MAX_CELLS` a side), read one slab of voxels at a time so that a
large scan never needs a float64 copy of itself; :func:`photon_fields.models_spec.surface.surface_grid` turns the
means into the stored int8 grid. Training computes it from the medium it fits; the bundle carries it to the runtime.
"""

from __future__ import annotations

import numpy as np

from photon_fields.models_spec.surface import surface_cells, surface_grid, voxel_cells
from photon_fields.runtime.transport.medium import Medium, voxel_extinction


def cell_extinction(m: Medium) -> np.ndarray:
    """The mean sigma_t of each cell's voxels, float64 (sx, sy, sz) for :func:`surface_cells` of the volume."""
    shape = m.density.shape
    cells = surface_cells(shape)
    owners = [voxel_cells(n, c) for n, c in zip(shape, cells, strict=True)]
    starts = [np.searchsorted(o, np.arange(c)) for o, c in zip(owners, cells, strict=True)]
    counts = [np.bincount(o, minlength=c).astype(np.float64) for o, c in zip(owners, cells, strict=True)]
    out = np.empty(cells)
    bounds = list(starts[0]) + [shape[0]]
    for i in range(cells[0]):
        plane = voxel_extinction(m, int(bounds[i]), int(bounds[i + 1])).sum(axis=0)
        rows = np.add.reduceat(plane, starts[1], axis=0)
        out[i] = np.add.reduceat(rows, starts[2], axis=1)
    return out / (counts[0][:, None, None] * counts[1][None, :, None] * counts[2][None, None, :])


def medium_surface_grid(m: Medium) -> np.ndarray:
    """The stored surface grid (int8 (sx, sy, sz, 3)) of medium ``m``."""
    return surface_grid(cell_extinction(m), m.bsize)
