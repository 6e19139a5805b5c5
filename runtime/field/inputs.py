"""The MLP input's columns besides the hash encodings, as numba loops (paper Sec. 3.1, Fig. 5).

:class:`photon_fields.runtime.field.field.PhotonField` builds each chunk's input rows ``[hash(x), hash(d) * gain,
phase features]`` (:mod:`photon_fields.models_spec.encoding` defines them). The hash encodings were numba kernels
already; the position's normalization, the direction features times g and the phase features were numpy expressions
over the chunk, each allocating temporaries: ~12-15 ms per 512x512 frame's 262k queries on one core, here ~5 ms
(bench/README.md, "The field's inputs in numba"):

- :func:`normalized_positions`: ``(x - bmin) / bsize`` in float64, one rounding to float32: the same IEEE
  operations in the same order as :func:`photon_fields.models_spec.encoding.normalize_position`, so bit for bit the
  same (tested);
- :func:`finish_rows`: the direction columns times each query's g and the phase columns set, in one pass over the
  rows. With one g for the whole chunk (a rendered frame) the phase features are one row, computed by
  ``phase_features`` itself and copied into every row; with per-query g the caller passes the full matrix;
- :func:`surface_rows`: the surface input's two columns (:mod:`photon_fields.models_spec.surface`), bit for bit
  those of ``surface_columns`` (tested), from the query's own direction.

Serial on purpose: a chunk is 16k queries, and waking numba's threads for three short parallel regions per chunk cost
more than they saved (a parallel version measured slower in the renderer). The direction's spherical coordinates stay
numpy's (``direction_input``): its vectorized arccos and atan2 beat a scalar loop over the C library's 2x.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from photon_fields.models_spec.encoding import box_arguments
from photon_fields.models_spec.surface import SURFACE_QUANT
from photon_fields.runtime.numba_inlining import install

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

#: Rows of the surface input per parallel task.
_SURFACE_BLOCK = 1024


@njit(cache=True)
def _normalize_kernel(x: np.ndarray, lo: np.ndarray, size: np.ndarray, out: np.ndarray) -> None:
    for i in range(x.shape[0]):
        for a in range(3):
            out[i, a] = np.float32((x[i, a] - lo[a]) / size[a])


def normalized_positions(x_world: np.ndarray, bmin: np.ndarray, bsize: np.ndarray) -> np.ndarray:
    """World positions (n, 3) -> float32 (n, 3), equal to ``normalize_position(x_world, bmin, bsize)``."""
    x, lo, size = box_arguments(x_world, bmin, bsize)
    out = np.empty((x.shape[0], 3), np.float32)
    _normalize_kernel(x, lo, size, out)  # any strides: the renderers pass (3, n) arrays transposed
    return out


@njit(cache=True)
def _finish_kernel(buf: np.ndarray, dir_col: int, phase_col: int, gains: np.ndarray, phase: np.ndarray) -> None:
    # gains: (0,) none, (1,) one for all rows, (n,) per row; phase: (0, P) none, (1, P) one row for all, or (n, P).
    n = buf.shape[0]
    row_step = 1 if phase.shape[0] == n and n > 1 else 0
    gain_step = 1 if gains.shape[0] > 1 else 0
    for i in range(n):
        if gains.shape[0] > 0:
            gi = gains[i * gain_step]
            for c in range(dir_col, phase_col):
                buf[i, c] *= gi
        if phase.shape[0] > 0:
            r = i * row_step
            for c in range(phase.shape[1]):
                buf[i, phase_col + c] = phase[r, c]


def finish_rows(buf: np.ndarray, dir_col: int, phase_col: int, gains: np.ndarray | None,
                phase: np.ndarray | None, phase_stop: int | None = None) -> None:
    """Multiply ``buf[:, dir_col:phase_col]`` by ``gains`` (None: unchanged; (1,) or (n,) float32) and set
    ``buf[:, phase_col:phase_stop]`` (``phase_stop`` None: to the last column) to ``phase`` ((1, P): the same row
    everywhere; or (n, P); None: left as they are, for a reused buffer that holds them already), in place."""
    g = np.zeros(0, np.float32) if gains is None else np.ascontiguousarray(gains, dtype=np.float32).reshape(-1)
    if phase is None and g.shape[0] == 0:
        return
    width = (buf.shape[1] if phase_stop is None else int(phase_stop)) - phase_col
    p = np.zeros((0, width), np.float32) if phase is None else np.ascontiguousarray(phase, dtype=np.float32)
    n = buf.shape[0]
    if g.shape[0] not in (0, 1, n) or p.ndim != 2 or p.shape[0] not in (0, 1, n) or \
            p.shape[1] != width or (p.shape[0] == 0 and phase is not None):
        raise ValueError(f"gains {g.shape} / phase {p.shape} do not fit {n} rows of {width} phase columns")
    _finish_kernel(buf, int(dir_col), int(phase_col), g, p)


@njit(cache=True, inline="always")
def _corner(grid: np.ndarray, w: float, i: int, j: int, k: int, v0: float, v1: float,
            v2: float) -> tuple[float, float, float]:
    return (v0 + w * np.float64(grid[i, j, k, 0]), v1 + w * np.float64(grid[i, j, k, 1]),
            v2 + w * np.float64(grid[i, j, k, 2]))


@njit(cache=True, parallel=True)
def _surface_kernel(buf: np.ndarray, col: int, u: np.ndarray, d: np.ndarray, g: np.ndarray, grid: np.ndarray,
                    quant: float) -> None:
    # The operations and their order of models_spec.surface.surface_vectors / surface_columns, row by row: the
    # corners in the order c = 0..7 (bit 0 x, bit 1 y, bit 2 z), each weight (wx wy) wz. Blocks of rows in
    # parallel: ~25 ns a row on one core, enough work per chunk for one parallel region.
    sx, sy, sz = grid.shape[0], grid.shape[1], grid.shape[2]
    g_step = 1 if g.shape[0] > 1 else 0
    n = buf.shape[0]
    for b in prange((n + _SURFACE_BLOCK - 1) // _SURFACE_BLOCK):
        for i in range(b * _SURFACE_BLOCK, min(n, (b + 1) * _SURFACE_BLOCK)):
            tx = min(max(np.float64(u[i, 0]) * sx - 0.5, 0.0), sx - 1.0)
            ty = min(max(np.float64(u[i, 1]) * sy - 0.5, 0.0), sy - 1.0)
            tz = min(max(np.float64(u[i, 2]) * sz - 0.5, 0.0), sz - 1.0)
            # t >= 0 after the clamp: int() is floor()
            x0, y0, z0 = min(int(tx), max(sx - 2, 0)), min(int(ty), max(sy - 2, 0)), min(int(tz), max(sz - 2, 0))
            fx, fy, fz = tx - x0, ty - y0, tz - z0
            gx, gy, gz = 1.0 - fx, 1.0 - fy, 1.0 - fz
            x1, y1, z1 = min(x0 + 1, sx - 1), min(y0 + 1, sy - 1), min(z0 + 1, sz - 1)
            v0 = v1 = v2 = 0.0
            v0, v1, v2 = _corner(grid, gx * gy * gz, x0, y0, z0, v0, v1, v2)
            v0, v1, v2 = _corner(grid, fx * gy * gz, x1, y0, z0, v0, v1, v2)
            v0, v1, v2 = _corner(grid, gx * fy * gz, x0, y1, z0, v0, v1, v2)
            v0, v1, v2 = _corner(grid, fx * fy * gz, x1, y1, z0, v0, v1, v2)
            v0, v1, v2 = _corner(grid, gx * gy * fz, x0, y0, z1, v0, v1, v2)
            v0, v1, v2 = _corner(grid, fx * gy * fz, x1, y0, z1, v0, v1, v2)
            v0, v1, v2 = _corner(grid, gx * fy * fz, x0, y1, z1, v0, v1, v2)
            v0, v1, v2 = _corner(grid, fx * fy * fz, x1, y1, z1, v0, v1, v2)
            v0, v1, v2 = v0 / quant, v1 / quant, v2 / quant
            s = d[i, 0] * v0 + d[i, 1] * v1 + d[i, 2] * v2
            gi = np.float64(g[i * g_step])
            buf[i, col] = np.float32(gi * s)
            buf[i, col + 1] = np.float32(gi * s * abs(s))


def surface_rows(buf: np.ndarray, col: int, u: np.ndarray, d: np.ndarray, g: np.ndarray, grid: np.ndarray) -> None:
    """Write the surface input's columns ``buf[:, col:col + 2]`` (:func:`photon_fields.models_spec.surface.
    surface_columns`, bit for bit) for normalized positions u (n, 3) float32, unit travel directions d (n, 3)
    float64 (any strides) and g (1,) for every row or (n,) float32, from the stored grid (int8 (sx, sy, sz, 3))."""
    if u.shape[0] != buf.shape[0] or d.shape[0] != buf.shape[0] or g.shape[0] not in (1, buf.shape[0]):
        raise ValueError(f"surface rows: u {u.shape}, d {d.shape}, g {g.shape} do not fit {buf.shape[0]} rows")
    _surface_kernel(buf, int(col), u, np.asarray(d, dtype=np.float64), np.asarray(g, dtype=np.float32), grid,
                    SURFACE_QUANT)
