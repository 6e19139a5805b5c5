"""Photons counting-sorted into a uniform grid: the search structure of the K-nearest-photon search
(:mod:`photon_fields.runtime.photons.knn`) and the radiance estimate
(:mod:`photon_fields.runtime.photons.knn_radiance`), built once per photon map or phase window.

Grid
----
The photons' bounding box is divided into ``dims`` cubic cells of edge h; photons are counting-sorted
by linear cell index ``(ix * ny + iy) * nz + iz`` (stable, O(n)), so the cells of one (ix, iy) row are
one contiguous run of photons and a row segment is scanned as a single span.

Default cell size: h is chosen so that the *photon-weighted* mean cell occupancy,
``sum_c count_c^2 / n`` -- the number of photons in the cell of a typical photon -- is about
``TARGET_OCCUPANCY`` (= 32). Queries are drawn near photons (camera rays hit the medium where photons
are), so it is the density around photons, not the bounding-box average, that sets the K-th distance;
for clustered maps the two differ by orders of magnitude. The rule starts from the bounding-box
average (number of cells ~ n / 32, solved with degenerate axes given one cell) and refines h twice by
the measured occupancy (h *= (32 / occupancy)^(1/3), two ``bincount`` passes). With density rho = m /
h^3 around a query, the K-th neighbour lies at r_K = h (3 K / (4 pi m))^(1/3), i.e. about 2 cells for
K = 1024 and m = 32: the search then stops after 2-4 rings and scans ~3 K photons per query. On 1M
clustered photons (bench/bench_knn.py data, K = 1024, r_max 0.01 to 0.1) the search cost was flat
within the measurement noise (~15 %) for occupancies between ~15 and ~100, and 30-50 % higher at 5 or
240 for the saturated radii; 32 sits in the middle of the flat range on a log scale.

Binned grids: with a bin per photon (its phase bin, ranked by g), photons are sorted by ``cell * bins + bin`` and
``cell_start`` has an entry per (cell, bin), so the photons of a run of bins in one cell are one span; the cell size
then targets an occupancy counted over every bin (the caller's ``occupancy``: several times TARGET_OCCUPANCY, since
a search reads only a kernel's share of each cell).

The number of cells is capped at ``max(4096, 4 n) / bins`` (cell_start, int32 below 2^31 photons, then costs at most
16 bytes per photon), which enlarges h when needed, a requested one included: strongly clustered maps with far
outliers reach the cap before the target occupancy and pay in scanning, not in correctness. n = 0 or
a zero-size bounding box gives a single cell (edge 1 unless requested).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

TARGET_OCCUPANCY = 32.0  # photon-weighted mean photons per cell of the default cell size
_REFINE_PASSES = 2
_MIN_CELL_CAP = 4096
_CELLS_PER_PHOTON_CAP = 4


@njit(cache=True)
def cell_coord(p: float, o: float, inv_h: float, lo: int, hi: int) -> int:
    """floor((p - o) / h) clamped to [lo, hi]; clamped as a float first so inf never reaches int()."""
    t = (p - o) * inv_h
    if t < lo:
        return lo
    if t >= hi:
        return hi
    return int(math.floor(t))


class PhotonGrid(NamedTuple):
    """Photons counting-sorted into a uniform grid. Cell (ix, iy, iz) spans
    ``origin + [ix, ix + 1) * cell_size`` (etc.) and holds sorted photons
    ``cell_start[c] : cell_start[c + 1]`` with ``c = (ix * dims[1] + iy) * dims[2] + iz``."""

    positions: np.ndarray  # (n, 3) float64, sorted by cell
    order: np.ndarray  # (n,) int64: positions[i] == input_positions[order[i]]
    cell_start: np.ndarray  # (ncells + 1,) int32 (int64 from 2^31 photons): the largest array of a clustered map
    origin: np.ndarray  # (3,) float64
    cell_size: float
    dims: np.ndarray  # (3,) int64
    #: Bins per cell: photons are sorted by (cell, bin) and ``cell_start[c * bins + b]`` starts bin b of cell c, so
    #: a search can read any contiguous run of bins of a cell as one span (1: one run per cell, a plain grid).
    bins: int = 1


class PhotonIndex(NamedTuple):
    """A grid plus the photon attributes gathered into its (cell-sorted) order; see build_photon_index."""

    grid: PhotonGrid
    directions: np.ndarray  # (n, 3) float32, grid order
    weights: np.ndarray  # (n, 3) float32, grid order
    #: (n,) uint8, grid order: the light each photon came from, or None (the estimates sum over the lights).
    light: np.ndarray | None = None
    #: The estimates' lights: 1, or with ``light`` the number of lights they keep apart (3 columns each).
    lights: int = 1
    #: (n,) uint8, grid order: each photon's phase bin, ranked by the bins' g (a binned grid, ``grid.bins`` > 1), or
    #: None. With ``bin_g`` and ``half_width`` the estimate at g reads only the bins within half_width of g, each
    #: weighted by the triangular kernel (:mod:`photon_fields.runtime.photons.phase_window`).
    bin: np.ndarray | None = None
    #: (bins,) float64, ascending: the g of each bin rank.
    bin_g: np.ndarray | None = None
    #: The kernel's half-width in g (> 0 with ``bin``).
    half_width: float = 0.0


@njit(cache=True)
def _cell_ids(pos: np.ndarray, origin: np.ndarray, inv_h: float, dims: np.ndarray) -> np.ndarray:
    n = pos.shape[0]
    out = np.empty(n, dtype=np.int64)
    for i in range(n):
        ix = cell_coord(pos[i, 0], origin[0], inv_h, 0, dims[0] - 1)
        iy = cell_coord(pos[i, 1], origin[1], inv_h, 0, dims[1] - 1)
        iz = cell_coord(pos[i, 2], origin[2], inv_h, 0, dims[2] - 1)
        out[i] = (ix * dims[1] + iy) * dims[2] + iz
    return out


@njit(cache=True)
def _counting_sort(cell: np.ndarray, ncells: int) -> tuple[np.ndarray, np.ndarray]:
    """Stable counting sort: (order, cell_start)."""
    n = cell.shape[0]
    start = np.zeros(ncells + 1, dtype=np.int64)
    for i in range(n):
        start[cell[i] + 1] += 1
    for c in range(ncells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        c = cell[i]
        order[fill[c]] = i
        fill[c] += 1
    return order, start


def _dims_for(extent: np.ndarray, h: float) -> np.ndarray:
    return np.maximum(1, np.ceil(extent / h)).astype(np.int64)


def _cap_cell_size(extent: np.ndarray, h: float, max_cells: int) -> float:
    """Smallest h' >= h with prod(dims(h')) <= max_cells (bisection on log h; ncells is monotone in h)."""
    if int(np.prod(_dims_for(extent, h))) <= max_cells:
        return h
    lo, hi = h, float(extent.max())  # hi: a single cell, which always fits
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if int(np.prod(_dims_for(extent, mid))) <= max_cells:
            hi = mid
        else:
            lo = mid
    return hi


def _default_cell_size(pos: np.ndarray, origin: np.ndarray, extent: np.ndarray, max_cells: int,
                       target: float = TARGET_OCCUPANCY) -> float:
    """The default rule of the module docstring: photon-weighted occupancy ~ ``target`` (TARGET_OCCUPANCY)."""
    n = pos.shape[0]
    target_cells = max(1, int(n / target))
    # Bounding-box average first: the smallest h with at most n / m cells (bisection from far below it;
    # degenerate axes count one cell, so flat or linear maps get a sensible h too).
    h = _cap_cell_size(extent, float(extent.max()) * 1e-6, target_cells)
    for _ in range(_REFINE_PASSES):
        dims = _dims_for(extent, h)
        counts = np.bincount(_cell_ids(pos, origin, 1.0 / h, dims)).astype(np.float64)
        occupancy = float(counts @ counts) / n
        h_new = _cap_cell_size(extent, h * (target / occupancy) ** (1.0 / 3.0), max_cells)
        if abs(h_new / h - 1.0) < 0.05:
            break
        h = h_new
    return h


def build_photon_grid(positions: np.ndarray, cell_size: float | None = None, bin_rank: np.ndarray | None = None,
                      bins: int = 1, occupancy: float = TARGET_OCCUPANCY) -> PhotonGrid:
    """Counting-sort photons into a uniform grid over their bounding box (see the module docstring); with
    ``bin_rank`` (n,) ints below ``bins``, by (cell, bin): a binned grid (:attr:`PhotonGrid.bins`). ``occupancy``:
    the default cell size's target photons per cell (counting every bin)."""
    pos = np.asarray(positions)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise ValueError(f"positions must have shape (n, 3), got {pos.shape}")
    pos = np.ascontiguousarray(pos, dtype=np.float64)
    n = pos.shape[0]
    if n and not np.isfinite(pos).all():
        raise ValueError("positions must be finite")
    if cell_size is not None and not (math.isfinite(cell_size) and cell_size > 0.0):
        raise ValueError(f"cell_size must be a positive finite number, got {cell_size!r}")
    bins = int(bins)
    if bins > 1 and bin_rank is None:
        raise ValueError(f"a grid of {bins} bins per cell needs each photon's bin_rank")
    if bin_rank is not None and (bin_rank.shape != (n,) or (n and (int(bin_rank.min()) < 0
                                                                  or int(bin_rank.max()) >= bins))):
        raise ValueError(f"bin_rank must be (n,) ints in [0, {bins})")
    if n == 0:
        return PhotonGrid(pos, np.zeros(0, dtype=np.int64), np.zeros(bins + 1, dtype=np.int64), np.zeros(3), 1.0,
                          np.ones(3, dtype=np.int64), bins)
    origin = pos.min(axis=0).astype(np.float64)
    extent = pos.max(axis=0).astype(np.float64) - origin
    max_cells = max(_MIN_CELL_CAP, _CELLS_PER_PHOTON_CAP * n) // bins  # cell_start holds cells x bins entries
    if extent.max() <= 0.0:
        h = float(cell_size) if cell_size is not None else 1.0  # all photons in one spot: one cell
    elif cell_size is None:
        h = _default_cell_size(pos, origin, extent, max(1, max_cells), float(occupancy))
    else:
        h = _cap_cell_size(extent, float(cell_size), max(1, max_cells))
    dims = _dims_for(extent, h)
    key = _cell_ids(pos, origin, 1.0 / h, dims)
    if bin_rank is not None:
        key = key * bins + np.asarray(bin_rank, np.int64)
    order, start = _counting_sort(key, int(np.prod(dims)) * bins)
    if n < np.iinfo(np.int32).max:
        start = start.astype(np.int32)  # up to 4 cells per photon: half the memory of int64
    return PhotonGrid(np.take(pos, order, axis=0), order, start, origin, float(h), dims, bins)


