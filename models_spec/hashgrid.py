"""Multiresolution hash encoding (paper Sec. 3.4), bit-for-bit as tiny-cuda-nn's ``HashGrid`` defines it.

This is the contract between training (``photon_fields.train.field.hashgrid.HashGridEncoding``, torch) and any runtime
evaluator: the level geometry, the table layout and a plain-numpy reference encoder. numpy only, no torch.

Parameters (:class:`HashGridConfig`, tcnn's names in brackets)
---------------------------------------------------------------
dims : 2 or 3 [n_input_dims]
    D, input dimensions: 3 for positions, 2 for directions (via :func:`direction_to_unit_square`).
levels : 1..32 [n_levels]
    L, grid levels.
features : 1, 2, 4 or 8 [n_features_per_level]
    F, features per table entry; the output has ``L * F`` columns, level-major (``out[:, l*F + f]``).
log2_table_size : 1..31 [log2_hashmap_size]
    T, the per-level table holds at most ``2**T`` entries.
base_resolution : int >= 1 [base_resolution]
    N_min, resolution of level 0.
per_level_scale : float >= 1 [per_level_scale]
    b, resolution growth per level. tcnn keeps it as a float32; so do we (the value is rounded to
    float32 before use, and ``to_dict`` stores the rounded value).

The paper's encodings are :data:`PAPER_POSITION` (D=3) and :data:`PAPER_DIRECTION` (D=2): 16 levels of
8 features, 2x scale, 2^19 tables ("Our encoding uses 16 grid levels with 8 features each, a 2x scaling
factor between levels, and a hash table size of 2^19"); the paper does not state N_min, so tcnn's default
16 is used.

Definition (per level l; all float arithmetic float32, all integer arithmetic uint32 with wraparound)
-----------------------------------------------------------------------------------------------------
- ``scale = exp2(l * log2(b)) * N_min - 1``, ``res = (uint32) ceil(scale) + 1``;
- table size: ``min(next_multiple_of_8(min(res^D, 2^31 - 1)), 2^T)``; the levels are stored one after
  another in one ``(total, F)`` table (:func:`table_offsets`);
- ``pos = fma(scale, x_d, 0.5)``, corner ``c = floor(pos) + {0, 1}`` (not clamped), ``frac = pos - floor(pos)``;
- index: the dense index ``sum_d c_d * stride_d`` with ``stride_0 = 1``, ``stride_{d+1} = stride_d * res``,
  the loop stopping as soon as ``stride > size``; if afterwards ``size < stride`` the level is *hashed* and
  the index becomes ``xor_d (c_d * HASH_PRIMES[d])``; finally ``index % size``;
- corner ``j`` (bit d of j set: ``c_d = floor(pos_d) + 1``) has weight ``prod_d (frac_d or 1 - frac_d)``,
  multiplied in dimension order; the level's features are ``acc = fma(w_j, table[index_j], acc)`` over
  j = 0 .. 2^D - 1 starting from 0 (linear interpolation, no smoothstep).

Exactness notes
---------------
- float32 fma: numpy has none. :func:`fma_f32` computes ``a * b`` in float64 (exact: the product of two
  24-bit significands has at most 48 bits) and adds ``c`` in float64. That sum is *not* always exact, and
  rounding it to float64 and then to float32 can differ from one rounding when the float64 result lands
  exactly on a float32 tie (double rounding; e.g. ``fma(1 + 2^-23, 2^-24 - 2^-47, 1 + 2^-23)``). The
  float64 sum is therefore rounded *to odd* (the exact error comes from TwoSum), which makes the final
  float32 rounding exact (53 >= 24 + 2). The result equals a hardware ``fmaf`` for all finite inputs.
- The feature accumulation uses fma because that is what runs in practice: nvcc contracts tcnn's
  ``result += weight * data`` into an fma by default, torch's CPU ``embedding_bag`` (fbgemm) accumulates
  with fma too, and ``train.field.hashgrid``'s kernels use ``llvm.fma``, so they match this reference bit for bit.
- ``exp2`` is evaluated in float64 and rounded to float32 (CUDA's ``exp2f`` has up to 2 ulp error): for
  power-of-two ``b`` (the paper's 2.0) every scale is exact and identical to tcnn's; for other ``b`` the
  last bit of ``scale`` may differ from a GPU run.
- The stride of the dense-index loop is an exact integer, as in tcnn since PR #501 (June 2025). Older tcnn
  (the paper's) kept it in uint32: once ``stride * res`` reached 2^32 it wrapped, the level counted as
  *not* hashed and its index kept only some coordinates (for the paper's configs levels 12-15, e.g. level
  15 of :data:`PAPER_POSITION` indexed by ``c_0 mod 2^19`` alone): a bug that wastes the finest levels, so
  we follow the fixed definition. A level is hashed exactly when ``res^D > size``. The hash products,
  the dense index and the final modulo are still uint32 with wraparound.
- Inputs are meant to lie in [0, 1]^D. Others follow the same formulas (``(uint32)(int) floor(pos)``
  wraps negative cells); non-finite inputs or ``|pos| >= 2^31`` (undefined in C) raise ValueError.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

#: tcnn's ``fast_hash`` primes for the first three dimensions (1 keeps consecutive x cells coherent in memory).
HASH_PRIMES: np.ndarray = np.array([1, 2654435761, 805459861], dtype=np.uint32)
#: tcnn's GridEncoding instantiations: these input dimensions and features per level.
SUPPORTED_DIMS = (2, 3)
SUPPORTED_FEATURES = (1, 2, 4, 8)
MAX_LEVELS = 32
_MASK32 = 0xFFFFFFFF
_MAX_PARAMS = 2**31 - 1  # tcnn's guard: std::numeric_limits<uint32_t>::max() / 2


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


@dataclass(frozen=True)
class HashGridConfig:
    """Hyperparameters of one hash-grid encoding (see the module docstring for their meaning)."""

    dims: int
    levels: int
    features: int
    log2_table_size: int
    base_resolution: int
    per_level_scale: float

    def __post_init__(self) -> None:
        for name in ("dims", "levels", "features", "log2_table_size", "base_resolution"):
            if not _is_int(getattr(self, name)):
                raise ValueError(f"HashGridConfig.{name} must be an int, got {getattr(self, name)!r}")
            object.__setattr__(self, name, int(getattr(self, name)))
        if self.dims not in SUPPORTED_DIMS:
            raise ValueError(f"HashGridConfig.dims must be 2 or 3 (tcnn's HashGrid), got {self.dims}")
        if not 1 <= self.levels <= MAX_LEVELS:
            raise ValueError(f"HashGridConfig.levels must be in 1..{MAX_LEVELS}, got {self.levels}")
        if self.features not in SUPPORTED_FEATURES:
            raise ValueError(f"HashGridConfig.features must be one of {SUPPORTED_FEATURES}, got {self.features}")
        if not 1 <= self.log2_table_size <= 31:
            raise ValueError(f"HashGridConfig.log2_table_size must be in 1..31, got {self.log2_table_size}")
        if self.base_resolution < 1:
            raise ValueError(f"HashGridConfig.base_resolution must be >= 1, got {self.base_resolution}")
        b = self.per_level_scale
        if isinstance(b, (bool, np.bool_)) or not isinstance(b, (int, float, np.integer, np.floating)):
            raise ValueError(f"HashGridConfig.per_level_scale must be a number, got {b!r}")
        with np.errstate(over="ignore"):
            b32 = float(np.float32(b))
        if not math.isfinite(b32) or b32 < 1.0:
            raise ValueError(f"HashGridConfig.per_level_scale must be finite (as float32) and >= 1, got {b!r}")
        # Stored as the float32 value tcnn uses, so that equal encodings compare (and serialize) equal.
        object.__setattr__(self, "per_level_scale", b32)
        finest = level_scale(self, self.levels - 1)
        if not finest < 2.0**31 - 1.0:
            # pos = scale * x + 0.5 goes through a C (int) cast in tcnn: beyond 2^31 that is undefined.
            raise ValueError(f"HashGridConfig: the finest level's scale {float(finest):.6g} must be < 2^31 - 1 "
                             "(lower levels, base_resolution or per_level_scale)")
        total = int(table_offsets(self)[-1])
        if total * self.features > _MASK32:
            # tcnn counts parameters (entries * F) in a uint32.
            raise ValueError(f"HashGridConfig: {total} table entries x {self.features} features exceed 2^32 - 1 "
                             "parameters (lower log2_table_size or levels)")

    @property
    def output_dims(self) -> int:
        """Columns of the encoding: ``levels * features``."""
        return self.levels * self.features

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict of the six fields."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> HashGridConfig:
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ValueError."""
        if not isinstance(data, Mapping):
            raise ValueError(f"HashGridConfig.from_dict needs a mapping, got {type(data).__name__}")
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(names))
        missing = [n for n in names if n not in data]
        if unknown or missing:
            raise ValueError(f"HashGridConfig.from_dict: unknown keys {unknown}, missing keys {missing}")
        return cls(**{n: data[n] for n in names})


