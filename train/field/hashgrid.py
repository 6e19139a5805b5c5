"""Trainable multiresolution hash encoding (paper Sec. 3.4) for CPU training, bit-exact with the reference.

:class:`HashGridEncoding` is tiny-cuda-nn's ``HashGrid`` as specified in :mod:`photon_fields.models_spec.hashgrid`: same
level geometry, same flat table layout (``table_offsets``), same corner indices and weights, and the same
float32 rounding. Its output equals :func:`photon_fields.models_spec.hashgrid.encode_reference` bit for bit, and the
table gradient equals :func:`photon_fields.models_spec.hashgrid.table_gradient_reference` bit for bit.

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
The forward and the corner math are the runtime's (:mod:`runtime.field.hashgrid`, numba, no torch), so training
and rendering evaluate the encoding with one implementation:

1. forward: :func:`photon_fields.runtime.field.hashgrid.encode`, the fused kernel (cell, corner rows and weights, and
   ``acc = fma(w_j, table[row_j], acc)`` with a single-rounding fma; see that module for its layout). It
   reads the parameter's storage in place; only the points are kept for the backward;
2. backward: :func:`runtime.field.hashgrid.corners` recomputes the (n, L, 2^D) corner rows and weights (instead
   of keeping 12 bytes per corner, ~100 MB at 2^16 points, alive from forward to backward), then
   ``_scatter_kernel`` (parallel over *levels*) adds ``grad[row] = fma(w_j, dL/dout, grad[row])``.
   Levels own disjoint rows, so no two threads touch one row and each row sees its additions in
   (point, corner) order: the gradient is bit-identical for any thread count, no atomics.

Why the torch-free kernels: a pure-torch scheme (int64 index math + ``F.embedding_bag``; same function, its
output bit-identical) makes many full passes over (n, L, D) and (n, L, 2^D) float64 / int64 tensors, and
``embedding_bag``'s dense CPU backward is slow for the n L 2^D lookups. The gradient is dense, as in tcnn,
so an optimizer step touches all ``rows * F`` parameters. ``bench/bench_hashgrid.py`` measures both
schemes (bench/README.md).

Threads: the kernels use numba's thread pool (``photon_fields.runtime.threads``), not torch's. Kernels are
compiled on first use and cached on disk (``cache=True``).
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from photon_fields.models_spec.hashgrid import HashGridConfig, total_table_rows
from photon_fields.runtime.field.hashgrid import corners as _runtime_corners
from photon_fields.runtime.field.hashgrid import encode as _runtime_encode
from photon_fields.runtime.field.hashgrid import fma32, level_constants


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
                    grad_table[r, f] = fma32(w, grad_out[i, lv * F + f], grad_table[r, f])


class _HashGridLookup(torch.autograd.Function):
    """out = photon_fields.runtime.field.hashgrid.encode(cfg, table, x); gradient for the table only (x is data)."""

    @staticmethod
    def forward(ctx: torch.autograd.function.FunctionCtx, table: torch.Tensor, x: np.ndarray,
                cfg: HashGridConfig) -> torch.Tensor:
        out = _runtime_encode(cfg, table.detach().contiguous().numpy(), x)
        # The backward recomputes the corners from the points: a copy (n * D floats), since x may share the
        # caller's tensor storage, which could change before backward.
        ctx.x = x.copy() if ctx.needs_input_grad[0] else None
        ctx.cfg = cfg
        return torch.from_numpy(out)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx: torch.autograd.function.FunctionCtx, grad_out: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        cfg = ctx.cfg
        rows, weights = _runtime_corners(cfg, ctx.x)
        n, width = rows.shape[0], cfg.levels << cfg.dims
        g = grad_out.to(torch.float32).contiguous().numpy()
        # np.zeros: lazily zeroed pages are cheaper than torch.zeros' memset for the 100s of MB here.
        grad = np.zeros((total_table_rows(cfg), cfg.features), dtype=np.float32)
        _scatter_kernel(rows.reshape(n, width), weights.reshape(n, width), g, cfg.levels, grad)
        return torch.from_numpy(grad), None, None


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
        level_constants(cfg)  # validates and caches the per-level constants the kernels read

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
        # Non-finite or far-out points are rejected by the runtime's kernels, exactly as the reference does.
        return x.detach().to(torch.float32).contiguous().numpy()

    def corners(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Corner rows of the flat table (int64) and weights (float32), both (n, L, 2^D): the reference's
        ``corner_indices(cfg, l, x)`` plus ``table_offsets(cfg)[l]``, per level
        (:func:`runtime.field.hashgrid.corners`)."""
        rows, weights = _runtime_corners(self.cfg, self._points(x))
        return torch.from_numpy(rows), torch.from_numpy(weights)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.table.device.type != "cpu" or self.table.dtype != torch.float32:
            raise ValueError("HashGridEncoding runs on the CPU with a float32 table")
        return _HashGridLookup.apply(self.table, self._points(x), self.cfg)