def build_photon_index(positions: np.ndarray, directions: np.ndarray, weights: np.ndarray,
                       cell_size: float | None = None, light: np.ndarray | None = None,
                       lights: int = 1, bin_rank: np.ndarray | None = None, bin_g: np.ndarray | None = None,
                       half_width: float = 0.0, occupancy: float = TARGET_OCCUPANCY) -> PhotonIndex:
    """Grid + attributes gathered once into grid order (all inputs in the same, original order). ``light`` (n,)
    with ``lights`` > 1: the estimates keep the lights' parts apart (:func:`photon_fields.runtime.photons.
    knn_radiance.indexed_radiance`). ``bin_rank`` (n,) with ``bin_g`` (the bins' g, ascending) and ``half_width``
    > 0: a binned index, whose estimate at g reads the bins of g's kernel (:class:`PhotonIndex`); ``occupancy``
    then names the photons per cell of all bins together."""
    binned = bin_rank is not None
    if binned:
        bin_g = np.ascontiguousarray(bin_g, dtype=np.float64)
        if (bin_g.ndim != 1 or not 1 <= bin_g.size <= 256 or np.any(np.diff(bin_g) <= 0.0)
                or not half_width > 0.0):
            raise ValueError("a binned index needs 1-256 ascending bin_g and half_width > 0")
    grid = build_photon_grid(positions, cell_size, bin_rank, len(bin_g) if binned else 1, occupancy)
    n = grid.order.shape[0]
    if lights != 1 and (light is None or light.shape != (n,) or (light.size and int(light.max()) >= lights)):
        raise ValueError(f"light must be (n,) indices below lights = {lights}")
    return PhotonIndex(grid, *gather_attributes(grid, directions, weights),
                       np.take(np.asarray(light, np.uint8), grid.order) if lights != 1 else None, int(lights),
                       np.take(np.asarray(bin_rank, np.uint8), grid.order) if binned else None,
                       bin_g if binned else None, float(half_width) if binned else 0.0)


def gather_attributes(grid: PhotonGrid, directions: np.ndarray,
                      weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions and weights ((n, 3), the photons' original order) gathered into the grid's order, float32."""
    n = grid.order.shape[0]
    out = []
    for name, a in (("directions", directions), ("weights", weights)):
        a = np.asarray(a)
        if a.shape != (n, 3):
            raise ValueError(f"{name} must have shape ({n}, 3) like the grid's positions, got {a.shape}")
        out.append(np.take(a, grid.order, axis=0).astype(np.float32, copy=False))  # np.take: ~3x faster than a[order]
    return out[0], out[1]
