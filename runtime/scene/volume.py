"""Scalar volumes: a normalized scalar grid placed in an axis-aligned box.

Conventions (shared by every renderer and by training):

- ``Volume.data`` is a float32 array of shape ``(nx, ny, nz)`` indexed ``[x, y, z]`` with values in
  [0, 1] (normalized by a window, see :func:`normalize_window`).
- Voxels are cell-centred: voxel ``(i, j, k)`` sits at normalized position ``((i + .5)/nx, ...)``.
- The world-space box is centred at the origin and its size is ``dims * spacing`` scaled so that the
  longest side is 1. Aspect ratio and anisotropic spacing are respected; the physical unit drops out,
  so a transfer function's density scale (extinction per unit length) means the same thing for every
  volume: "per longest box side".
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from photon_fields.runtime.errors import InputError


@dataclass(frozen=True, eq=False)
class Volume:
    """A normalized scalar grid in a box. Build it with :func:`make_volume` or a reader."""

    data: np.ndarray
    spacing: tuple[float, float, float] = (1.0, 1.0, 1.0)
    name: str = "volume"
    _fingerprint: list = field(default_factory=list, repr=False)  # lazily computed cache

    @property
    def dims(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self.data.shape)  # type: ignore[return-value]

    @property
    def extent(self) -> np.ndarray:
        """World-space size of the box (longest side 1)."""
        size = np.asarray(self.dims, dtype=np.float64) * np.asarray(self.spacing, dtype=np.float64)
        return size / size.max()

    @property
    def bbox_min(self) -> np.ndarray:
        return -0.5 * self.extent

    @property
    def bbox_max(self) -> np.ndarray:
        return 0.5 * self.extent

    @property
    def voxel_size(self) -> float:
        """Smallest world-space voxel edge (a natural step length for marching)."""
        return float(np.min(self.extent / np.asarray(self.dims, dtype=np.float64)))

    def fingerprint(self) -> str:
        """sha256 of the normalized data, its shape and spacing: identifies the volume in bundles/maps."""
        if not self._fingerprint:
            h = hashlib.sha256()
            h.update(np.asarray(self.dims, dtype=np.int64).tobytes())
            h.update(np.asarray(self.spacing, dtype=np.float64).tobytes())
            data = np.ascontiguousarray(self.data, dtype=np.float32)
            for plane in data:  # chunked so a large volume does not need a second full copy
                h.update(plane.tobytes())
            self._fingerprint.append(h.hexdigest())
        return self._fingerprint[0]


def normalize_window(
    raw: np.ndarray, window: tuple[float, float] | None = None, what: str = "volume", chunk_voxels: int = 1 << 24
) -> np.ndarray:
    """Map ``raw`` to float32 in [0, 1] with ``(v - lo) / (hi - lo)`` clipped; default window = data min/max.

    Works chunk by chunk along the first axis so that a memory-mapped input is streamed, not loaded
    twice. Raises :class:`InputError` on NaN/inf voxels or an empty/degenerate window.
    """
    if raw.ndim != 3:
        raise InputError(what, f"expected a 3-D scalar grid, got shape {tuple(raw.shape)}")
    if min(raw.shape) < 2:
        raise InputError(what, f"every dimension must be at least 2 voxels, got shape {tuple(raw.shape)}")
    if not (np.issubdtype(raw.dtype, np.number) and not np.issubdtype(raw.dtype, np.complexfloating)):
        raise InputError(what, f"unsupported dtype {raw.dtype}; expected an integer or float scalar type")
    step = max(1, chunk_voxels // max(1, raw.shape[1] * raw.shape[2]))
    is_float = np.issubdtype(raw.dtype, np.floating)
    lo_d, hi_d = np.inf, -np.inf
    for s in range(0, raw.shape[0], step):
        block = np.asarray(raw[s : s + step])
        if is_float and not np.all(np.isfinite(block)):
            bad = np.argwhere(~np.isfinite(block))[0]
            index = tuple(int(i) for i in (bad[0] + s, *bad[1:]))
            raise InputError(what, f"non-finite voxel value (NaN or inf) at index {index}")
        lo_d = min(lo_d, float(block.min()))
        hi_d = max(hi_d, float(block.max()))
    if window is None:
        lo, hi = lo_d, hi_d
        if hi <= lo:  # constant volume: map it to 1 so it is visible, not to 0/0
            return np.ones(raw.shape, dtype=np.float32)
    else:
        lo, hi = float(window[0]), float(window[1])
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
            raise InputError(what, f"window [{lo}, {hi}] must be finite with low < high")
    out = np.empty(raw.shape, dtype=np.float32)
    scale = 1.0 / (hi - lo)
    for s in range(0, raw.shape[0], step):
        block = np.asarray(raw[s : s + step], dtype=np.float64)
        out[s : s + step] = np.clip((block - lo) * scale, 0.0, 1.0)
    return out


def make_volume(
    raw: np.ndarray,
    spacing: tuple[float, float, float] | list[float] = (1.0, 1.0, 1.0),
    window: tuple[float, float] | None = None,
    name: str = "volume",
) -> Volume:
    """Build a :class:`Volume` from an array indexed ``[x, y, z]`` (normalized by ``window``)."""
    sp = tuple(float(s) for s in spacing)
    if len(sp) != 3 or not all(np.isfinite(s) and s > 0 for s in sp):
        raise InputError(f"{name} spacing", f"must be three positive numbers, got {list(spacing)}")
    data = normalize_window(np.asarray(raw) if not isinstance(raw, np.memmap) else raw, window, what=name)
    return Volume(data=np.ascontiguousarray(data), spacing=sp, name=name)  # type: ignore[arg-type]
