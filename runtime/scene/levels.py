"""Coarser levels of a scene's volume: what the preview marches while a person drags the view or edits the
transfer function or the lights of a large volume (the interactive level of desktop volume renderers).

Parameters
----------
level : int
    Level k averages blocks of 2^k x 2^k x 2^k voxels (level 0 is the volume itself).
INTERACTIVE_SIDE : int
    :func:`interactive_level` picks the least level whose longest side has at most this many voxels.

The preview's cost grows with the volume's resolution (samples per ray, light-volume cells and their shadow rays,
the medium's and the step grids' passes), the neural renderer's hardly: at 256^3 a transfer-function edit's first
preview frame took 1.6 s (bench/README.md, ray marcher). A level keeps the scene's box, so a camera, the lights and
every world position mean the same on it; only the grid is coarser:

- a continuous volume's scalar is averaged over each block (before classification, as a resampled data set is in
  ParaView's level of detail: a wall one or two voxels thick comes out optically thicker, up to +5 % in the mean of
  the embedded shell at 256^3);
- a label volume takes each block's voxel nearest its centre (labels are never averaged: no label the volume does
  not have can appear), and its transfer function is restricted to the labels the level still has.

Sides that are not a multiple of the block are padded with their last voxel; the level's voxels are then stretched
to fill the box (by less than 1 / (side / 2^k) of it). Levels are made once per volume and kept on it
(:attr:`photon_fields.runtime.scene.volume.Volume`'s cache), so a transfer-function edit reuses them; a scene's
level (:func:`scene_at_level`) is kept in its shared cache with its medium, light volume and step grids, and a
light edit's scene adopts its medium as the full level's (:meth:`photon_fields.runtime.scene.scene.Scene.adopt_medium`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from photon_fields.runtime.scene.labels import LabelTransfer, volume_labels
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.volume import Volume

#: The longest side, in voxels, of the level :func:`interactive_level` picks (bench/README.md, ray marcher).
INTERACTIVE_SIDE = 128
#: The coarsest level made: blocks of 2^5 = 32 voxels a side.
MAX_LEVEL = 5


def interactive_level(dims: tuple[int, ...], side: int = INTERACTIVE_SIDE) -> int:
    """The least level whose longest side has at most ``side`` voxels (0 for volumes up to that size)."""
    longest = max(int(n) for n in dims)
    if longest <= side:
        return 0
    return min(MAX_LEVEL, math.ceil(math.log2(longest / side)))


def check_level(level: int, what: str = "level") -> int:
    """``level`` as an int in 0 .. :data:`MAX_LEVEL` (ValueError naming ``what`` otherwise)."""
    if isinstance(level, bool) or not isinstance(level, (int, np.integer)) or not 0 <= int(level) <= MAX_LEVEL:
        raise ValueError(f"{what} must be an integer in 0..{MAX_LEVEL}, got {level!r}")
    return int(level)


def _padded(data: np.ndarray, f: int) -> np.ndarray:
    """``data`` padded with its last voxel along each axis to a multiple of ``f``."""
    pad = [(0, -n % f) for n in data.shape]
    return np.pad(data, pad, mode="edge") if any(p for _, p in pad) else data


def block_mean(data: np.ndarray, f: int) -> np.ndarray:
    """The mean over each f x f x f block (sides padded to a multiple of ``f`` first), float32; the sum is taken
    slice by slice of blocks, in float64, so that memory stays ~1 / f^2 of the volume's beyond the result."""
    nx, ny, nz = (-(-n // f) for n in data.shape)
    out = np.empty((nx, ny, nz), np.float32)
    for i in range(nx):  # the last slab of a side that is not a multiple of f is padded along x too
        slab = _padded(np.asarray(data[i * f:(i + 1) * f], dtype=np.float64), f)
        out[i] = slab.reshape(f, ny, f, nz, f).mean(axis=(0, 2, 4))
    return out


def block_centres(data: np.ndarray, f: int) -> np.ndarray:
    """Each f x f x f block's voxel nearest its centre (index f // 2 within the block, clamped to the volume)."""
    idx = [np.minimum(np.arange(-(-n // f)) * f + f // 2, n - 1) for n in data.shape]
    return np.ascontiguousarray(data[np.ix_(*idx)], dtype=np.float32)


def coarser_volume(volume: Volume, level: int, labels: bool = False) -> Volume:
    """``volume`` at ``level`` (module docstring): the block mean, or with ``labels`` each block's centre voxel;
    the same box, window and value range. Made once per (level, labels) and kept on ``volume``."""
    level = check_level(level)
    if level == 0:
        return volume
    cache = volume._levels
    key = (level, bool(labels))
    if key not in cache:
        f = 1 << level
        data = block_centres(volume.data, f) if labels else block_mean(volume.data, f)
        spacing = tuple(float(s) * n / c for s, n, c in zip(volume.spacing, volume.dims, data.shape, strict=True))
        cache[key] = Volume(data=data, spacing=spacing, name=f"{volume.name} (level {level})",  # type: ignore[arg-type]
                            window=volume.window, value_range=volume.value_range)
    return cache[key]


def _labels_kept(tf: LabelTransfer, volume: Volume) -> LabelTransfer | None:
    """``tf`` restricted to the labels ``volume`` has (None if it names none of them)."""
    keep = np.isin(tf.labels, volume_labels(volume, tf.name).values)
    if not keep.any():
        return None
    if keep.all():
        return tf
    return LabelTransfer(tf.labels[keep], tf.albedo[keep], tf.opacity[keep], tf.density_scale, tf.name)


def scene_at_level(scene: Scene, level: int) -> Scene:
    """``scene`` on its volume's ``level`` (module docstring): the same transfer function (a label function
    restricted to the labels the level has), lights, camera and g. The level's scene (its medium, light volume,
    step grids) is kept in ``scene``'s shared cache ``"levels"``, which camera and g overrides share; level 0, and a
    label level that keeps none of the function's labels, is ``scene`` itself."""
    level = check_level(level)
    if level == 0:
        return scene
    levels = scene.shared_cache("levels")
    if level not in levels:
        labels = isinstance(scene.tf, LabelTransfer)
        volume = coarser_volume(scene.volume, level, labels)
        tf = _labels_kept(scene.tf, volume) if labels else scene.tf
        if tf is None:
            return scene
        levels[level] = replace(scene, volume=volume, tf=tf, name=f"{scene.name} (level {level})", _cache={})
    levels[level].medium()  # built on the kept scene, which the overrides below then share
    return levels[level].with_overrides(g=scene.g, camera=scene.camera)