def tcnn_config(cfg: HashGridConfig) -> dict[str, Any]:
    """The equivalent tiny-cuda-nn encoding JSON (for ``tcnn.Encoding(cfg.dims, tcnn_config(cfg))``)."""
    return {"otype": "HashGrid", "n_levels": cfg.levels, "n_features_per_level": cfg.features,
            "log2_hashmap_size": cfg.log2_table_size, "base_resolution": cfg.base_resolution,
            "per_level_scale": cfg.per_level_scale, "interpolation": "Linear"}


# ----------------------------------------------------------------------------------------------------
# Level geometry
# ----------------------------------------------------------------------------------------------------


def _check_level(cfg: HashGridConfig, level: int) -> int:
    if not _is_int(level) or not 0 <= level < cfg.levels:
        raise ValueError(f"level must be an int in 0..{cfg.levels - 1}, got {level!r}")
    return int(level)


def level_scale(cfg: HashGridConfig, level: int) -> np.float32:
    """tcnn's ``grid_scale``: ``exp2f(level * log2f(b)) * N_min - 1.0f`` in float32 arithmetic."""
    level = int(level)  # not _check_level: __post_init__ calls this before the config is complete
    log2_b = np.float32(math.log2(float(np.float32(cfg.per_level_scale))))
    exponent = np.float32(level) * log2_b
    with np.errstate(over="ignore"):  # absurd configs overflow to inf, which __post_init__ then rejects
        power = np.float32(np.exp2(np.float64(exponent)))
        return np.float32(power * np.float32(cfg.base_resolution)) - np.float32(1.0)


