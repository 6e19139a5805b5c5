"""The renderable medium: a volume classified by a transfer function, packed for numba kernels.

Parameters
----------
volume : photon_fields.runtime.scene.volume.Volume
    Normalized scalar grid and its world box.
tf : photon_fields.runtime.scene.transfer.TransferFunction or photon_fields.runtime.scene.labels.LabelTransfer
    Scalar -> (albedo, extinction); evaluated post-classification (the scalar is interpolated
    trilinearly first, then mapped through the TF lookup table), as volume renderers such as OpenVKL do.
    A label (categorical) transfer function gives a *categorical* medium instead (below).
macrocell : int or None
    Edge length, in voxels, of a majorant-grid cell (default None: :func:`auto_macrocell`, ``DEFAULT_MACROCELL`` = 2
    up to 256 voxels a side, more above so that the grid keeps to ``MAX_MACROCELLS_SIDE`` = 128 cells a side).
leap : bool
    Build the empty-space leap distances (default True); False gives a walk that steps through every
    macrocell, the reference the leaping walk is tested against bit for bit.

The majorant grid (Novak et al. 2014 call it a "coarse grid of local majorants") holds, per macrocell, an
upper bound of the extinction anywhere inside it. The bound is exact-conservative: trilinear
interpolation stays within the min/max of the voxels it touches, and the TF table is linearly
interpolated, so the max of the table over the covered index range bounds sigma_t. Delta and ratio
tracking (:mod:`runtime.transport.tracking`) step through this grid with a 3D DDA so that empty space costs one
step per macrocell and dense regions use a tight local bound.

Categorical media (label volumes, :mod:`photon_fields.runtime.scene.labels`): ``categorical`` is True,
``density`` holds each voxel's dense label index 0..K-1 (exact small integers in float32) and the tables have
K entries, one per label present. :func:`scalar_at` then returns the *nearest* voxel's index instead of
interpolating, and the table lookups index it exactly: a renderer only ever sees a label's own albedo and
extinction, never a blend that no label has (interpolating labels before classification makes the border
between labels 3 and 7 pass through 4, 5 and 6). One flag in the same NamedTuple keeps every kernel on one
code path; the branch it adds to the trilinear path is a predictable one on a loop-invariant field
(measured: no difference beyond noise in delta/ratio tracking throughput). The majorant of a macrocell is
then the largest table entry over the *voxels* of its trilinear support, not over an index range (label
indices carry no order): the nearest voxel of any point in the macrocell is one of them, so the bound is
exact, and tighter than the index-range bound, which would count every label between the smallest and the
largest present.

Empty-space leaping: ``leap[o, c]`` is the edge r, in macrocells, of the largest cube of empty macrocells with
its corner at macrocell c that extends from c towards octant o of directions (0 if c is not empty, capped at
255; octant o = [dx >= 0] + 2 [dy >= 0] + 4 [dz >= 0]). A ray in c travelling into octant o stays in that cube
until it leaves it, so it can jump to the cube's exit in one step instead of crossing r^3 macrocells one by
one (proximity clouds, Cohen & Sheffer 1994, made directional so that occupied cells behind the ray do not
shorten the leap). A ray draws no random number in empty macrocells, and the walk computes every boundary
distance in closed form from the plane's index, so leaping changes no sample: images are bit-identical to
the cell-by-cell walk.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from photon_fields.runtime.borrowed import borrowed
from photon_fields.runtime.numba_inlining import install
from photon_fields.runtime.prefetch import prefetch_stencil
from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.transfer import LUT_SIZE, TransferFunction
from photon_fields.runtime.scene.volume import Volume

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

DEFAULT_MACROCELL = 2  # measured with empty-space leaping: 2 beats 1, 4 and 8 on the embedded scenes (bench/README.md)
#: :func:`auto_macrocell`'s grid side, at most: at 512^3 a 2-voxel macrocell's 256^3 grid made the neural and the
#: path-traced frames 1.4x slower than 4-voxel ones and took 134 MB of majorant and of leap tables each, rebuilt at
#: every transfer-function edit (bench/README.md, "the macrocell at 512^3").
MAX_MACROCELLS_SIDE = 128
_MAJORANT_SAFETY = 1.0 + 1e-6  # guards against rounding in the interpolation of sigma_t
LEAP_CAP = 255  # leap distances are stored as uint8


class Medium(NamedTuple):
    """Arrays consumed by the kernels. World box = [bmin, bmin + bsize]."""

    density: np.ndarray  # float32 (nx, ny, nz): normalized scalar in [0, 1] (categorical: label index 0..K-1)
    ext_lut: np.ndarray  # float64 (LUT,): extinction per unit length at s = i / (LUT - 1) (categorical: (K,))
    albedo_lut: np.ndarray  # float64 (LUT, 3) (categorical: (K, 3))
    majorant: np.ndarray  # float64 (cx, cy, cz): max extinction per macrocell
    leap: np.ndarray  # uint8 (8, cx, cy, cz): per direction octant, the empty cube at each macrocell (module docstring)
    bmin: np.ndarray  # float64 (3,)
    bsize: np.ndarray  # float64 (3,)
    voxels_per_unit: np.ndarray  # float64 (3,): density.shape / bsize, so a lookup multiplies instead of dividing
    categorical: bool = False  # nearest-voxel label index and exact table lookups (module docstring)


@njit(cache=True, inline="always")
def borrowed_medium(m: Medium) -> Medium:
    """``m`` with its arrays borrowed (:mod:`photon_fields.runtime.borrowed`: no reference counting in the walks'
    loops): for a serial task kernel's own use while its caller holds ``m``."""
    return Medium(borrowed(m.density), borrowed(m.ext_lut), borrowed(m.albedo_lut), borrowed(m.majorant),
                  borrowed(m.leap), borrowed(m.bmin), borrowed(m.bsize), borrowed(m.voxels_per_unit), m.categorical)


