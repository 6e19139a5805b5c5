"""Cell-centred grids over the medium's world box, and their trilinear lookups.

Several renderers cache a quantity on a grid of cells over the volume's box and interpolate it at camera samples:
PVRT's radiance, light and optical-depth volumes (``runtime/pvrt/``) and the ray marcher's light volume
(:mod:`photon_fields.runtime.transport.light_volume`). Cell (i, j, k) of a (gx, gy, gz) grid is centred at
``bmin + (i + 0.5, j + 0.5, k + 0.5) * bsize / (gx, gy, gz)``; with the volume's own shape its centres are the voxel
centres. A lookup clamps at the border (the outer half cell takes the border cell's value).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from photon_fields.runtime.transport.medium import Medium

#: A cell-centred grid over the world box, for the kernels below: its origin (xyz), cells per unit length (xyz) and
#: cells (xyz). Plain numbers: an inlined kernel that was handed the medium and looped took and released a reference
#: to each of its 7 arrays per call (numba's pruning of reference counts missed them), a third of the time of
#: summing a sample; numbers carry no reference.
Grid = tuple[float, float, float, float, float, float, int, int, int]


@njit(cache=True, inline="always")
def grid_coord(p: float, lo: float, scale: float, n: int) -> tuple[int, float]:
    """Lower index and fraction of the trilinear stencil along one axis of a cell-centred grid of ``n`` cells from
    ``lo`` on, ``scale`` cells per unit length (n / the box's size), at coordinate ``p`` (clamped at the border).
    (A multiplication: the camera samples' stencils divided three times each before.)"""
    u = min(max((p - lo) * scale - 0.5, 0.0), n - 1.0)
    i = min(int(u), n - 2)
    return i, u - i


@njit(cache=True, inline="always")
def grid_of(m: Medium, gx: int, gy: int, gz: int) -> Grid:
    """The (gx, gy, gz) grid over ``m``'s box."""
    return m.bmin[0], m.bmin[1], m.bmin[2], gx / m.bsize[0], gy / m.bsize[1], gz / m.bsize[2], gx, gy, gz


@njit(cache=True, inline="always")
def stencil(grid: Grid, x: float, y: float, z: float) -> tuple[int, int, int, float, float, float]:
    """Lower corner and fractions of the trilinear stencil of ``grid`` at x (:func:`grid_coord`)."""
    i, fx = grid_coord(x, grid[0], grid[3], grid[6])
    j, fy = grid_coord(y, grid[1], grid[4], grid[7])
    k, fz = grid_coord(z, grid[2], grid[5], grid[8])
    return i, j, k, fx, fy, fz


@njit(cache=True, inline="always")
def cell_centre(grid: Grid, i: int, j: int, k: int) -> tuple[float, float, float]:
    """World position of cell (i, j, k)'s centre."""
    return grid[0] + (i + 0.5) / grid[3], grid[1] + (j + 0.5) / grid[4], grid[2] + (k + 0.5) / grid[5]


@njit(cache=True, inline="always")
def blend(v000: float, v100: float, v010: float, v110: float, v001: float, v101: float, v011: float, v111: float,
          fx: float, fy: float, fz: float) -> float:
    """The trilinear blend of a stencil's eight corner values (``vijk``: corner (i, j, k) of the stencil) at the
    fractions (fx, fy, fz): x first, then y, then z."""
    c00 = v000 * (1 - fx) + v100 * fx
    c10 = v010 * (1 - fx) + v110 * fx
    c01 = v001 * (1 - fx) + v101 * fx
    c11 = v011 * (1 - fx) + v111 * fx
    return (c00 * (1 - fy) + c10 * fy) * (1 - fz) + (c01 * (1 - fy) + c11 * fy) * fz


@njit(cache=True, inline="always")
def trilinear(vol: np.ndarray, i: int, j: int, k: int, fx: float, fy: float, fz: float) -> float:
    """``vol`` (gx, gy, gz) interpolated at the stencil (i, j, k, fx, fy, fz) of :func:`stencil`."""
    return blend(vol[i, j, k], vol[i + 1, j, k], vol[i, j + 1, k], vol[i + 1, j + 1, k], vol[i, j, k + 1],
                 vol[i + 1, j, k + 1], vol[i, j + 1, k + 1], vol[i + 1, j + 1, k + 1], fx, fy, fz)