def level_resolution(cfg: HashGridConfig, level: int) -> int:
    """Grid vertices per axis: ``(uint32) ceil(scale) + 1``."""
    return int(np.ceil(level_scale(cfg, _check_level(cfg, level)))) + 1


def _table_size(cfg: HashGridConfig, level: int) -> int:
    res = int(np.ceil(level_scale(cfg, level))) + 1
    params = min(res**cfg.dims, _MAX_PARAMS)
    params = -(-params // 8) * 8  # next multiple of 8: aligned memory accesses in tcnn
    return min(params, 1 << cfg.log2_table_size)


def level_table_size(cfg: HashGridConfig, level: int) -> int:
    """Entries of the level's table: ``min(next_multiple_8(min(res^D, 2^31 - 1)), 2^T)``."""
    return _table_size(cfg, _check_level(cfg, level))


def table_offsets(cfg: HashGridConfig) -> np.ndarray:
    """int64 (L + 1,): level l owns rows ``offsets[l] : offsets[l + 1]`` of the flat ``(offsets[-1], F)``
    table (tcnn's ``hashmap_offsets_table``, last entry = total rows)."""
    sizes = [_table_size(cfg, level) for level in range(cfg.levels)]
    return np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)


def total_table_rows(cfg: HashGridConfig) -> int:
    """Rows of the flat table (``table_offsets(cfg)[-1]``)."""
    return int(table_offsets(cfg)[-1])


def _stride_loop(res: int, size: int, dims: int) -> tuple[tuple[int, ...], int]:
    # tcnn's grid_index loop: multipliers per dim (0 for dims it never reaches) and the final stride, kept
    # exact (Python int) as in tcnn >= PR #501; see the module docstring.
    stride = 1
    mult = [0] * dims
    for d in range(dims):
        if stride > size:
            break
        mult[d] = stride
        stride = stride * res
    return tuple(mult), stride


def level_dense_strides(cfg: HashGridConfig, level: int) -> tuple[int, ...]:
    """Per-dimension multipliers of the dense index (uint32 values; 0 for dimensions tcnn's loop skips).
    Only used when the level is not hashed: ``index = sum_d c_d * m_d mod 2^32``."""
    level = _check_level(cfg, level)
    return _stride_loop(level_resolution(cfg, level), _table_size(cfg, level), cfg.dims)[0]


def level_is_hashed(cfg: HashGridConfig, level: int) -> bool:
    """True if the level's dense index is replaced by the hash (``res^D > size``)."""
    level = _check_level(cfg, level)
    size = _table_size(cfg, level)
    return size < _stride_loop(level_resolution(cfg, level), size, cfg.dims)[1]


@dataclass(frozen=True)
class LevelSpec:
    """Everything an evaluator needs about one level (all values as tcnn computes them)."""

    level: int
    scale: np.float32
    resolution: int
    table_size: int
    offset: int
    hashed: bool
    dense_strides: tuple[int, ...]


def level_specs(cfg: HashGridConfig) -> list[LevelSpec]:
    """:class:`LevelSpec` of every level, coarsest first."""
    offsets = table_offsets(cfg)
    return [LevelSpec(level, level_scale(cfg, level), level_resolution(cfg, level), level_table_size(cfg, level),
                      int(offsets[level]), level_is_hashed(cfg, level), level_dense_strides(cfg, level))
            for level in range(cfg.levels)]


