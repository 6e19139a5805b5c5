"""Multiresolution hash encoding for inference (paper Sec. 3.4): numba kernels, no torch.

:func:`encode` is tiny-cuda-nn's ``HashGrid`` exactly as :mod:`models_spec.hashgrid` defines it, and equals
:func:`photon_fields.models_spec.hashgrid.encode_reference` bit for bit: ``pos = fma(scale, x, 0.5)`` with one rounding,
the same uint32 corner indices, weights multiplied in dimension order and the features accumulated as
``acc = fma(w_j, table[row_j], acc)`` over corners j = 0 .. 2^D - 1 from +0. :func:`corners` returns the
corner rows and weights themselves. ``train.field.hashgrid`` uses both (its forward *is* :func:`encode`, its
backward scatters into :func:`corners`), so training and rendering share one implementation.

Parameters of :func:`encode`
----------------------------
cfg : HashGridConfig
    The encoding (D = 2 or 3 input dims, L levels, F features per level, table size, N_min, scale b).
table : float32 ndarray (total_table_rows(cfg), F)
    The flat table, level l in rows ``table_offsets(cfg)[l] : table_offsets(cfg)[l + 1]``; used in place
    when C-contiguous (a strided table is copied first). Pass it through :func:`aligned_table` once after
    loading: numpy places large arrays 16 bytes past a 64-byte boundary, so half of the 32-byte rows of an
    F = 8 table straddle two cache lines, and the encoding is memory-bound (measured 1.25-1.5x faster with
    the aligned copy; torch's allocator already aligns to 64).
x : array (n, D)
    Points, meant to lie in [0, 1]^D (directions via ``direction_to_unit_square``); rounded to float32
    (tcnn's input type) like the reference. Non-finite x, or x so far outside [0, 1] that
    ``floor(scale * x + 0.5)`` leaves the int32 range, raises ValueError, exactly when the reference does
    (checked before anything is written: a min/max pass over x, exact fma only for points near the limit).
out : float32 ndarray (n, >= col + L*F), optional
    Written in place: columns ``col : col + L*F`` (level-major, ``out[i, col + l*F + f]``); the other
    columns are not touched. Any row stride works (so does a column slice ``buf[:, a:b]``), but each row's
    columns must be contiguous (column stride 4 bytes). Default: a new (n, L*F) array. This lets the
    renderer encode both inputs straight into one MLP input buffer, no copies:
    ``encode(pos_cfg, tp, xp, out=buf)`` then ``encode(dir_cfg, td, u, out=buf, col=Lp*Fp)``.
col : int >= 0 (default 0)
    First column written.

Threads: numba's pool (``numba.set_num_threads``, ``photon_fields.runtime.threads.set_threads``). Kernels are
specialized per (D, F), compiled on first use (~3-5 s each) and cached on disk (``cache=True``).

Layout and speed
----------------
Per level and point the work is a few float32 / integer operations for the cell, the 2^D rows and
weights, then 2^D random reads of an F-float row. For the paper's tables (2^19 rows of 32 B per fine
level, 228 MB in all for D=3) the random reads decide: a D=3 point touches ~80-90 cache lines (13 hashed
levels x 4 corner pairs x ~1.5 lines, as a pair shares a line when its x cell is even, + 3 dense levels),
and this machine serves ~10-16 ns per independent random line per core (a plain gather over 16 MB-1 GB).
With every point in one cell (all hits) the kernel does 2.6 M D=3 points/s per thread (4.3 M for D=2);
on random points 0.45-0.55 M: memory-bound by ~5x, at ~60 % of the plain-gather bound.

``bench/bench_runtime_hashgrid.py`` (``bench/results/runtime_hashgrid.json``), quiet machine (other
processes < 0.2 core), 64-byte aligned tables, uniform random points, best of >= 3 calls, M points/s:

======================================  ==========  ==========  ==========  ===================
config (L x F, 2^T rows per level)      1 thr 2^16  2 thr 2^14  2 thr 2^16  numpy reference 2^14
======================================  ==========  ==========  ==========  ===================
paper D=3 position (16 x 8, 2^19)       0.54        0.90        0.99        0.015
paper D=2 direction (16 x 8, 2^19)      0.99        1.89        1.94        0.038
D=3, 2^16 rows (2 MB per level)         0.44        0.92        0.97        0.015
D=3, 2^14 rows (cache-resident)         0.51        1.42        1.43        0.016
D=3, F = 2 (8-byte rows)                0.72        1.03        1.02        0.038
D=2, 2^14 rows                          1.40        3.05        2.89        0.045
======================================  ==========  ==========  ==========  ===================

Figures vary by up to 2x between runs (the memory system is shared with the host's other guests); the
2^18 ones are within 25 % of 2^16, either way. Both encodings of one field query: 0.61 M queries/s (2 threads,
random); on ray-ordered queries (64 samples along each camera ray, raster order) D=2 rises to 5.7 M/s
(neighbouring rays share cells), D=3 stays at 0.9 M/s (its fine cells are far smaller than the sample
spacing), 0.77 M queries/s for both.

Loop layouts compared (section ``layouts`` of the bench, 2^16 points, 2 threads):

- *blocks* (the default, ``_LAYOUT``): ``prange`` over blocks of ``_BLOCK`` points, each thread runs its
  block through all levels, level by level, points innermost. One parallel region per call, the block's
  output rows (1024 x 512 B for D=3) stay in L2 while the levels fill them, per-level constants are
  hoisted out of the point loop. Block sizes 256-4096 measure the same.
- *levels outside*: for each level, ``prange`` over all blocks, so one level's table is read by the whole
  batch at once. Quiet machine: same speed as *blocks* (0.89 vs 0.87 D=3, 1.90 vs 1.86 D=2). But it has a
  barrier per level, and with another process on the cores it fell to 0.3-0.6x of *blocks* (4x slower
  at 2^14); with cache-resident tables it was 3x slower (each level pass streams the (n, L*F) output
  through the caches again). So *blocks* wins.
- *points outside* (blocks of 1 point): 0.48x (D=3), 0.8x (D=2).
- prefetching: a two-phase block (rows and weights of 128 points with ``llvm.prefetch`` of each row,
  then the gathers) and prefetching 2-16 points ahead in the fused loop gave no gain (-10 % to +5 %);
  the fused loop is short enough for the out-of-order core to overlap several points' misses itself.
- table placement (section ``alignment``): 64-byte aligned 0.89 / 1.90 M/s against 0.59 / 1.51 M/s for
  numpy's default placement 16 bytes past a line (D=3 / D=2): see :func:`aligned_table`.

Within a point, a corner's F features are one <F x float> load and one vector fma (``llvm.fma.v{F}f32``,
:func:`_interp_store`): numba leaves LLVM's SLP vectorizer off, and the scalar form (F loads + F fmas per
corner) was ~1.4x slower on cache-resident tables. Lanes are independent IEEE fmas: the result is the
same. Integer math is uint64 registers with masks where tcnn's uint32 wraps; hashed levels (2^T rows)
reduce with a mask, dense levels divide only at the far faces. Validating x costs one min/max pass.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from llvmlite import ir
from numba import literally, njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from photon_fields.models_spec.hashgrid import HASH_PRIMES, HashGridConfig, fma_f32, level_specs, total_table_rows
from photon_fields.runtime.numba_inlining import install

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

_MASK = np.uint64(0xFFFFFFFF)
_ONE_U = np.uint64(1)
_LAYOUT = "blocks"  # the measured winner (module docstring)
_BLOCK = 1024  # points per prange task: 256-4096 measure the same; 16 tasks at n = 2^14 for 2 threads


# ----------------------------------------------------------------------------------------------------
# LLVM intrinsics: exact float32 fma, scalar and F-wide
# ----------------------------------------------------------------------------------------------------


@intrinsic
def fma32(typingctx, a, b, c):  # numba intrinsic: arguments are numba types
    """float32 fused multiply-add with one rounding (LLVM lowers it to vfmadd or a correct libm call)."""
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):  # llvmlite IR builder callback
        f32 = ir.FloatType()
        fn = builder.module.declare_intrinsic("llvm.fma", [f32], ir.FunctionType(f32, [f32, f32, f32]))
        return builder.call(fn, args)

    return sig, codegen


@intrinsic
def _interp_store(typingctx, table, out, i, col, rows, weights, gain, nfeat):
    """``out[i, col : col + F] = (fma-chain over j of weights[j] * table[rows[j], :] from +0) * gain``, F =
    ``nfeat`` (an int literal), as one <F x float> load + fma per corner and one multiply. ``table`` must be
    C-contiguous (F floats per row) and ``out``'s columns contiguous; rows / weights are equal-length tuples
    (uint64 / float32), gain a float32 (1: the sums as they are, bit for bit)."""
    if not isinstance(nfeat, types.IntegerLiteral):
        return None  # numba retries with the literal type; F must be a compile-time constant
    F = nfeat.literal_value
    K = rows.count
    sig = types.void(table, out, i, col, rows, weights, gain, nfeat)

    def codegen(context, builder, signature, args):
        tab = context.make_array(signature.args[0])(context, builder, args[0])
        dst = context.make_array(signature.args[1])(context, builder, args[1])
        i32, i64 = ir.IntType(32), ir.IntType(64)
        vt = ir.VectorType(ir.FloatType(), F)
        fma = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vt, [vt, vt, vt]), f"llvm.fma.v{F}f32")
        undef = ir.Constant(vt, ir.Undefined)
        splat = ir.Constant(ir.VectorType(i32, F), None)  # shuffle mask of zeros: broadcast lane 0
        acc = ir.Constant(vt, None)  # +0.0 in every lane, as the reference's np.zeros
        for j in range(K):
            row = builder.extract_value(args[4], j)
            src = builder.gep(tab.data, [builder.mul(row, ir.Constant(i64, F))], inbounds=True)
            v = builder.load(builder.bitcast(src, vt.as_pointer()), typ=vt, align=4)
            w = builder.insert_element(undef, builder.extract_value(args[5], j), ir.Constant(i32, 0))
            acc = builder.call(fma, [builder.shuffle_vector(w, undef, splat), v, acc])
        g = builder.insert_element(undef, args[6], ir.Constant(i32, 0))
        acc = builder.fmul(acc, builder.shuffle_vector(g, undef, splat))
        offset = builder.add(builder.mul(args[2], builder.extract_value(dst.strides, 0)),
                             builder.mul(args[3], ir.Constant(i64, 4)))
        ptr = builder.inttoptr(builder.add(builder.ptrtoint(dst.data, i64), offset), vt.as_pointer())
        builder.store(acc, ptr, align=4)
        return context.get_dummy_value()

    return sig, codegen


# ----------------------------------------------------------------------------------------------------
# Per-point corner math (inlined into every kernel; the only copy of tcnn's index/weight definition)
# ----------------------------------------------------------------------------------------------------


@njit(inline="always")
def _axis(scale, xv):  # -> cell and cell + 1 (uint32 values in uint64), frac
    pos = fma32(scale, xv, np.float32(0.5))
    fl = np.floor(pos)
    c = np.uint64(np.int64(fl)) & _MASK  # tcnn: (uint32_t)(int) floorf(pos); x was checked in Python
    return c, (c + _ONE_U) & _MASK, pos - fl  # frac is exact in float32


@njit(inline="always")
def _dense_row(v, size, offset):
    v &= _MASK  # tcnn's uint32 sum
    if v >= size:  # only at the far faces (corner cell + 1 = res) or outside [0, 1]: skip the division
        v %= size
    return v + offset


@njit(inline="always")
def _point3(x, i, scale, hashed, m0, m1, m2, size, offset):
    """Rows (uint64, offset included) and weights of the 8 corners of point i at one D=3 level."""
    a0, b0, t0 = _axis(scale, x[i, 0])
    a1, b1, t1 = _axis(scale, x[i, 1])
    a2, b2, t2 = _axis(scale, x[i, 2])
    one = np.float32(1.0)
    u0 = one - t0
    u1 = one - t1
    u2 = one - t2
    # Weight of corner j: ((w_0 * w_1) * w_2) in dimension order (1 * w_0 is exact); pairs shared.
    w00 = u0 * u1
    w10 = t0 * u1
    w01 = u0 * t1
    w11 = t0 * t1
    weights = (w00 * u2, w10 * u2, w01 * u2, w11 * u2, w00 * t2, w10 * t2, w01 * t2, w11 * t2)
    h1a = a1 * m1  # low 32 bits are tcnn's uint32 products
    h1b = b1 * m1
    h2a = a2 * m2
    h2b = b2 * m2
    if hashed:
        mask = size - _ONE_U  # hashed levels have 2^T rows (_level_constants checks)
        rows = (((a0 ^ h1a ^ h2a) & mask) + offset, ((b0 ^ h1a ^ h2a) & mask) + offset,
                ((a0 ^ h1b ^ h2a) & mask) + offset, ((b0 ^ h1b ^ h2a) & mask) + offset,
                ((a0 ^ h1a ^ h2b) & mask) + offset, ((b0 ^ h1a ^ h2b) & mask) + offset,
                ((a0 ^ h1b ^ h2b) & mask) + offset, ((b0 ^ h1b ^ h2b) & mask) + offset)
    else:
        e0a = a0 * m0
        e0b = b0 * m0
        rows = (_dense_row(e0a + h1a + h2a, size, offset), _dense_row(e0b + h1a + h2a, size, offset),
                _dense_row(e0a + h1b + h2a, size, offset), _dense_row(e0b + h1b + h2a, size, offset),
                _dense_row(e0a + h1a + h2b, size, offset), _dense_row(e0b + h1a + h2b, size, offset),
                _dense_row(e0a + h1b + h2b, size, offset), _dense_row(e0b + h1b + h2b, size, offset))
    return rows, weights


@njit(inline="always")
def _point2(x, i, scale, hashed, m0, m1, size, offset):
    """Rows (uint64, offset included) and weights of the 4 corners of point i at one D=2 level."""
    a0, b0, t0 = _axis(scale, x[i, 0])
    a1, b1, t1 = _axis(scale, x[i, 1])
    one = np.float32(1.0)
    u0 = one - t0
    u1 = one - t1
    weights = (u0 * u1, t0 * u1, u0 * t1, t0 * t1)
    h1a = a1 * m1
    h1b = b1 * m1
    if hashed:
        mask = size - _ONE_U
        rows = (((a0 ^ h1a) & mask) + offset, ((b0 ^ h1a) & mask) + offset,
                ((a0 ^ h1b) & mask) + offset, ((b0 ^ h1b) & mask) + offset)
    else:
        e0a = a0 * m0
        e0b = b0 * m0
        rows = (_dense_row(e0a + h1a, size, offset), _dense_row(e0b + h1a, size, offset),
                _dense_row(e0a + h1b, size, offset), _dense_row(e0b + h1b, size, offset))
    return rows, weights


# ----------------------------------------------------------------------------------------------------
# Kernels. The per-block loops are plain functions specialized on D and F (``literally``: the corner
# tuples get a fixed length, the F-wide fma is one vector op, the other dimension's code is pruned); the
# parallel drivers are built per (D, F) with both as closure constants (numba caches those per value).
# The loops stay out of the parallel functions because numba's array analysis fails on integer tuples.
# ----------------------------------------------------------------------------------------------------


@njit(cache=True)
def _encode_block(x, table, out, col, i0, i1, scale, hashed, m0, m1, m2, size, offset, gain, D, F):
    """Encode points i0 .. i1 - 1 at one level into ``out[:, col : col + F]``, times ``gain``."""
    literally(D)
    literally(F)
    for i in range(i0, i1):
        if D == 3:
            r3, w3 = _point3(x, i, scale, hashed, m0, m1, m2, size, offset)
            _interp_store(table, out, i, col, r3, w3, gain, F)
        else:
            r2, w2 = _point2(x, i, scale, hashed, m0, m1, size, offset)
            _interp_store(table, out, i, col, r2, w2, gain, F)


@njit(cache=True)
def _corners_block(x, rows_out, w_out, col, i0, i1, scale, hashed, m0, m1, m2, size, offset, D):
    """Corner rows and weights of points i0 .. i1 - 1 at one level into columns col .. col + 2^D - 1."""
    literally(D)
    for i in range(i0, i1):
        if D == 3:
            r3, w3 = _point3(x, i, scale, hashed, m0, m1, m2, size, offset)
            for j in range(8):
                rows_out[i, col + j] = np.int64(r3[j])
                w_out[i, col + j] = w3[j]
        else:
            r2, w2 = _point2(x, i, scale, hashed, m0, m1, size, offset)
            for j in range(4):
                rows_out[i, col + j] = np.int64(r2[j])
                w_out[i, col + j] = w2[j]


@functools.cache
def _encode_kernel(D: int, F: int, layout: str) -> Any:
    if layout == "levels":

        @njit(cache=True, parallel=True)
        def encode_levels_outside(x, table, scales, hashed, mult, sizes, offsets, out, col, block, gain):
            n = x.shape[0]
            nblocks = (n + block - 1) // block
            for lv in range(scales.shape[0]):
                for k in prange(nblocks):
                    _encode_block(x, table, out, col + lv * F, k * block, min(n, (k + 1) * block), scales[lv],
                                  hashed[lv], mult[lv, 0], mult[lv, 1], mult[lv, 2], sizes[lv], offsets[lv], gain, D, F)

        return encode_levels_outside

    if layout == "blocks":

        @njit(cache=True, parallel=True)
        def encode_blocks_outside(x, table, scales, hashed, mult, sizes, offsets, out, col, block, gain):
            n = x.shape[0]
            nblocks = (n + block - 1) // block
            for k in prange(nblocks):
                for lv in range(scales.shape[0]):
                    _encode_block(x, table, out, col + lv * F, k * block, min(n, (k + 1) * block), scales[lv],
                                  hashed[lv], mult[lv, 0], mult[lv, 1], mult[lv, 2], sizes[lv], offsets[lv], gain, D, F)

        return encode_blocks_outside

    raise ValueError(f"unknown layout {layout!r}")


@functools.cache
def _corners_kernel(D: int) -> Any:
    @njit(cache=True, parallel=True)
    def corners_kernel(x, scales, hashed, mult, sizes, offsets, rows_out, w_out, block):
        # rows_out / w_out: (n, L * 2^D); column l * 2^D + j is corner j of level l.
        n = x.shape[0]
        nblocks = (n + block - 1) // block
        for k in prange(nblocks):  # the encoder's "blocks" layout: one parallel region, no barrier per level
            for lv in range(scales.shape[0]):
                _corners_block(x, rows_out, w_out, lv << D, k * block, min(n, (k + 1) * block), scales[lv],
                               hashed[lv], mult[lv, 0], mult[lv, 1], mult[lv, 2], sizes[lv], offsets[lv], D)

    return corners_kernel


# ----------------------------------------------------------------------------------------------------
# Python API
# ----------------------------------------------------------------------------------------------------


def level_constants(cfg: HashGridConfig) -> tuple[np.ndarray, ...]:
    """Per-level arrays the kernels read, from :func:`photon_fields.models_spec.hashgrid.level_specs`: float32 scales,
    bool hashed, uint64 (L, 3) multipliers (hash primes or dense strides; 0 past D), uint64 table sizes,
    uint64 row offsets. Cached per config (level_specs takes ~1.6 ms, a fifth of a 2^14-point encode); do not
    modify."""
    if not isinstance(cfg, HashGridConfig):
        raise TypeError(f"cfg must be a HashGridConfig, got {type(cfg).__name__}")
    return _level_constants(cfg)


@functools.lru_cache(maxsize=64)
def _level_constants(cfg: HashGridConfig) -> tuple[np.ndarray, ...]:
    specs = level_specs(cfg)
    mult = np.zeros((cfg.levels, 3), np.uint64)
    for s in specs:
        if s.hashed and s.table_size & (s.table_size - 1):
            # The kernels reduce hashed indices with a mask; models_spec guarantees 2^T rows when hashed.
            raise AssertionError(f"hashed level {s.level} has {s.table_size} rows, not a power of two")
        for d in range(cfg.dims):
            mult[s.level, d] = int(HASH_PRIMES[d]) if s.hashed else s.dense_strides[d]
    return (np.array([s.scale for s in specs], np.float32), np.array([s.hashed for s in specs], np.bool_), mult,
            np.array([s.table_size for s in specs], np.uint64), np.array([s.offset for s in specs], np.uint64))


def _points(cfg: HashGridConfig, x: Any) -> np.ndarray:
    """x as C-contiguous float32 (n, D), checked like the reference: finite, and ``floor(fma(scale, x, 0.5))``
    inside the int32 range at every level (tcnn's (int) cast)."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    if x.ndim != 2 or x.shape[1] != cfg.dims:
        raise ValueError(f"x must have shape (n, {cfg.dims}), got {x.shape}")
    if x.size:
        # |fma(scale, x, 0.5)| grows with the scale, and the scales grow with the level: the finest decides.
        finest = _level_constants(cfg)[0].max()
        lo, hi = float(x.min()), float(x.max())  # NaN propagates into both
        if not max(-lo, hi) * float(finest) < 2.0**30:  # far from the limit (and finite): the usual case
            if not np.all(np.isfinite(x)):
                raise ValueError("x must be finite")
            if np.any(np.abs(np.floor(fma_f32(finest, x, np.float32(0.5)))) >= 2.0**31):
                raise ValueError("x is too far outside [0, 1]: scale * x + 0.5 must stay within the int32 range")
    return x


def _table(cfg: HashGridConfig, table: Any) -> np.ndarray:
    if not isinstance(table, np.ndarray) or table.dtype != np.float32 or \
            table.shape != (total_table_rows(cfg), cfg.features):
        got = f"{table.dtype} {table.shape}" if isinstance(table, np.ndarray) else type(table).__name__
        raise ValueError(f"table must be a float32 ndarray of shape {(total_table_rows(cfg), cfg.features)}, "
                         f"got {got}")
    return np.ascontiguousarray(table)


def _output(cfg: HashGridConfig, n: int, out: np.ndarray | None, col: Any) -> tuple[np.ndarray, int]:
    if not isinstance(col, (int, np.integer)) or isinstance(col, (bool, np.bool_)) or col < 0:
        raise ValueError(f"col must be an int >= 0, got {col!r}")
    col = int(col)
    if out is None:
        if col:
            raise ValueError("col needs out")
        return np.empty((n, cfg.output_dims), np.float32), col
    if not isinstance(out, np.ndarray) or out.dtype != np.float32 or out.ndim != 2:
        raise ValueError(f"out must be a 2-D float32 ndarray, got "
                         f"{f'{out.dtype} {out.ndim}-D' if isinstance(out, np.ndarray) else type(out).__name__}")
    if out.shape[0] != n or out.shape[1] < col + cfg.output_dims:
        raise ValueError(f"out must have {n} rows and >= {col + cfg.output_dims} columns (col {col} + "
                         f"{cfg.output_dims}), got {out.shape}")
    if out.strides[1] != 4 or out.strides[0] % 4:
        # The kernel stores each level's F features as one vector at out[i, col + l*F].
        raise ValueError(f"out's rows must have contiguous columns (strides (k*4, 4)), got strides {out.strides}")
    if not out.flags.writeable:
        raise ValueError("out is read-only")
    return out, col


def encode(cfg: HashGridConfig, table: np.ndarray, x: np.ndarray, out: np.ndarray | None = None,
           col: int = 0, gain: float = 1.0) -> np.ndarray:
    """Hash-encode points x (n, D) with the flat float32 table: ``out[:, col : col + L*F]`` (float32,
    level-major), equal to ``encode_reference(cfg, table, x)`` bit for bit, times ``gain`` (one float32 product per
    feature: the field's direction gain of a frame's one g, as the separate pass over the rows gave it). Returns
    ``out`` (a new (n, L*F) array when not given). See the module docstring for the parameters."""
    consts = level_constants(cfg)
    table = _table(cfg, table)
    x = _points(cfg, x)
    out, col = _output(cfg, x.shape[0], out, col)
    if x.shape[0] == 0:
        return out
    _encode_kernel(cfg.dims, cfg.features, _LAYOUT)(x, table, *consts, out, col, _BLOCK, np.float32(gain))
    return out


def encode_with_layout(cfg: HashGridConfig, table: np.ndarray, x: np.ndarray, out: np.ndarray, layout: str,
                       block: int) -> np.ndarray:
    """:func:`encode` with another loop layout ("blocks" or "levels") and points per block, for the
    benchmark's layout comparison (same result bit for bit). x is checked as in :func:`encode`; table must
    be a C-contiguous float32 table and out an (n, >= L*F) float32 array with contiguous columns."""
    x = _points(cfg, x)
    _encode_kernel(cfg.dims, cfg.features, layout)(x, table, *level_constants(cfg), out, 0, int(block), np.float32(1.0))
    return out


def aligned_table(table: np.ndarray, alignment: int = 64) -> np.ndarray:
    """A copy of ``table`` (float32, C order) whose data starts on an ``alignment``-byte boundary (a cache
    line), so that no row of 16 or 32 bytes straddles two lines; returned as is when it already does."""
    table = np.asarray(table)
    if table.dtype != np.float32:
        raise ValueError(f"table must be float32, got {table.dtype}")
    if alignment < 1 or alignment & (alignment - 1):
        raise ValueError(f"alignment must be a power of two, got {alignment}")
    if table.flags.c_contiguous and table.ctypes.data % alignment == 0:
        return table
    buf = np.empty(table.nbytes + alignment, np.uint8)
    start = -buf.ctypes.data % alignment
    copy = buf[start:start + table.nbytes].view(np.float32).reshape(table.shape)
    copy[...] = table
    return copy


def corners(cfg: HashGridConfig, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corner rows of the flat table (int64) and weights (float32), both (n, L, 2^D): level l's
    ``corner_indices(cfg, l, x)`` plus ``table_offsets(cfg)[l]``, from the same code as :func:`encode`
    (whose output is the fma chain ``sum_j w[:, l, j] * table[rows[:, l, j]]`` in j order)."""
    consts = level_constants(cfg)
    x = _points(cfg, x)
    n, L, K = x.shape[0], cfg.levels, 1 << cfg.dims
    rows = np.empty((n, L * K), np.int64)
    weights = np.empty((n, L * K), np.float32)
    if n:
        _corners_kernel(cfg.dims)(x, *consts, rows, weights, _BLOCK)
    return rows.reshape(n, L, K), weights.reshape(n, L, K)

