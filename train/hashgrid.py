"""Trainable multiresolution hash encoding (paper Sec. 3.4) for CPU training, bit-exact with the reference.

:class:`HashGridEncoding` is tiny-cuda-nn's ``HashGrid`` as specified in :mod:`models_spec.hashgrid`: same
level geometry, same flat table layout (``table_offsets``), same corner indices and weights, and the same
float32 rounding. Its output equals :func:`models_spec.hashgrid.encode_reference` bit for bit, and the
table gradient equals :func:`models_spec.hashgrid.table_gradient_reference` bit for bit.

Parameters
----------
cfg : HashGridConfig
    Levels L, features F, table size 2^T, N_min, per-level scale b, input dims D (3 positions, 2 directions).
seed : int (default 0)
    Seeds a fresh ``torch.Generator`` for the table initialization when ``generator`` is not given.
generator : torch.Generator, optional
    Draws the initial table, uniform in [-1e-4, 1e-4] as tcnn does.

The module has one parameter, ``table``: float32 ``(total_table_rows(cfg), F)``, level l in rows
``table_offsets(cfg)[l] : table_offsets(cfg)[l + 1]`` (so a tcnn parameter vector reshaped to (-1, F)
loads directly). ``forward(x)`` maps ``x`` (n, D) in [0, 1]^D (cast to float32, tcnn's input type) to
float32 (n, L * F), level-major. It is differentiable with respect to ``table`` only: ``x`` gets no
gradient (positions and directions are data here; tcnn's dL/dx is not needed by the paper).

Implementation and speed
------------------------
Three numba kernels behind one ``torch.autograd.Function``:

1. ``_corners_kernel`` (parallel over points): per point and level, ``pos = fma(scale, x, 0.5)`` with a
   true single-rounding fma (``llvm.fma.f32``), the 2^D corner rows (uint32 arithmetic in uint64
   registers, masked to 32 bits where tcnn's uint32 wraps: the hash products, the dense sum) already
   offset into the flat table, and the float32 weights multiplied in dimension order;
2. ``_gather_kernel`` (parallel over points): ``acc = fma(w_j, table[row_j], acc)`` over the corners, the
   accumulation tcnn gets from nvcc's fma contraction and torch's ``embedding_bag`` from fbgemm;
3. ``_scatter_kernel`` (backward, parallel over *levels*): ``grad[row] = fma(w_j, dL/dout, grad[row])``.
   Levels own disjoint rows, so no two threads touch one row and each row sees its additions in
   (point, corner) order: the gradient is bit-identical for any thread count, no atomics.

Measured on this machine (2 weak cores, otherwise idle: other processes used < 0.05 core), n = 2^16
points, 2 threads, best of 5, ``bench/bench_hashgrid.py`` (results in ``bench/results/hashgrid.json``):

=============================================================  =========  ==================
scheme, config                                                 forward    forward + backward
=============================================================  =========  ==================
this module, paper D=3 (16 levels x 8 features, 2^19 tables)   166 ms     417 ms
this module, paper D=2 (same, directions)                      83 ms      240 ms
pure torch (int64 index math + ``F.embedding_bag``), D=3       719 ms     2727 ms
=============================================================  =========  ==================

The pure-torch scheme (same function: its output is bit-identical) loses in both halves: its index math
makes many full passes over (n, L, D) and (n, L, 2^D) float64 / int64 tensors (~0.5 s, against ~60 ms
for ``_corners_kernel``), and ``embedding_bag``'s dense CPU backward takes ~2 s for the n L 2^D = 8.4 M
lookups; its forward gather alone is no faster than ``_gather_kernel`` (~0.1 s). Of the module's
backward (~250 ms) the scatter is nearly all; the 228 MB gradient comes from ``np.zeros`` (lazily zeroed
pages, cheaper than ``torch.zeros``' memset). On a loaded machine (load 2-3) the figures grow 1.5-2x.
The gradient is dense, as in tcnn, so an optimizer step touches all ``rows * F`` parameters (57 M for
the paper's D=3 table): in a training step that update, not the encoding, is likely the larger cost.

Threads: the kernels use numba's thread pool (``numba.set_num_threads``; ``runtime.cli_common.set_threads``),
not torch's. Kernels are compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
import torch
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic

from models_spec.hashgrid import HASH_PRIMES, HashGridConfig, level_specs, total_table_rows

_MASK = np.uint64(0xFFFFFFFF)
_ONE_U = np.uint64(1)


@intrinsic
def _fma32(typingctx, a, b, c):  # numba intrinsic: arguments are numba types
    """float32 fused multiply-add with one rounding (LLVM lowers it to vfmadd or a correct libm call)."""
    sig = types.float32(types.float32, types.float32, types.float32)

    def codegen(context, builder, signature, args):  # llvmlite IR builder callback
        f32 = ir.FloatType()
        fn = builder.module.declare_intrinsic("llvm.fma", [f32], ir.FunctionType(f32, [f32, f32, f32]))
        return builder.call(fn, args)

    return sig, codegen


@njit(cache=True, parallel=True)
def _corners_kernel(x: np.ndarray, scales: np.ndarray, hashed: np.ndarray, mult: np.ndarray, sizes: np.ndarray,
                    offsets: np.ndarray, rows_out: np.ndarray, w_out: np.ndarray) -> None:
    # rows_out / w_out: (n, L * 2^D); column l * 2^D + j is corner j of level l (bit d of j: +1 in dim d).
    n, D = x.shape
    L = scales.shape[0]
    K = 1 << D
    for i in prange(n):
        cell = np.empty(3, np.uint64)
        frac = np.empty(3, np.float32)
        for lv in range(L):
            for d in range(D):
                p = _fma32(scales[lv], x[i, d], np.float32(0.5))
                fl = np.floor(p)
                frac[d] = p - fl  # exact in float32
                cell[d] = np.uint64(np.int64(fl)) & _MASK  # tcnn: (uint32_t)(int) floorf(pos)
            for j in range(K):
                w = np.float32(1.0)
                index = np.uint64(0)
                for d in range(D):
                    if (j >> d) & 1:
                        w = w * frac[d]
                        c = (cell[d] + _ONE_U) & _MASK
                    else:
                        w = w * (np.float32(1.0) - frac[d])
                        c = cell[d]
                    if hashed[lv]:
                        index ^= (c * mult[lv, d]) & _MASK  # c * prime mod 2^32
                    else:
                        index += c * mult[lv, d]  # wraps mod 2^64; the low 32 bits are tcnn's uint32 sum
                rows_out[i, lv * K + j] = np.int64((index & _MASK) % sizes[lv] + offsets[lv])
                w_out[i, lv * K + j] = w


@njit(cache=True, parallel=True)
def _gather_kernel(rows: np.ndarray, weights: np.ndarray, table: np.ndarray, levels: int, out: np.ndarray) -> None:
    n = rows.shape[0]
    K = rows.shape[1] // levels
    F = table.shape[1]
    for i in prange(n):
        acc = np.empty(8, np.float32)
        for lv in range(levels):
            for f in range(F):
                acc[f] = np.float32(0.0)
            for j in range(K):
                r = rows[i, lv * K + j]
                w = weights[i, lv * K + j]
                for f in range(F):
                    acc[f] = _fma32(w, table[r, f], acc[f])
            for f in range(F):
                out[i, lv * F + f] = acc[f]


@njit(cache=True, parallel=True)
def _scatter_kernel(rows: np.ndarray, weights: np.ndarray, grad_out: np.ndarray, levels: int,
                    grad_table: np.ndarray) -> None:
    # One level per task: levels own disjoint rows, so this is race-free and deterministic.
    n = rows.shape[0]
    K = rows.shape[1] // levels
    F = grad_table.shape[1]
    for lv in prange(levels):
        for i in range(n):
            for j in range(K):
                r = rows[i, lv * K + j]
                w = weights[i, lv * K + j]
                for f in range(F):
                    grad_table[r, f] = _fma32(w, grad_out[i, lv * F + f], grad_table[r, f])


class _HashGridLookup(torch.autograd.Function):
    """out[i, l*F + f] = sum_j w[i, l, j] * table[rows[i, l, j], f] (fma chain); gradient for table only."""

    @staticmethod
    def forward(ctx: torch.autograd.function.FunctionCtx, table: torch.Tensor, rows: torch.Tensor,
                weights: torch.Tensor, levels: int) -> torch.Tensor:
        out = np.empty((rows.shape[0], levels * table.shape[1]), dtype=np.float32)
        _gather_kernel(rows.numpy(), weights.numpy(), table.detach().contiguous().numpy(), levels, out)
        ctx.save_for_backward(rows, weights)
        ctx.levels = levels
        ctx.table_shape = tuple(table.shape)
        return torch.from_numpy(out)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx: torch.autograd.function.FunctionCtx, grad_out: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        rows, weights = ctx.saved_tensors
        g = grad_out.to(torch.float32).contiguous().numpy()
        # np.zeros: lazily zeroed pages are cheaper than torch.zeros' memset for the 100s of MB here.
        grad = np.zeros(ctx.table_shape, dtype=np.float32)
        _scatter_kernel(rows.numpy(), weights.numpy(), g, ctx.levels, grad)
        return torch.from_numpy(grad), None, None, None


class HashGridEncoding(torch.nn.Module):
    """tcnn HashGrid encoding with one float32 parameter ``table`` (see the module docstring)."""

    def __init__(self, cfg: HashGridConfig, *, seed: int = 0, generator: torch.Generator | None = None) -> None:
        super().__init__()
        if not isinstance(cfg, HashGridConfig):
            raise TypeError(f"cfg must be a HashGridConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        if generator is None:
            generator = torch.Generator().manual_seed(int(seed))
        table = torch.empty(total_table_rows(cfg), cfg.features, dtype=torch.float32)
        table.uniform_(-1e-4, 1e-4, generator=generator)
        self.table = torch.nn.Parameter(table)
        # Per-level constants as tcnn computes them (models_spec); numpy, because only the kernels read them.
        specs = level_specs(cfg)
        self._scales = np.array([s.scale for s in specs], dtype=np.float32)
        self._hashed = np.array([s.hashed for s in specs], dtype=np.bool_)
        self._mult = np.array([[int(HASH_PRIMES[d]) if s.hashed else s.dense_strides[d] for d in range(cfg.dims)]
                               for s in specs], dtype=np.uint64)
        self._sizes = np.array([s.table_size for s in specs], dtype=np.uint64)
        self._offsets = np.array([s.offset for s in specs], dtype=np.uint64)
        # pos = scale * x + 0.5 must stay inside the int32 range of tcnn's (int) cast.
        self._max_abs_x = (2.0**31 - 2.0) / float(self._scales.max()) if float(self._scales.max()) > 0 else np.inf

    @property
    def output_dims(self) -> int:
        return self.cfg.output_dims

    def extra_repr(self) -> str:
        c = self.cfg
        return (f"dims={c.dims}, levels={c.levels}, features={c.features}, log2_table_size={c.log2_table_size}, "
                f"base_resolution={c.base_resolution}, per_level_scale={c.per_level_scale}, rows={self.table.shape[0]}")

    def _points(self, x: torch.Tensor) -> np.ndarray:
        if not isinstance(x, torch.Tensor):
            raise TypeError(f"x must be a torch.Tensor, got {type(x).__name__}")
        if x.dim() != 2 or x.shape[1] != self.cfg.dims:
            raise ValueError(f"x must have shape (n, {self.cfg.dims}), got {tuple(x.shape)}")
        if not x.is_floating_point() or x.device.type != "cpu":
            raise ValueError(f"x must be a floating-point CPU tensor, got {x.dtype} on {x.device}")
        xn = x.detach().to(torch.float32).contiguous().numpy()
        if xn.size:
            if not np.isfinite(xn).all():
                raise ValueError("x must be finite")
            if float(np.abs(xn).max()) > self._max_abs_x:
                raise ValueError("x is too far outside [0, 1]: scale * x + 0.5 must stay within the int32 range")
        return xn

    def corners(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Corner rows of the flat table (int64) and weights (float32), both (n, L, 2^D): the reference's
        ``corner_indices(cfg, l, x)`` plus ``table_offsets(cfg)[l]``, per level."""
        xn = self._points(x)
        n, K, L = xn.shape[0], 1 << self.cfg.dims, self.cfg.levels
        rows = np.empty((n, L * K), dtype=np.int64)
        weights = np.empty((n, L * K), dtype=np.float32)
        _corners_kernel(xn, self._scales, self._hashed, self._mult, self._sizes, self._offsets, rows, weights)
        return torch.from_numpy(rows).view(n, L, K), torch.from_numpy(weights).view(n, L, K)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.table.device.type != "cpu" or self.table.dtype != torch.float32:
            raise ValueError("HashGridEncoding runs on the CPU with a float32 table")
        rows, weights = self.corners(x)
        n, width = rows.shape[0], self.cfg.levels << self.cfg.dims
        return _HashGridLookup.apply(self.table, rows.view(n, width), weights.view(n, width), self.cfg.levels)