def auto_macrocell(shape: tuple[int, ...]) -> int:
    """The macrocell edge for a volume of this shape: :data:`DEFAULT_MACROCELL`, or more where the grid's longest
    side would pass :data:`MAX_MACROCELLS_SIDE` cells (up to 256^3 voxels: 2)."""
    return max(DEFAULT_MACROCELL, math.ceil(max(shape) / MAX_MACROCELLS_SIDE))


def build_medium(volume: Volume, tf: TransferFunction | LabelTransfer, macrocell: int | None = None,
                 leap: bool = True) -> Medium:
    """The medium of ``volume`` under ``tf``: categorical for a :class:`LabelTransfer` (module docstring);
    ``macrocell`` None: :func:`auto_macrocell`."""
    macrocell = auto_macrocell(volume.dims) if macrocell is None else int(macrocell)
    if getattr(tf, "categorical", False):
        density, ext_lut, albedo_lut = tf.tables(volume)  # type: ignore[union-attr]
        majorant = categorical_majorant_grid(density, ext_lut, macrocell)
    else:
        albedo_lut, ext_lut = tf.lut(LUT_SIZE)  # type: ignore[union-attr]
        density = np.ascontiguousarray(volume.data, dtype=np.float32)
        ranges = volume._majorant_ranges  # the volume's own part of the majorant, kept for the next edit
        if macrocell not in ranges:  # float32: the scalars' own values, at half the memory
            ranges[macrocell] = tuple(r.astype(np.float32) for r in scalar_ranges(density, macrocell))
        majorant = majorant_grid(density, ext_lut, macrocell, ranges[macrocell])
    return Medium(np.ascontiguousarray(density, dtype=np.float32), np.ascontiguousarray(ext_lut),
                  np.ascontiguousarray(albedo_lut), majorant, leap_distances(majorant, leap),
                  volume.bbox_min.astype(np.float64), volume.extent.astype(np.float64),
                  np.asarray(density.shape, np.float64) / volume.extent.astype(np.float64),
                  bool(getattr(tf, "categorical", False)))


def voxel_extinction(m: Medium, start: int = 0, stop: int | None = None) -> np.ndarray:
    """sigma_t at every voxel centre of the x-planes [start, stop) (default all), float64 (planes, ny, nz): where
    both interpolation modes return the voxel's own value, so this is exact for continuous and categorical media
    alike."""
    d = m.density[start:stop]
    if m.categorical:
        return m.ext_lut[d.astype(np.int64)]
    return np.interp(d.astype(np.float64), np.linspace(0.0, 1.0, m.ext_lut.shape[0]), m.ext_lut)


