"""Scalar volumes: a normalized scalar grid placed in an axis-aligned box.

Conventions (shared by every renderer and by training):

- ``Volume.data`` is a float32 array of shape ``(nx, ny, nz)`` indexed ``[x, y, z]`` with values in
  [0, 1] (normalized by a window, see :func:`normalize_window`).
- Voxels are cell-centred: voxel ``(i, j, k)`` sits at normalized position ``((i + .5)/nx, ...)``.
- The world-space box is centred at the origin and its size is ``dims * spacing`` scaled so that the
  longest side is 1. Aspect ratio and anisotropic spacing are respected; the physical unit drops out,
  so a transfer function's density scale (extinction per unit length) means the same thing for every
  volume: "per longest box side".
- ``Volume.window`` records the raw values mapped to 0 and 1 and ``Volume.value_range`` the raw data's own
  min/max (both None for a volume built without :func:`make_volume`). They cost nothing and make the raw
  values recoverable, ``raw = lo + data * (hi - lo)``, which is what a label volume's categorical transfer
  function needs (:mod:`photon_fields.runtime.scene.labels`): the renderers keep one normalized grid, and label
  identity is recovered exactly (to well under half a label for value ranges below 2^20) when a label
  transfer function is bound to the volume. They are not part of :meth:`Volume.fingerprint` (that would change
  every existing volume's fingerprint); :meth:`Volume.label_fingerprint` adds them for label scenes.
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
    #: Raw values mapped to 0 and 1 by the normalization (module docstring); None if unknown.
    window: tuple[float, float] | None = None
    #: Raw data min and max (before clipping to the window); None if unknown.
    value_range: tuple[float, float] | None = None
    _fingerprint: list = field(default_factory=list, repr=False)  # lazily computed cache
    #: Lazily computed label grid (photon_fields.runtime.scene.labels.volume_labels), reused across media.
    _labels: list = field(default_factory=list, repr=False)
    #: Lazily made coarser levels (photon_fields.runtime.scene.levels.coarser_volume), reused across media.
    _levels: dict = field(default_factory=dict, repr=False)
    #: Lazily computed per-macrocell scalar ranges (photon_fields.runtime.transport.medium.scalar_ranges; float32,
    #: 1/4 of the volume's bytes at 2-voxel macrocells), reused across media: an edit's majorant is table lookups.
    _majorant_ranges: dict = field(default_factory=dict, repr=False)

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

    def label_fingerprint(self) -> str:
        """:meth:`fingerprint` extended by the raw window: two label volumes with the same normalized grid but
        different raw labels (e.g. labels {0, 1, 2} and {0, 2, 4}) are different media under one label
        transfer function, whose keys are raw labels."""
        h = hashlib.sha256(self.fingerprint().encode())
        h.update(np.asarray(self.window if self.window is not None else (np.nan, np.nan), np.float64).tobytes())
        return h.hexdigest()


def normalize_window(
    raw: np.ndarray, window: tuple[float, float] | None = None, what: str = "volume", chunk_voxels: int = 1 << 24
) -> np.ndarray:
    """Map ``raw`` to float32 in [0, 1] with ``(v - lo) / (hi - lo)`` clipped; default window = data min/max.

    Works chunk by chunk along the first axis so that a memory-mapped input is streamed, not loaded
    twice. Raises :class:`InputError` on NaN/inf voxels or an empty/degenerate window.
    """
    return normalize_with_window(raw, window, what, chunk_voxels)[0]


def normalize_with_window(
    raw: np.ndarray, window: tuple[float, float] | None = None, what: str = "volume", chunk_voxels: int = 1 << 24
) -> tuple[np.ndarray, tuple[float, float], tuple[float, float]]:
    """:func:`normalize_window`, also returning the window used (raw values mapped to 0 and 1) and the raw
    data's min and max. A constant volume (mapped to 1) reports the window ``(v - 1, v)``, so that
    ``lo + 1 * (hi - lo)`` still recovers its value ``v``."""
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
            return np.ones(raw.shape, dtype=np.float32), (lo - 1.0, lo), (lo_d, hi_d)
    else:
        lo, hi = float(window[0]), float(window[1])
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
            raise InputError(what, f"window [{lo}, {hi}] must be finite with low < high")
    out = np.empty(raw.shape, dtype=np.float32)
    scale = 1.0 / (hi - lo)
    for s in range(0, raw.shape[0], step):
        block = np.asarray(raw[s : s + step], dtype=np.float64)
        out[s : s + step] = np.clip((block - lo) * scale, 0.0, 1.0)
    return out, (lo, hi), (lo_d, hi_d)


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
    data, win, value_range = normalize_with_window(np.asarray(raw) if not isinstance(raw, np.memmap) else raw,
                                                   window, what=name)
    return Volume(data=np.ascontiguousarray(data), spacing=sp, name=name, window=win,  # type: ignore[arg-type]
                  value_range=value_range)
