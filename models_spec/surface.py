"""The field's surface input: how the camera ray meets the medium's surface at the query point.

What: two more MLP input columns, ``g s`` and ``g s |s|`` with ``s = d . v(x)``, d the camera ray's unit travel
direction and v(x) the medium's smoothed extinction gradient turned outwards and softly normalized (below): s is
near -1 where the ray enters a surface head on, near +1 where it leaves one, near 0 inside homogeneous medium or
along a surface. Times g like the direction features (:func:`photon_fields.models_spec.encoding.direction_gains`),
so the field stays isotropic at g = 0.

Why: seen from behind a lit object at forward scattering (head at g = 0.6 / 0.75, the camera orbited 180 degrees),
the field was darker than its photon map while the map was right, and no setting of the fit changed that
(bench/README.md, ``bench_fidelity.py``, has the figures). At those points the field had the angular *mean* right
but spread the light from the directions that look into the lit surface, which cameras see, to the others: the
contrast depends on x through the surface's orientation, a product of position and direction that a small bias-free
ReLU MLP fed with separate hash features of x and d approximates poorly. These columns hand it that product.

Definition (training and the runtime evaluate exactly this; the bundle carries the grid, ``tables.npz`` array
``surface``, and its shape in the field config, :attr:`photon_fields.models_spec.encoding.FieldConfig.surface`):

- the grid: cells tiling the volume's box, :func:`surface_cells` (one per voxel up to :data:`SURFACE_MAX_CELLS` a
  side; a larger volume's voxels are shared out to coarser cells by the cell their centre falls in); each cell holds the
  mean extinction sigma_t of its voxels. :func:`surface_grid` smooths it with a Gaussian of :data:`SURFACE_SMOOTHING`
  cells (separable, truncated at :data:`SURFACE_RADIUS` cells, edge cells repeated), takes the gradient by central
  differences (one-sided at the edges) in world units, and stores ``v = -grad / (|grad| + c)``, c the median of
  |grad| over the cells where it is not 0 (a soft normalization: |v| ~ 1 at a surface, ~0 where sigma_t is flat),
  as int8 ``round(127 v)``, shape (sx, sy, sz, 3);
- at a query: u the normalized position (:func:`photon_fields.models_spec.encoding.normalize_position`), v(u)
  trilinear over the cell centres ``(i + 0.5) / s`` (clamped at the grid's edge cells), :func:`surface_columns`.
"""

from __future__ import annotations

import math

import numpy as np

#: MLP input columns of the surface input.
SURFACE_COLUMNS = 2
#: Cells along the grid's longest side at most: a finer volume shares its voxels out to coarser cells.
SURFACE_MAX_CELLS = 128
#: The Gaussian's standard deviation, in cells, before the gradient (a one-voxel shell's two faces become one
#: surface; unsmoothed, each voxel's noise was a surface of its own).
SURFACE_SMOOTHING = 1.0
#: Cells either side where the Gaussian is cut off.
SURFACE_RADIUS = 3
#: The int8 scale of a stored component: v = stored / SURFACE_QUANT.
SURFACE_QUANT = 127.0