# ----------------------------------------------------------------------------------------------------
# Reference encoder
# ----------------------------------------------------------------------------------------------------


def fma_f32(a: np.ndarray | float, b: np.ndarray | float, c: np.ndarray | float) -> np.ndarray:
    """Exact float32 ``fma(a, b, c)`` (one rounding) for float32 inputs, broadcasting like numpy.

    a * b is exact in float64; the float64 sum is rounded to odd (TwoSum gives its exact error) so that
    the final rounding to float32 is the single correct one (see the module docstring)."""
    a64 = np.asarray(a, dtype=np.float32).astype(np.float64)
    b64 = np.asarray(b, dtype=np.float32).astype(np.float64)
    c64 = np.asarray(c, dtype=np.float32).astype(np.float64)
    p = a64 * b64
    s = np.asarray(p + c64)
    bb = s - p
    err = (p - (s - bb)) + (c64 - bb)  # TwoSum: s + err == p + c exactly
    # Round to odd: an inexact s with an even last bit moves one float64 ulp toward the exact value.
    even = (s.view(np.int64) & 1) == 0
    fix = (err != 0) & even
    if np.any(fix):
        s = np.where(fix, np.nextafter(s, np.copysign(np.inf, err)), s)
    return np.asarray(s).astype(np.float32)