def block_extinction(m: Medium, block: int) -> np.ndarray:
    """The mean of sigma_t at the voxel centres of each ``block``^3 block (float64; the grid padded at its far ends
    by repeating the border voxels): :func:`voxel_extinction` averaged over blocks in one parallel pass, without
    the whole grid's float64 copy (at 256^3 numpy's interpolation and block mean took 0.23 s of every edit's first
    denoised frame)."""
    cells = tuple(-(-n // block) for n in m.density.shape)
    out = np.empty(cells)
    _block_extinction(m.density, m.ext_lut, m.categorical, int(block), out)
    return out


@njit(cache=True, parallel=True)
def _block_extinction(density: np.ndarray, lut: np.ndarray, categorical: bool, block: int, out: np.ndarray) -> None:
    nx, ny, nz = density.shape
    cx, cy, cz = out.shape
    inv = 1.0 / (block * block * block)
    for a in prange(cx):
        for b in range(cy):
            for c in range(cz):
                acc = 0.0
                for i in range(a * block, (a + 1) * block):
                    ii = min(i, nx - 1)
                    for j in range(b * block, (b + 1) * block):
                        jj = min(j, ny - 1)
                        for k in range(c * block, (c + 1) * block):
                            acc += _extinction_of(lut, categorical, density[ii, jj, min(k, nz - 1)])
                out[a, b, c] = acc * inv


def leap_distances(majorant: np.ndarray, leap: bool = True) -> np.ndarray:
    """Per direction octant and macrocell, the edge of the largest empty cube cornered there (module docstring),
    capped at ``LEAP_CAP``; ``leap=False`` caps it at 1, which turns leaping off."""
    out = np.empty((8, *majorant.shape), np.uint8)
    _empty_cubes(np.ascontiguousarray(majorant), LEAP_CAP if leap else 1, out)
    return out


@njit(cache=True, parallel=True)
def _empty_cubes(majorant: np.ndarray, cap: int, out: np.ndarray) -> None:
    """out[o, c] = 0 where the majorant is > 0, else 1 + the least of the seven neighbours of c one cell further
    into octant o (the 3D form of the largest-square recurrence); cells beyond the grid count as empty. The
    octants are independent: one task each."""
    nx, ny, nz = majorant.shape
    for o in prange(8):
        sx, sy, sz = (1 if o & 1 else -1), (1 if o & 2 else -1), (1 if o & 4 else -1)
        for a in range(nx):
            i = nx - 1 - a if sx > 0 else a
            for b in range(ny):
                j = ny - 1 - b if sy > 0 else b
                for c in range(nz):
                    k = nz - 1 - c if sz > 0 else c
                    if majorant[i, j, k] > 0.0:
                        out[o, i, j, k] = 0
                        continue
                    least = cap
                    for corner in range(1, 8):
                        ii = i + sx * (corner & 1)
                        jj = j + sy * ((corner >> 1) & 1)
                        kk = k + sz * ((corner >> 2) & 1)
                        if 0 <= ii < nx and 0 <= jj < ny and 0 <= kk < nz:
                            least = min(least, int(out[o, ii, jj, kk]))
                    out[o, i, j, k] = min(least + 1, cap)


def majorant_grid(density: np.ndarray, ext_lut: np.ndarray, macrocell: int,
                  ranges: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Per-macrocell max extinction (see module docstring for why it is a true bound): the table's max over the
    index range of the scalars whose trilinear support reaches into the macrocell. ``ranges``: those scalars' min
    and max per macrocell (:func:`scalar_ranges`), which depend on the volume alone; None computes them here (the
    ranges as numpy arrays took 1-2 s of a 512^3 volume's medium; :func:`build_medium` keeps them on the volume,
    so that a transfer-function edit's majorant is only the table lookups)."""
    smin, smax = scalar_ranges(density, macrocell) if ranges is None else ranges
    return _majorant_from_ranges(smin, smax, _sparse_max_table(ext_lut), _MAJORANT_SAFETY)


def scalar_ranges(density: np.ndarray, macrocell: int) -> tuple[np.ndarray, np.ndarray]:
    """Min and max of the scalars whose trilinear support reaches into each macrocell (:func:`_cell_scalar_range`):
    what the majorant needs of the volume, whatever the transfer function."""
    n = np.array(density.shape)
    cells = np.maximum(1, -(-n // macrocell))  # ceil
    return _cell_scalar_range(density, int(cells[0]), int(cells[1]), int(cells[2]))


@njit(cache=True, parallel=True)
def _majorant_from_ranges(smin: np.ndarray, smax: np.ndarray, table: np.ndarray, safety: float) -> np.ndarray:
    lut_n = table.shape[1]
    cx, cy, cz = smin.shape
    out = np.empty((cx, cy, cz))
    for a in prange(cx):
        for b in range(cy):
            for c in range(cz):
                lo = int(math.floor(float(smin[a, b, c]) * (lut_n - 1)))
                hi = int(math.ceil(float(smax[a, b, c]) * (lut_n - 1)))
                out[a, b, c] = _range_max_one(table, lo, hi) * safety
    return out


def categorical_majorant_grid(index: np.ndarray, ext_lut: np.ndarray, macrocell: int) -> np.ndarray:
    """Per-macrocell max extinction of a categorical medium: the max of ``ext_lut[label]`` over the voxels of
    the macrocell's trilinear support (module docstring: a superset of the nearest voxels of its points)."""
    n = np.array(index.shape)
    cells = np.maximum(1, -(-n // macrocell))
    voxel_sigma = np.asarray(ext_lut, dtype=np.float64)[np.asarray(index, dtype=np.int64)]
    _, smax = _cell_scalar_range(voxel_sigma, int(cells[0]), int(cells[1]), int(cells[2]))
    return smax * _MAJORANT_SAFETY


@njit(cache=True, parallel=True)
def _cell_scalar_range(density: np.ndarray, cx: int, cy: int, cz: int) -> tuple[np.ndarray, np.ndarray]:
    """Min and max of the voxels whose trilinear support reaches into each macrocell (of any per-voxel value: the
    normalized scalar, or a categorical medium's extinction per voxel): macrocell a spans
    normalized [a / cells, (a + 1) / cells), i.e. voxel-centre coordinates [a n / cells - 0.5, ...)."""
    smin = np.empty((cx, cy, cz))
    smax = np.empty((cx, cy, cz))
    for a in prange(cx):
        for b in range(cy):
            for c in range(cz):
                smin[a, b, c], smax[a, b, c] = _cell_range(density, a, b, c, cx, cy, cz)
    return smin, smax


@njit(cache=True, inline="always")
def _cell_range(density: np.ndarray, a: int, b: int, c: int, cx: int, cy: int, cz: int) -> tuple[float, float]:
    """Min and max of the voxels whose trilinear support reaches into macrocell (a, b, c)
    (:func:`_cell_scalar_range`)."""
    nx, ny, nz = density.shape
    x0, x1 = _voxel_span(a, cx, nx)
    y0, y1 = _voxel_span(b, cy, ny)
    z0, z1 = _voxel_span(c, cz, nz)
    lo = np.inf
    hi = -np.inf
    for i in range(x0, x1):
        for j in range(y0, y1):
            for k in range(z0, z1):
                v = density[i, j, k]
                lo = min(lo, v)
                hi = max(hi, v)
    return lo, hi


@njit(cache=True, inline="always")
def _voxel_span(cell: int, cells: int, n: int) -> tuple[int, int]:
    lo = int(math.floor(cell / cells * n - 0.5))
    hi = int(math.ceil((cell + 1) / cells * n - 0.5))
    return max(lo, 0), min(hi, n - 1) + 1


def _sparse_max_table(lut: np.ndarray) -> np.ndarray:
    """Sparse table of ``lut``: row k holds max(lut[i : i + 2^k]) at i (rows padded with lut's last entry),
    so that the max over any index range is the max of two entries (:func:`range_max`)."""
    n = lut.shape[0]
    rows = [np.asarray(lut, dtype=np.float64)]
    span = 1
    while 2 * span <= n:
        prev = rows[-1]
        rows.append(np.maximum(prev, np.concatenate([prev[span:], np.full(span, prev[-1])])))
        span *= 2
    return np.stack(rows)


def range_max(table: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """max(lut[lo : hi + 1]) elementwise for index arrays lo <= hi, from :func:`_sparse_max_table`: the two
    power-of-two windows that cover [lo, hi] (the classic O(1) range-maximum query; exact, since max is)."""
    return _range_max(table, np.ascontiguousarray(lo, dtype=np.int64), np.ascontiguousarray(hi, dtype=np.int64))


@njit(cache=True)
def _range_max(table: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    out = np.empty(lo.shape[0])
    for i in range(lo.shape[0]):
        out[i] = _range_max_one(table, lo[i], hi[i])
    return out


@njit(cache=True, inline="always")
def _range_max_one(table: np.ndarray, lo: int, hi: int) -> float:
    """:func:`range_max` of one range: k = floor(log2(hi - lo + 1)), counted in integers."""
    k = 0
    while (2 << k) <= hi - lo + 1:
        k += 1
    return max(table[k, lo], table[k, hi - (1 << k) + 1])


# --- kernels' view of the medium -------------------------------------------------------------------


@njit(cache=True, inline="always")
def _voxel_coords(m: Medium, x: float, y: float, z: float) -> tuple[float, float, float]:
    """World point -> continuous voxel coordinates (voxel centres at integers), clamped to the grid."""
    nx, ny, nz = m.density.shape
    return (min(max((x - m.bmin[0]) * m.voxels_per_unit[0] - 0.5, 0.0), nx - 1.0),
            min(max((y - m.bmin[1]) * m.voxels_per_unit[1] - 0.5, 0.0), ny - 1.0),
            min(max((z - m.bmin[2]) * m.voxels_per_unit[2] - 0.5, 0.0), nz - 1.0))


@njit(cache=True, inline="always")
def _lower_corner(m: Medium, vx: float, vy: float, vz: float) -> tuple[int, int, int]:
    """The trilinear stencil's lower corner at voxel coordinates (vx, vy, vz) (:func:`_voxel_coords`)."""
    nx, ny, nz = m.density.shape
    return min(int(vx), nx - 2), min(int(vy), ny - 2), min(int(vz), nz - 2)


@njit(cache=True, inline="always")
def scalar_at(m: Medium, x: float, y: float, z: float) -> float:
    """Trilinearly interpolated normalized scalar at world point (x, y, z) (clamped at the border); in a
    categorical medium, the nearest voxel's label index (never interpolated)."""
    vx, vy, vz = _voxel_coords(m, x, y, z)
    if m.categorical:  # vx <= nx - 1, so int(vx + 0.5) <= nx - 1: the nearest voxel centre
        return m.density[int(vx + 0.5), int(vy + 0.5), int(vz + 0.5)]
    i, j, k = _lower_corner(m, vx, vy, vz)
    fx, fy, fz = vx - i, vy - j, vz - k
    d = m.density
    c00 = d[i, j, k] * (1.0 - fx) + d[i + 1, j, k] * fx
    c10 = d[i, j + 1, k] * (1.0 - fx) + d[i + 1, j + 1, k] * fx
    c01 = d[i, j, k + 1] * (1.0 - fx) + d[i + 1, j, k + 1] * fx
    c11 = d[i, j + 1, k + 1] * (1.0 - fx) + d[i + 1, j + 1, k + 1] * fx
    c0 = c00 * (1.0 - fy) + c10 * fy
    c1 = c01 * (1.0 - fy) + c11 * fy
    return c0 * (1.0 - fz) + c1 * fz


#: Volumes of at least this many bytes of scalars have their march's next stencils prefetched
#: (:func:`worth_prefetching`): smaller ones stay in the caches, where the prefetches only cost (bench/README.md).
PREFETCH_MIN_BYTES = 16 << 20


def worth_prefetching(m: Medium) -> bool:
    """Whether marches over ``m`` should prefetch their next samples' stencils (:data:`PREFETCH_MIN_BYTES`)."""
    return m.density.nbytes >= PREFETCH_MIN_BYTES


@njit(cache=True, inline="always")
def prefetch_scalar_stencil(m: Medium, x: float, y: float, z: float) -> None:
    """Start loading the cache lines of :func:`scalar_at`'s stencil at (x, y, z) (:mod:`photon_fields.runtime.prefetch`:
    for a march's next sample, so that its lookup finds them in cache)."""
    vx, vy, vz = _voxel_coords(m, x, y, z)
    i, j, k = _lower_corner(m, vx, vy, vz)
    prefetch_stencil(m.density, i, j, k)


@njit(cache=True, inline="always")
def _lut_pos(lut_n: int, s: float) -> tuple[int, float]:
    f = min(max(s, 0.0), 1.0) * (lut_n - 1)
    i = min(int(f), lut_n - 2)
    return i, f - i


# The table lookups take the tables, not the medium, and the callers below read the medium's fields before any
# branch: an inlined kernel that passes ``m`` on and then branches on ``m.categorical`` left numba's reference-count
# pruning unable to pair the increments of the medium's seven arrays with their decrements, six calls each way per
# lookup (measured: 55 ns per extinction lookup against 21 ns written this way; the same arithmetic).


@njit(cache=True, inline="always")
def _extinction_of(lut: np.ndarray, categorical: bool, s: float) -> float:
    """sigma_t of the scalar ``s`` that :func:`scalar_at` returned (``lut``: the medium's ext_lut)."""
    if categorical:  # s is an exact label index
        v = lut[int(s)]
    else:
        i, f = _lut_pos(lut.shape[0], s)
        v = lut[i] * (1.0 - f) + lut[i + 1] * f
    return v


@njit(cache=True, inline="always")
def _albedo_of(a: np.ndarray, categorical: bool, s: float) -> tuple[float, float, float]:
    """The albedo of the scalar ``s`` that :func:`scalar_at` returned (``a``: the medium's albedo_lut)."""
    if categorical:  # s is an exact label index
        k = int(s)
        rgb = (a[k, 0], a[k, 1], a[k, 2])
    else:
        i, f = _lut_pos(a.shape[0], s)
        rgb = (a[i, 0] * (1.0 - f) + a[i + 1, 0] * f, a[i, 1] * (1.0 - f) + a[i + 1, 1] * f,
               a[i, 2] * (1.0 - f) + a[i + 1, 2] * f)
    return rgb


@njit(cache=True, inline="always")
def extinction_at(m: Medium, x: float, y: float, z: float) -> float:
    lut = m.ext_lut
    categorical = m.categorical
    return _extinction_of(lut, categorical, scalar_at(m, x, y, z))


@njit(cache=True, inline="always")
def albedo_at(m: Medium, x: float, y: float, z: float) -> tuple[float, float, float]:
    a = m.albedo_lut
    categorical = m.categorical
    return _albedo_of(a, categorical, scalar_at(m, x, y, z))


@njit(cache=True, inline="always")
def extinction_albedo_at(m: Medium, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """(sigma_t, albedo RGB) from one interpolation of the scalar: for a march that needs both at each sample
    (the albedo is only meaningful where sigma_t > 0)."""
    lut = m.ext_lut
    a = m.albedo_lut
    categorical = m.categorical
    s = scalar_at(m, x, y, z)
    a0, a1, a2 = _albedo_of(a, categorical, s)
    return _extinction_of(lut, categorical, s), a0, a1, a2


@njit(cache=True, inline="always")
def intersect_box(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float) -> tuple[float, float]:
    """Slab test: (t_near, t_far) of the ray against the world box; t_near > t_far means a miss.
    t_near is clamped to 0 (rays starting inside the box)."""
    t0, t1 = 0.0, math.inf
    for a in range(3):
        o = (ox, oy, oz)[a]
        d = (dx, dy, dz)[a]
        lo = m.bmin[a]
        hi = m.bmin[a] + m.bsize[a]
        if abs(d) < 1e-300:
            if o < lo or o > hi:
                return 1.0, 0.0
            continue
        inv = 1.0 / d
        ta = (lo - o) * inv
        tb = (hi - o) * inv
        if ta > tb:
            ta, tb = tb, ta
        t0 = max(t0, ta)
        t1 = min(t1, tb)
    return t0, t1


@njit(cache=True)
def extinction_batch(m: Medium, p: np.ndarray) -> np.ndarray:
    """sigma_t at points p (3, n): for tests and tools."""
    out = np.empty(p.shape[1])
    for i in range(p.shape[1]):
        out[i] = extinction_at(m, p[0, i], p[1, i], p[2, i])
    return out


@njit(cache=True)
def albedo_batch(m: Medium, p: np.ndarray) -> np.ndarray:
    """Albedo (3, n) at points p (3, n): for tests and tools."""
    out = np.empty((3, p.shape[1]))
    for i in range(p.shape[1]):
        out[0, i], out[1, i], out[2, i] = albedo_at(m, p[0, i], p[1, i], p[2, i])
    return out