def surface_cells(volume_shape: tuple[int, ...]) -> tuple[int, int, int]:
    """The grid's cells along each axis for a volume of this shape: ceil(n / f) with f = ceil(longest side /
    :data:`SURFACE_MAX_CELLS`) (the voxels themselves up to that size)."""
    f = max(1, math.ceil(max(volume_shape) / SURFACE_MAX_CELLS))
    return tuple(max(1, -(-int(n) // f)) for n in volume_shape)  # type: ignore[return-value]


def voxel_cells(n_voxels: int, n_cells: int) -> np.ndarray:
    """For each voxel along an axis of ``n_voxels``, the cell of ``n_cells`` tiling the same extent that its centre
    falls in (int64 (n_voxels,), nondecreasing; every cell gets at least one voxel when n_cells <= n_voxels)."""
    centres = (np.arange(n_voxels, dtype=np.float64) + 0.5) * (n_cells / n_voxels)
    return np.minimum(np.floor(centres).astype(np.int64), n_cells - 1)


def _smooth_axis(a: np.ndarray, axis: int) -> np.ndarray:
    k = np.arange(-SURFACE_RADIUS, SURFACE_RADIUS + 1, dtype=np.float64)
    w = np.exp(-0.5 * (k / SURFACE_SMOOTHING) ** 2)
    w /= w.sum()
    pad = [(0, 0)] * a.ndim
    pad[axis] = (SURFACE_RADIUS, SURFACE_RADIUS)
    p = np.pad(a, pad, mode="edge")
    n = a.shape[axis]
    out = np.zeros_like(a)
    for j, wj in enumerate(w):
        out += wj * np.take(p, np.arange(j, j + n), axis=axis)
    return out


def surface_grid(extinction: np.ndarray, bsize: np.ndarray) -> np.ndarray:
    """The stored grid (int8 (sx, sy, sz, 3), module docstring) from the cells' mean extinction (sx, sy, sz) over a
    box of world size ``bsize`` (3,)."""
    ext = np.asarray(extinction, dtype=np.float64)
    if ext.ndim != 3 or not np.all(np.isfinite(ext)):
        raise ValueError(f"the surface grid needs a finite 3-D extinction grid, got shape {ext.shape}")
    smooth = ext
    for axis in range(3):
        smooth = _smooth_axis(smooth, axis)
    spacing = np.asarray(bsize, dtype=np.float64).reshape(3) / np.asarray(ext.shape, dtype=np.float64)
    grad = np.zeros((3, *ext.shape))
    for axis in range(3):
        if ext.shape[axis] > 1:
            grad[axis] = np.gradient(smooth, spacing[axis], axis=axis)
    mag = np.sqrt((grad * grad).sum(axis=0))
    nonzero = mag[mag > 0.0]
    c = float(np.median(nonzero)) if nonzero.size else 1.0
    v = -grad / (mag + c)
    q = np.clip(np.rint(v * SURFACE_QUANT), -SURFACE_QUANT, SURFACE_QUANT).astype(np.int8)
    return np.ascontiguousarray(np.moveaxis(q, 0, -1))


def check_surface_grid(grid: np.ndarray, cells: tuple[int, int, int]) -> None:
    """Refuse a stored grid that is not int8 (cells..., 3)."""
    if grid.dtype != np.int8 or grid.shape != (*cells, 3):
        raise ValueError(f"the surface grid must be int8 {(*cells, 3)}, got {grid.dtype} {grid.shape}")


def unit_direction(dirs: np.ndarray) -> np.ndarray:
    """The unit vectors (n, 3) float64 of direction inputs (n, 2) (:func:`photon_fields.models_spec.hashgrid.
    direction_to_unit_square`'s inverse, to float32 rounding): what training, which keeps only the inputs, passes
    as d."""
    uv = np.asarray(dirs, dtype=np.float64)
    theta = uv[:, 0] * np.pi
    phi = uv[:, 1] * (2.0 * np.pi) - np.pi
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=1)


def surface_vectors(grid: np.ndarray, u: np.ndarray) -> np.ndarray:
    """v(u) (n, 3) float64: the grid trilinear at normalized positions u (n, 3) (module docstring)."""
    uu = np.asarray(u, dtype=np.float32).astype(np.float64)
    n = uu.shape[0]
    cells = np.asarray(grid.shape[:3])
    t = np.clip(uu * cells - 0.5, 0.0, cells - 1.0)
    i0 = np.minimum(np.floor(t).astype(np.int64), np.maximum(cells - 2, 0))
    f = t - i0
    i1 = np.minimum(i0 + 1, cells - 1)
    out = np.zeros((n, 3))
    for c in range(8):
        ix = i1[:, 0] if c & 1 else i0[:, 0]
        iy = i1[:, 1] if c & 2 else i0[:, 1]
        iz = i1[:, 2] if c & 4 else i0[:, 2]
        wx = f[:, 0] if c & 1 else 1.0 - f[:, 0]
        wy = f[:, 1] if c & 2 else 1.0 - f[:, 1]
        wz = f[:, 2] if c & 4 else 1.0 - f[:, 2]
        out += (wx * wy * wz)[:, None] * grid[ix, iy, iz].astype(np.float64)
    return out / SURFACE_QUANT


def surface_columns(grid: np.ndarray, u: np.ndarray, d: np.ndarray, g: np.ndarray) -> np.ndarray:
    """The surface input (n, :data:`SURFACE_COLUMNS`) float32 at normalized positions u (n, 3), unit travel
    directions d (n, 3) and phase coefficients g (n,): ``[g s, g s |s|]`` with s = d . v(u) (float64, one rounding)."""
    v = surface_vectors(grid, u)
    dd = np.asarray(d, dtype=np.float64)
    s = dd[:, 0] * v[:, 0] + dd[:, 1] * v[:, 1] + dd[:, 2] * v[:, 2]
    gg = np.asarray(g, dtype=np.float32).astype(np.float64).reshape(-1)
    return np.stack([gg * s, gg * s * np.abs(s)], axis=1).astype(np.float32)
