"""The fused volumetric radiance estimate over a photon grid (paper Eq. 5), on the K-nearest-photon search of
:mod:`photon_fields.runtime.photons.knn`.

Radiance estimate
-----------------
Jensen's adaptive-radius estimator for volumetric photon maps. At query point x with view direction d
(the camera ray's *travel* direction, unit length) and Henyey-Greenstein coefficient g:

    Q(x, d) = sum over the photons strictly inside the ball (x, r) of  p_g(cos_n) * w_n / (4/3 pi r^3)
    cos_n   = -dot(omega_n, d)   (photon n travels along omega_n and scatters towards the camera, along -d)
    r       = distance to the K-th nearest photon if at least K photons lie within r_max (the sum then runs
              over the K - 1 nearer ones), otherwise r_max (the whole ball was searched: shrinking r to the
              farthest photon found would overestimate the density).

Why K - 1. The K-th photon is not a sample of the ball's content: it is what *chose* the radius, and it sits
on the sphere. Counting it makes the estimate K / (K - 1) too bright on average (for Poisson photons of
density lambda, lambda V(r_K) is Gamma(K, 1) distributed and E[1 / Gamma(K, 1)] = 1 / (K - 1)); the K - 1
photons inside are, given r_K, uniform in the ball, so their sum over V(r_K) is unbiased. At K = 16 this is
the difference between +6.7 % and 0 (tests/runtime/photons/test_knn.py), which is what lets a small K, with
its small ball and small kernel bias at dense surfaces, be used at all. The radiance estimate therefore needs
K >= 2.

No photon within r_max gives Q = 0. ``r_max = inf`` is allowed (plain KNN); with fewer than K photons in
the whole map the estimate is then 0 (the volume is infinite). If K photons coincide exactly with the
query point, r = 0 and Q = +inf: that is the density of a point mass, not a bug of the search.

Parameters
----------
positions : (n, 3) float array
    Photon positions, stored as float64 in the grid (a float32 grid measured ~25 % slower: the scan
    then converts every coordinate, and 12 MB per million photons is not worth that).
directions, weights : (n, 3) float arrays, in the ORIGINAL photon order (the order of ``positions``)
    Unit travel directions omega_n and RGB powers w_n. :func:`knn_radiance` gathers them into grid
    order on every call (an O(n) copy, ~0.1 s per million photons here: as long as 2^16 queries at
    r_max = 0.01 take). For repeated estimates over one photon map, :func:`build_photon_index` gathers
    once and :func:`indexed_radiance` reuses it; a :class:`PhotonIndex` bundles the grid with its
    gathered attributes, so sorted attributes can never be paired with the wrong grid or passed where
    original-order ones are expected. Gathered, they are stored as float32 (the sums run in float64): they
    are read only for the K photons kept per query, and a fit holds 16 windows' worth of them (half the
    memory; estimates move by ~1e-7 relative).
view_dirs : (q, 3) float array
    Unit travel directions d of the camera rays at the queries (not normalized here).
g : float in [-1, 1]
    HG coefficient (``photon_fields.runtime.transport.phase`` convention: cos is between travel directions).
k : int >= 1
    Number of neighbours (1024 is the paper's default).
r_max : float > 0 (may be inf)
    Search radius bound; photons at distance exactly r_max are included.
cell_size : float or None
    Grid cell edge; ``None`` picks the default rule of :mod:`photon_fields.runtime.photons.photon_grid`.
    Results never depend on it (only speed).

Binned index
------------
A :class:`photon_fields.runtime.photons.photon_grid.PhotonIndex` with ``bin``/``bin_g``/``half_width`` holds the
photons of many narrow phase bins at once (sorted by cell, then bin). The estimate at g then searches only the bins
whose triangular weight 1 - |g_b - g| / half_width exceeds 1e-9 (a contiguous run: the bins are ranked by g, so each
cell's share is one span) and multiplies each photon's weight by its bin's weight over the sum of those weights:
the estimate over the weighted union of the kernel's bins (:mod:`photon_fields.runtime.photons.phase_window`),
with the kernel centred at each query's own g. With every bin in the kernel a row of cells is still one span.

Threads, blocks and per-worker scratch as the search's (:mod:`photon_fields.runtime.photons.knn`). The fused
estimator never materializes (q, K) arrays: its memory is O(q + T K).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.photons.knn import (
    _capacity,
    _check_query_args,
    _morton_order,
    _n_workers,
    _search,
    _worker_scratch,
    _worker_slots,
)
from photon_fields.runtime.photons.photon_grid import PhotonGrid, PhotonIndex, gather_attributes
from photon_fields.runtime.transport.phase import check_g, hg_eval

_FOUR_THIRDS_PI = 4.0 / 3.0 * math.pi
_KERNEL_EPS = 1e-9  # a bin's kernel weight must exceed this to count (phase_window's _EPS)


@njit(cache=True)
def _kernel_bins(bin_g: np.ndarray, half_width: float, g: float) -> tuple[int, int, float]:
    """The bins b0..b1 of g's triangular kernel (weight 1 - |g_b - g| / h above 1e-9, as
    :func:`photon_fields.runtime.photons.phase_window.window_weights`) and 1 / their weights' sum; (0, -1, 0)
    when no bin lies inside the kernel. ``bin_g`` ascending."""
    b0 = -1
    b1 = -1
    total = 0.0
    for b in range(bin_g.shape[0]):
        w = 1.0 - abs(bin_g[b] - g) / half_width
        if w > _KERNEL_EPS:
            if b0 < 0:
                b0 = b
            b1 = b
            total += w
    if b0 < 0:
        return np.int64(0), np.int64(-1), 0.0
    return np.int64(b0), np.int64(b1), 1.0 / total


@njit(cache=True, parallel=True, nogil=True)
def _radiance_kernel(pos: np.ndarray, cell_start: np.ndarray, origin: np.ndarray, h: float, dims: np.ndarray,
                     nb: int, dirs: np.ndarray, wts: np.ndarray, light: np.ndarray, lights: int, rank: np.ndarray,
                     bin_g: np.ndarray, half_width: float, queries: np.ndarray, view: np.ndarray, qorder: np.ndarray,
                     g: np.ndarray, k: int, r_max: float, nw: int,
                     cap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # lights > 1: photon j's weights go to the RGB columns 3 light[j] .. 3 light[j] + 2 of the estimate.
    # half_width > 0 (a binned grid): the search reads the bins of the query's kernel in g, photon j's weights
    # times its bin's kernel weight (rank[j]: the bin; bin_g: the bins' g).
    q = queries.shape[0]
    est = np.zeros((q, 3 * lights))
    radius = np.full(q, r_max)
    found = np.zeros(q, dtype=np.int64)
    d2, idx, tmp = _worker_scratch(nw, cap)
    acc = np.empty((nw, 3 * lights))
    binned = half_width > 0.0
    for w in prange(nw):
        for t in _worker_slots(w, nw, q):
            i = qorder[t]
            gi = g[i]
            b0 = 0
            b1 = nb - 1
            inv_total = 1.0
            if binned:
                kernel = _kernel_bins(bin_g, half_width, gi)
                b0 = kernel[0]
                b1 = kernel[1]
                inv_total = kernel[2]
                if b1 < b0:
                    continue  # no bin within the kernel: no photon
            m, kth = _search(pos, cell_start, origin, h, dims, nb, b0, b1, queries[i, 0], queries[i, 1],
                             queries[i, 2], k, r_max, d2[w], idx[w], tmp[w])
            found[i] = m
            if m == 0:
                continue
            r = r_max if m < k else math.sqrt(kth)
            radius[i] = r
            # With the K-th photon's radius, that photon lies on the sphere and is left out (module docstring).
            skip = kth if m >= k else -1.0
            vx, vy, vz = view[i, 0], view[i, 1], view[i, 2]
            for c in range(3 * lights):
                acc[w, c] = 0.0
            for jj in range(m):
                if d2[w, jj] == skip:
                    skip = -1.0  # only one photon, even when several tie at the K-th distance
                    continue
                j = np.uint64(idx[w, jj])
                p = hg_eval(gi, -(dirs[j, 0] * vx + dirs[j, 1] * vy + dirs[j, 2] * vz))
                if binned:
                    p *= (1.0 - abs(bin_g[rank[j]] - gi) / half_width) * inv_total
                col = 3 * np.int64(light[j]) if lights > 1 else 0
                acc[w, col] += p * wts[j, 0]
                acc[w, col + 1] += p * wts[j, 1]
                acc[w, col + 2] += p * wts[j, 2]
            inv_vol = 1.0 / (_FOUR_THIRDS_PI * r * r * r)
            for c in range(3 * lights):
                est[i, c] = acc[w, c] * inv_vol
    return est, radius, found


def _per_query_g(g: float | np.ndarray, queries: np.ndarray) -> np.ndarray:
    """g as a float64 array (q,), checked to lie in [-1, 1]."""
    if np.ndim(g) == 0:
        return np.full(queries.shape[0], check_g(g))
    ga = np.ascontiguousarray(g, dtype=np.float64)
    if ga.shape != (queries.shape[0],):
        raise ValueError(f"g must be a number or have shape ({queries.shape[0]},) like the queries, got {ga.shape}")
    if not np.all(np.abs(ga) <= 1.0):  # also refuses NaN
        raise ValueError("every g must lie in [-1, 1]")
    return ga


def indexed_radiance(index: PhotonIndex, queries: np.ndarray, view_dirs: np.ndarray, g: float | np.ndarray, k: int,
                     r_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fused estimate Q (module docstring) over a PhotonIndex (attributes already in grid order), with
    the phase function's g one for all queries (a number) or one per query (q,).

    Returns (estimate (q, 3 L) float64, radius (q,) float64 = r of the formula (r_max when fewer than k
    photons were found), found (q,) int64 = min(k, count within r_max) photons found (k - 1 of them are
    summed when k were found)). L is the index's ``lights`` (1, or with a ``light`` array one RGB triple per
    light, columns 3 l .. 3 l + 2 from the photons of light l: the same search, split by light; their sum is the
    estimate without the split). Needs k >= 2 (module docstring: why K - 1)."""
    qs, k, r = _check_query_args(queries, k, r_max)
    if k < 2:
        raise ValueError(f"the radiance estimate needs k >= 2 (the k-th photon only sets the radius), got {k}")
    vd = np.ascontiguousarray(view_dirs, dtype=np.float64)
    if vd.shape != qs.shape:
        raise ValueError(f"view_dirs must have shape {qs.shape} like queries, got {vd.shape}")
    grid = index.grid
    light = np.zeros(0, np.uint8) if index.light is None else index.light
    rank = np.zeros(0, np.uint8) if index.bin is None else index.bin
    bin_g = np.zeros(0) if index.bin_g is None else index.bin_g
    return _radiance_kernel(grid.positions, grid.cell_start, grid.origin, float(grid.cell_size), grid.dims,
                            int(grid.bins), index.directions, index.weights, light, index.lights, rank, bin_g,
                            float(index.half_width), qs, vd, _morton_order(grid, qs), _per_query_g(g, qs), k, r,
                            _n_workers(qs.shape[0]), _capacity(k, grid.order.shape[0]))


def knn_radiance(grid: PhotonGrid, directions: np.ndarray, weights: np.ndarray, queries: np.ndarray,
                 view_dirs: np.ndarray, g: float | np.ndarray, k: int,
                 r_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fused estimate Q with ``directions``/``weights`` (n, 3) in the ORIGINAL photon order.

    Gathers them into grid order first (O(n) per call); for many calls on one map use
    build_photon_index + indexed_radiance. Returns (estimate (q, 3), radius (q,), found (q,))."""
    return indexed_radiance(PhotonIndex(grid, *gather_attributes(grid, directions, weights)), queries, view_dirs,
                               g, k, r_max)
