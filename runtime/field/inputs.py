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
  ``phase_features`` itself and copied into every row; with per-query g the caller passes the full matrix.

Serial on purpose: a chunk is 16k queries, and waking numba's threads for three short parallel regions per chunk cost
more than they saved (a parallel version measured slower in the renderer). The direction's spherical coordinates stay
numpy's (``direction_input``): its vectorized arccos and atan2 beat a scalar loop over the C library's 2x.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from photon_fields.models_spec.encoding import box_arguments


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
                phase: np.ndarray | None) -> None:
    """Multiply ``buf[:, dir_col:phase_col]`` by ``gains`` (None: unchanged; (1,) or (n,) float32) and set
    ``buf[:, phase_col:]`` to ``phase`` ((1, P): the same row everywhere; or (n, P); None: left as they are, for a
    reused buffer that holds them already), in place."""
    g = np.zeros(0, np.float32) if gains is None else np.ascontiguousarray(gains, dtype=np.float32).reshape(-1)
    if phase is None and g.shape[0] == 0:
        return
    p = (np.zeros((0, buf.shape[1] - phase_col), np.float32) if phase is None
         else np.ascontiguousarray(phase, dtype=np.float32))
    n = buf.shape[0]
    if g.shape[0] not in (0, 1, n) or p.ndim != 2 or p.shape[0] not in (0, 1, n) or \
            p.shape[1] != buf.shape[1] - phase_col or (p.shape[0] == 0 and phase is not None):
        raise ValueError(f"gains {g.shape} / phase {p.shape} do not fit {n} rows of {buf.shape[1] - phase_col} "
                         "phase columns")
    _finish_kernel(buf, int(dir_col), int(phase_col), g, p)