def _as_points(cfg: HashGridConfig, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != 2 or x.shape[1] != cfg.dims:
        raise ValueError(f"x must have shape (n, {cfg.dims}), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("x must be finite")
    return x


def corner_indices(cfg: HashGridConfig, level: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Table slots and interpolation weights of the 2^D cell corners of each point at one level.

    Parameters
    ----------
    x : (n, D) array, converted to float32 (tcnn's input type); meant to lie in [0, 1]^D.

    Returns
    -------
    indices : int64 (n, 2^D), values in [0, table_size): rows *within the level* (add
        ``table_offsets(cfg)[level]`` for the flat table). Column j is the corner whose dimension d is
        ``floor(pos_d) + ((j >> d) & 1)``.
    weights : float32 (n, 2^D), ``prod_d (frac_d if bit d of j else 1 - frac_d)`` multiplied in order d = 0, 1, ...
    """
    level = _check_level(cfg, level)
    x = _as_points(cfg, x)
    scale = level_scale(cfg, level)
    size = _table_size(cfg, level)
    mult, final_stride = _stride_loop(int(np.ceil(scale)) + 1, size, cfg.dims)
    hashed = size < final_stride

    pos = fma_f32(scale, x, np.float32(0.5))
    cell = np.floor(pos)
    if np.any(np.abs(cell) >= 2.0**31):
        raise ValueError("x is too far outside [0, 1]: scale * x + 0.5 must stay within the int32 range")
    frac = pos - cell  # exact in float32
    grid = (cell.astype(np.int64) & _MASK32).astype(np.uint32)  # tcnn: (uint32_t)(int) floorf(pos)

    n, D = x.shape
    indices = np.empty((n, 1 << D), dtype=np.int64)
    weights = np.empty((n, 1 << D), dtype=np.float32)
    one = np.uint32(1)
    for j in range(1 << D):
        index = np.zeros(n, dtype=np.uint32)
        w = np.ones(n, dtype=np.float32)
        for d in range(D):
            bit = (j >> d) & 1
            c = grid[:, d] + one if bit else grid[:, d]  # uint32 add: wraps like the C code
            w = w * (frac[:, d] if bit else np.float32(1.0) - frac[:, d])
            if hashed:
                index ^= c * HASH_PRIMES[d]  # uint32 multiply, mod 2^32
            else:
                index += c * np.uint32(mult[d])
        indices[:, j] = index % np.uint32(size)
        weights[:, j] = w
    return indices, weights


def _check_table(cfg: HashGridConfig, table: np.ndarray) -> np.ndarray:
    table = np.asarray(table)
    shape = (total_table_rows(cfg), cfg.features)
    if table.shape != shape or table.dtype != np.float32:
        raise ValueError(f"table must be float32 of shape {shape}, got {table.dtype} {table.shape}")
    return table


def encode_reference(cfg: HashGridConfig, table: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Reference encoding: float32 (n, L * F), level l in columns ``l*F : (l+1)*F``.

    ``table`` is the flat float32 ``(total_table_rows(cfg), F)`` table; per level the corners are
    accumulated with fma in corner order (see the module docstring)."""
    table = _check_table(cfg, table)
    x = _as_points(cfg, x)
    offsets = table_offsets(cfg)
    out = np.empty((x.shape[0], cfg.output_dims), dtype=np.float32)
    for level in range(cfg.levels):
        idx, w = corner_indices(cfg, level, x)
        rows = table[offsets[level] + idx]  # (n, 2^D, F)
        acc = np.zeros((x.shape[0], cfg.features), dtype=np.float32)
        for j in range(idx.shape[1]):
            acc = fma_f32(w[:, j, None], rows[:, j, :], acc)
        out[:, level * cfg.features:(level + 1) * cfg.features] = acc
    return out


def table_gradient_reference(cfg: HashGridConfig, x: np.ndarray, grad_out: np.ndarray) -> np.ndarray:
    """d(sum(out * grad_out)) / d(table) as float32 ``(total, F)``: every corner adds ``w * grad_out``
    to its row.

    The additions to one row happen in occurrence order (point, then level, then corner) and each is an
    fma, ``g_row = fma(w, grad, g_row)``: what ``train.field.hashgrid``'s backward computes (and torch's CPU
    ``embedding_bag`` backward, too); ``np.add.at`` of float32 products gives the same up to rounding."""
    x = _as_points(cfg, x)
    grad_out = np.asarray(grad_out, dtype=np.float32)
    if grad_out.shape != (x.shape[0], cfg.output_dims):
        raise ValueError(f"grad_out must have shape {(x.shape[0], cfg.output_dims)}, got {grad_out.shape}")
    offsets = table_offsets(cfg)
    F = cfg.features
    per_level = [corner_indices(cfg, level, x) for level in range(cfg.levels)]
    # Flatten in occurrence order (point, level, corner).
    rows = np.stack([offsets[lv] + idx for lv, (idx, _) in enumerate(per_level)], axis=1).reshape(-1)
    w = np.stack([wt for _, wt in per_level], axis=1).reshape(-1)
    g = np.repeat(grad_out.reshape(-1, F), 1 << cfg.dims, axis=0)  # (n * L * 2^D, F)
    # Rank of each occurrence among those of its row; within one rank the rows are distinct, so each
    # rank is one vectorized step and the per-row order is preserved.
    order = np.argsort(rows, kind="stable")
    sorted_rows = rows[order]
    starts = np.r_[0, np.flatnonzero(sorted_rows[1:] != sorted_rows[:-1]) + 1]
    counts = np.diff(np.r_[starts, rows.size])
    rank = np.empty(rows.size, dtype=np.int64)
    rank[order] = np.arange(rows.size) - np.repeat(starts, counts)
    grad = np.zeros((total_table_rows(cfg), F), dtype=np.float32)
    by_rank = np.argsort(rank, kind="stable")
    bounds = np.searchsorted(rank[by_rank], np.arange(int(counts.max()) + 2 if counts.size else 1))
    for r in range(bounds.size - 1):
        sel = by_rank[bounds[r]:bounds[r + 1]]
        grad[rows[sel]] = fma_f32(w[sel, None], g[sel], grad[rows[sel]])
    return grad


def direction_to_unit_square(d: np.ndarray) -> np.ndarray:
    """Unit directions (n, 3) -> float32 (n, 2) in [0, 1]^2 for the D=2 encoding.

    Column 0 is ``theta / pi`` with ``theta = arccos(clip(d_z, -1, 1))`` (0 at +z, 1 at -z); column 1 is
    ``(atan2(d_y, d_x) + pi) / (2 pi)`` (the azimuth; the seam at d_y = 0, d_x < 0 maps to 0 for
    d_y = -0.0 and 1 for d_y = +0.0; the poles get atan2(0, 0) = 0, i.e. 0.5). Computed in float64, then
    rounded to float32 once. ``d`` is not renormalized (the clip only absorbs rounding), so pass unit
    vectors: the runtime and training then see identical coordinates for identical directions.
    """
    d = np.asarray(d, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"d must have shape (n, 3), got {d.shape}")
    theta = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    phi = np.arctan2(d[:, 1], d[:, 0])
    return np.stack([theta / np.pi, (phi + np.pi) / (2.0 * np.pi)], axis=1).astype(np.float32)


# Defined last: validating a config needs the level functions above.
#: The paper's position encoding (Sec. 3.4), N_min = tcnn's default 16.
PAPER_POSITION = HashGridConfig(3, 16, 8, 19, 16, 2.0)
#: The paper's direction encoding (Sec. 3.4), on :func:`direction_to_unit_square` coordinates.
PAPER_DIRECTION = HashGridConfig(2, 16, 8, 19, 16, 2.0)
