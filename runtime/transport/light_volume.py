"""The ray marcher's light volume: each delta light's transmittance on a grid of cells, marched when first read.

Parameters
----------
cells_per_voxel : float (default :func:`auto_cells_per_voxel`: 1, fewer for volumes over ~320^3 voxels)
    Grid cells per voxel along each axis (:func:`new_light_volume`). Finer grids resolve the light's fall-off
    across a dense, sharp wall (a skull, a shell) better and cost memory (4 bytes per cell and light) and a march
    per cell read. The default keeps a light's volume within :data:`AUTO_CELLS` cells (128 MiB): at one cell per
    voxel a 512^3 scan with two lights would take 1 GiB, and a frame reads it at random.
shadow_step : float
    Base step of each cell's shadow ray, in world units (the renderer passes :data:`DEFAULT_SHADOW_STEP` voxels).
units : numpy.ndarray or None
    Base steps per segment of the cells' shadow rays, per macrocell (:mod:`photon_fields.runtime.transport.step_grid`;
    the renderer passes up to :data:`SHADOW_SPAN`); None: every base step sampled.

A shadow ray per camera sample and light made the ray marcher the slowest renderer on dense media (each sample
marched a ray through the volume to every light). A light's transmittance does not depend on the camera, so the
preview caches it: ``T(c -> light)`` at the centre of every cell c that a sample reads, interpolated trilinearly at
the sample (an approximation of the per-sample shadow ray; bench/README.md, ray marcher, says how close). A cell is
marched when a camera sample's stencil first reaches it, so a frame pays only for the cells near what the camera
sees (a few per cent of the grid on a dense volume, where rays stop at the surface), and later frames of the same
scene (camera moves, progressive passes) find them filled. The renderer does it in two passes: a ray whose
sample finds an unfilled corner (:func:`light_transmittance` returns -1) marks, from there to its end, the cells
its samples read (:func:`want_stencil`) instead of summing them; the marked cells are marched
(:func:`fill_wanted`), and those rays are marched once more from the same random state, so the image is the one a
filled volume gives. Marking also flags the cell's brick (:data:`BRICK` cells a side), and the fill looks for
marked cells in flagged bricks only: a resting view's frames keep finding a few hundred new cells (its jittered
samples reach a little further each frame), and a scan of the whole grid for them (34M entries at 256^3) cost more
than the rest of such a frame.

**A margin in idle time.** A resting view's later frames and the next views after a small camera move read cells
just beside those filled for the frames before (a pixel's jitter moves its stencil across cell centres; a view a few
degrees on sees the same surfaces): each such frame marks a few hundred cells and marches its rays twice, and the
first full frame after a 5-degree orbit of a 256^3 head took 3x as long as with its cells filled (bench/README.md,
ray marcher, "idle time"). Filling those cells up front would make every change's first frame wait longer. So a fill
remembers the bricks where it filled cells that frames asked for (``LightVolume.margin``), and
:func:`fill_margin`, for a caller with nothing else to do (the viewer between changes), fills every unfilled cell
among the 26 around each filled cell of those bricks (:data:`NEIGHBOUR`), once: the cells it fills do not flag their
bricks, so each idle moment adds one ring around the bricks that frames filled in since the last, never a flood (a
brick that frames fill in again spreads from every filled cell of it, the last ring's included). The marks are a
filled cell's neighbours, its values those of any fill: the images do not change.

Marking and filling race benignly: a cell's value is a deterministic function of the cell (the midpoint rule of
:mod:`photon_fields.runtime.transport.marching`, no random numbers), so every image is the same whatever was filled
before, in whatever order, on however many threads (tested). Point lights march to the light's position,
directional ones to the box; the environment is not a delta light and has no entry read (the marcher leaves it
unscattered).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from photon_fields.runtime.borrowed import borrowed
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.prefetch import prefetch_stencil
from photon_fields.runtime.transport.cell_grid import Grid, blend, cell_centre, stencil
from photon_fields.runtime.transport.emitters import delta_light_direction
from photon_fields.runtime.transport.marching import march_transmittance_in_segments
from photon_fields.runtime.transport.medium import Medium, borrowed_medium
from photon_fields.runtime.transport.tracking import task_stride

DEFAULT_CELLS_PER_VOXEL = 1.0
#: The default grid's cells per light at most (:func:`auto_cells_per_voxel`): one per voxel up to ~320^3 voxels.
AUTO_CELLS = 1 << 25
#: Voxels per step of a cell's shadow ray: half a voxel, since a cell is marched once and read by many samples
#: (the per-sample shadow rays' 1-voxel sum reads bright at sharp walls; bench/README.md, ray marcher).
DEFAULT_SHADOW_STEP = 0.5
#: Base steps one segment of a cell's shadow ray may span (where sigma_t is smooth and thin: the step grid's
#: bounds). A 256^3 volume of the same shapes as a 96^3 one has a third of its optical depth per voxel, and its
#: cells' rays, two base steps a voxel, were most of a first frame (bench/README.md, ray marcher).
SHADOW_SPAN = 4
#: A cell's shadow ray stops where its optical depth passes this (transmittance 1e-4) and counts as dark.
TAU_MAX = -math.log(1e-4)
#: A light volume's size limit: an error names the option to lower rather than filling the memory.
MAX_BYTES = 1 << 30
#: The value of a cell not marched yet, and of one that a frame has asked for (:func:`want_stencil`).
UNFILLED = np.float32(-1.0)
WANTED = np.float32(-2.0)
#: An unfilled cell beside a filled one, marked by :func:`fill_margin`: filled as a wanted one is, but its brick is
#: not remembered for the next margin (module docstring, "A margin in idle time").
NEIGHBOUR = np.float32(-3.0)
#: Edge of a brick of cells, the unit in which marked cells are looked for (module docstring): a power of two.
BRICK = 8
#: Bricks one parallel fill takes at most: between two, a cancellable render may stop (the viewer's resting frames:
#: at 256^3 an edit's full fill is a second of work, ~30 ms a chunk).
FILL_CHUNK = 256
_BRICK_SHIFT = BRICK.bit_length() - 1


class LightVolume(NamedTuple):
    """Transmittances (gx, gy, gz, lights) float32, :data:`UNFILLED` until read; the grid; the cells' shadow base
    step (world units) and base steps per segment per macrocell (uint8); per :data:`BRICK` of cells (uint8), 1
    where a cell is marked and not filled yet (``wanted``), and 1 where cells that frames asked for were filled
    since the last :func:`fill_margin` (``margin``)."""

    values: np.ndarray
    grid: Grid
    shadow_step: float
    units: np.ndarray
    wanted: np.ndarray
    margin: np.ndarray


def light_volume_shape(volume_shape: tuple[int, ...], cells_per_voxel: float) -> tuple[int, int, int]:
    """Cells along each axis: the voxels times ``cells_per_voxel``, plus a ring of one cell outside the box."""
    return tuple(max(1, int(round(n * cells_per_voxel))) + 2 for n in volume_shape)  # type: ignore[return-value]


def auto_cells_per_voxel(volume_shape: tuple[int, ...]) -> float:
    """The default cells per voxel for a volume of this shape: :data:`DEFAULT_CELLS_PER_VOXEL`, or less, in steps
    of 1/64, where that grid (its ring included) would pass :data:`AUTO_CELLS` cells."""
    scale = DEFAULT_CELLS_PER_VOXEL
    while scale > 1 / 64 and math.prod(light_volume_shape(volume_shape, scale)) > AUTO_CELLS:
        scale -= 1 / 64
    return scale


def new_light_volume(m: Medium, lights: int, cells_per_voxel: float, shadow_step: float,
                     units: np.ndarray | None = None) -> LightVolume:
    """An unfilled light volume for ``lights`` lights over ``m``'s box; refuses one over :data:`MAX_BYTES`.
    ``units``: its shadow rays' base steps per segment per macrocell (None: one).

    Its cells tile the box (at one cell per voxel their centres are the voxel centres, where the volume's values
    are: a lattice shifted by half a voxel read the shell's lit wall 18 % bright instead of 9 % dark) plus a ring
    of cells outside it: where the medium touches the box (a scan cropped to its tissue), a sample at the lit
    face interpolates towards the light outside, where a lookup clamped at the box read the value half a cell
    inside (a slab filling the box, 1.5 optical depths per voxel, read 23 % dark)."""
    cells = light_volume_shape(m.density.shape, cells_per_voxel)
    size = int(np.prod(cells)) * max(lights, 1) * 4
    if size > MAX_BYTES:
        raise InputError("--light-grid-scale", f"a {'x'.join(map(str, cells))} light volume for {lights} lights would "
                         f"take {size / 2**20:.0f} MiB (limit {MAX_BYTES >> 20} MiB): use a smaller scale")
    spacing = m.bsize / (np.asarray(cells, dtype=np.float64) - 2.0)
    origin = m.bmin - spacing  # cell 0 is the ring's: centred half a cell outside the box
    grid = (float(origin[0]), float(origin[1]), float(origin[2]), float(1.0 / spacing[0]), float(1.0 / spacing[1]),
            float(1.0 / spacing[2]), cells[0], cells[1], cells[2])
    values = np.full((*cells, max(lights, 1)), UNFILLED, dtype=np.float32)
    units = np.ones(m.majorant.shape, np.uint8) if units is None else units
    if units.shape != m.majorant.shape:
        raise ValueError(f"units {units.shape} are not per macrocell {m.majorant.shape}")
    bricks = tuple(-(-n // BRICK) for n in cells)
    return LightVolume(values, grid, float(shadow_step), units, np.zeros(bricks, np.uint8),
                       np.zeros(bricks, np.uint8))


def adopt_light_columns(lv: LightVolume, kind: np.ndarray, vec: np.ndarray, old: LightVolume, old_kind: np.ndarray,
                        old_vec: np.ndarray) -> int:
    """Copy into ``lv`` the filled cells of every light that ``old`` (a light volume over the same medium and grid)
    holds as well: the same kind and position or direction (a cell's value depends on nothing else: not on the
    light's colour or power, nor on the other lights). Returns how many lights were copied."""
    if old.values.shape[:3] != lv.values.shape[:3] or old.grid != lv.grid or old.shadow_step != lv.shadow_step:
        return 0
    copied = 0
    for k in range(len(kind)):
        for j in range(len(old_kind)):
            if old_kind[j] == kind[k] and np.array_equal(old_vec[j], vec[k]):
                column = old.values[..., j]
                lv.values[..., k] = np.where(column >= 0.0, column, UNFILLED)
                copied += 1
                break
    return copied


@njit(cache=True, inline="always")
def light_transmittance(v: np.ndarray, light: int, i: int, j: int, k: int, fx: float, fy: float, fz: float) -> float:
    """Light ``light``'s transmittance at the stencil (i, j, k, fx, fy, fz) of a light volume's grid, trilinear in
    its values ``v``; -1 if a corner is not filled yet (the caller marks it, :func:`want_stencil`, and comes back
    after :func:`fill_wanted`). Nothing is marched here: a march (a call with the medium) inside the camera loop,
    even one never taken, made every warm frame 15-25 % slower."""
    v000, v100, v010, v110 = v[i, j, k, light], v[i + 1, j, k, light], v[i, j + 1, k, light], v[i + 1, j + 1, k, light]
    v001, v101 = v[i, j, k + 1, light], v[i + 1, j, k + 1, light]
    v011, v111 = v[i, j + 1, k + 1, light], v[i + 1, j + 1, k + 1, light]
    if min(min(min(v000, v100), min(v010, v110)), min(min(v001, v101), min(v011, v111))) < 0.0:
        return -1.0
    return blend(v000, v100, v010, v110, v001, v101, v011, v111, fx, fy, fz)


@njit(cache=True, inline="always")
def prefetch_light_stencil(v: np.ndarray, grid: Grid, x: float, y: float, z: float) -> None:
    """Start loading the cache lines of the light volume ``v``'s stencil at (x, y, z) (:mod:`photon_fields.runtime.
    prefetch`), every light's values of a cell lying together: the four (i, j) corner pairs."""
    i, j, k, _, _, _ = stencil(grid, x, y, z)
    prefetch_stencil(v, i, j, k)


@njit(cache=True, inline="always")
def _mark_unfilled(v: np.ndarray, wanted: np.ndarray, a: int, b: int, e: int, light: int, mark: float) -> None:
    """Mark cell (a, b, e) of light ``light`` with ``mark`` if it is :data:`UNFILLED`, and flag its brick in
    ``wanted`` (a benign race: every writer writes the same value)."""
    if v[a, b, e, light] == UNFILLED:
        v[a, b, e, light] = mark
        wanted[a >> _BRICK_SHIFT, b >> _BRICK_SHIFT, e >> _BRICK_SHIFT] = 1


@njit(cache=True, inline="always")
def want_stencil(v: np.ndarray, wanted: np.ndarray, light: int, i: int, j: int, k: int) -> None:
    """Mark the stencil's unfilled corners :data:`WANTED` for light ``light`` and flag their bricks in ``wanted``
    (a benign race: every writer writes the same value)."""
    for c in range(8):
        _mark_unfilled(v, wanted, i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1), light, WANTED)


@njit(cache=True)
def _fill_brick(m: Medium, kind: np.ndarray, vec: np.ndarray, v: np.ndarray, grid: Grid, h: float,
                units: np.ndarray, bi: int, bj: int, bk: int) -> bool:
    """March the :data:`WANTED` and :data:`NEIGHBOUR` cells of brick (bi, bj, bk) (:func:`fill_wanted`), serially;
    True if one of them was wanted by a frame."""
    m, units = borrowed_medium(m), borrowed(units)  # no reference counting in the loops (runtime/borrowed.py)
    gx, gy, gz, lights = v.shape
    wanted = False
    for a in range(bi * BRICK, min(gx, (bi + 1) * BRICK)):
        for b in range(bj * BRICK, min(gy, (bj + 1) * BRICK)):
            for e in range(bk * BRICK, min(gz, (bk + 1) * BRICK)):
                for light in range(lights):
                    state = v[a, b, e, light]
                    if state != WANTED and state != NEIGHBOUR:
                        continue
                    wanted = wanted or state == WANTED
                    px, py, pz = cell_centre(grid, a, b, e)
                    lx, ly, lz, scale, tend = delta_light_direction(kind[light], vec[light], px, py, pz)
                    tr = (march_transmittance_in_segments(m, units, px, py, pz, lx, ly, lz, tend, h, TAU_MAX)
                          if scale > 0.0 else 0.0)
                    v[a, b, e, light] = np.float32(tr)
    return wanted


@njit(cache=True, parallel=True)
def _fill(m: Medium, kind: np.ndarray, vec: np.ndarray, v: np.ndarray, grid: Grid, h: float,
          units: np.ndarray, bricks: np.ndarray, margin: np.ndarray) -> None:
    n = bricks.shape[0]
    stride = task_stride(n)
    for t in prange(n):  # golden-ratio order: the wanted cells cluster where the camera looks
        b = (t * stride) % n
        if _fill_brick(m, kind, vec, v, grid, h, units, bricks[b, 0], bricks[b, 1], bricks[b, 2]):
            margin[bricks[b, 0], bricks[b, 1], bricks[b, 2]] = 1


@njit(cache=True, parallel=True)
def _mark_margin(v: np.ndarray, wanted: np.ndarray, bricks: np.ndarray) -> None:
    """Mark :data:`NEIGHBOUR` every :data:`UNFILLED` cell within one cell (the 26 around it) of a filled cell of
    the same light in ``bricks``, and flag their bricks in ``wanted``. Cells only go from unfilled to neighbour,
    and only filled cells spread, so the marks are the same in whatever order the threads take the bricks (a
    benign race: every writer writes the same value)."""
    gx, gy, gz, lights = v.shape
    for t in prange(bricks.shape[0]):
        bi, bj, bk = bricks[t, 0], bricks[t, 1], bricks[t, 2]
        for a in range(bi * BRICK, min(gx, (bi + 1) * BRICK)):
            for b in range(bj * BRICK, min(gy, (bj + 1) * BRICK)):
                for e in range(bk * BRICK, min(gz, (bk + 1) * BRICK)):
                    for light in range(lights):
                        if v[a, b, e, light] < 0.0:
                            continue
                        for p in range(max(a - 1, 0), min(a + 2, gx)):
                            for q in range(max(b - 1, 0), min(b + 2, gy)):
                                for r in range(max(e - 1, 0), min(e + 2, gz)):
                                    _mark_unfilled(v, wanted, p, q, r, light, NEIGHBOUR)


def fill_wanted(m: Medium, kind: np.ndarray, vec: np.ndarray, lv: LightVolume,
                cancel: Callable[[], bool] | None = None) -> bool:
    """March every :data:`WANTED` (and :data:`NEIGHBOUR`) cell of ``lv`` towards its light (in parallel over the
    flagged bricks, up to :data:`FILL_CHUNK` bricks at a time), clear the flags and flag in ``lv.margin`` the bricks
    where it filled wanted cells; True when done. ``cancel`` is asked before each chunk:
    when it returns True the fill stops and returns False, the bricks not filled still flagged (a later fill
    completes them; what was filled stays, each cell's value being its own). ``m`` must be the medium the volume
    was made for, or one over the same majorant grid (a transfer-function edit's): its shadow rays read ``lv.units``
    per macrocell of ``m``, and another grid's indices would run past them."""
    if lv.units.shape != m.majorant.shape:
        raise ValueError(f"the light volume's step units are per macrocell of a {lv.units.shape} grid, the medium's "
                         f"grid is {m.majorant.shape}")
    bricks = np.argwhere(lv.wanted)
    for start in range(0, len(bricks), FILL_CHUNK):
        if cancel is not None and cancel():
            return False
        chunk = bricks[start:start + FILL_CHUNK]
        _fill(m, kind, vec, lv.values, lv.grid, lv.shadow_step, lv.units, chunk, lv.margin)
        lv.wanted[chunk[:, 0], chunk[:, 1], chunk[:, 2]] = 0
    return True


def fill_margin(m: Medium, kind: np.ndarray, vec: np.ndarray, lv: LightVolume,
                cancel: Callable[[], bool] | None = None) -> bool:
    """Fill every unfilled cell beside a cell filled for frames since the last call (the bricks ``lv.margin``
    flags; module docstring, "A margin in idle time"), then clear those flags; True when done, False when ``cancel``
    stopped the fill (:func:`fill_wanted`: the marks not filled yet stay, and the next fill of any kind, this one's
    included, completes them). The images are the same with or without it (each cell's value is its own); only
    later frames' fills are smaller."""
    bricks = np.argwhere(lv.margin)
    if len(bricks):
        _mark_margin(lv.values, lv.wanted, bricks)
        lv.margin[bricks[:, 0], bricks[:, 1], bricks[:, 2]] = 0
    return fill_wanted(m, kind, vec, lv, cancel)
