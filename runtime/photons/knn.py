"""K-nearest-photon search on a uniform grid (the search of paper Eq. 5's estimate, which is
:mod:`photon_fields.runtime.photons.knn_radiance`).

Search algorithm
----------------
Per query, the cells overlapping the r_max ball (clamped to the grid) are visited ring by ring around
the query's cell (ring s = the cells at Chebyshev distance s from it). A ring is scanned row by row: a
row (fixed ix, iy) is skipped if its distance to x exceeds the current bound and otherwise trimmed along
z to the cells the bound's ball reaches, so a shell row is one contiguous span of photons and an
interior row contributes its two end cells. Photons with distance^2 <= bound are appended to a
per-worker candidate buffer (written unconditionally, kept by a conditional increment: no mispredicted
branch per photon). The bound starts at r_max^2.

After each ring the radius the searched block of cells certainly covers, ``safe`` (distance from x to
the block's faces; faces at the grid's edge count as infinitely far), is known:

- safe >= r_max: the whole ball has been searched, stop;
- with at least K candidates, one pass counts them within eight radii safe + {-1, -3/4, -1/2, -1/4, 0,
  1/2, 1, 2} h. K within ``safe``: stop; the smallest of the first five radii holding K and the one
  below it then bracket the K-th distance, so the selection only has to look at the candidates in that
  band (a few hundred for K = 1024 instead of ~2 K). Otherwise the bound tightens to the smallest of
  the last three radii holding K, so the next ring scans only cells that can still matter;
- the ring reached the r_max box's far corner: stop.

The early stop is what makes small K-th distances cheap: a query in a dense cluster stops after a ring
or two whatever r_max is. The K-th distance is then found by a quickselect on values only (out of place,
branch-free partitions, ties dropped and counted: :mod:`photon_fields.runtime.photons.knn_select`), and the
buffer is compacted to exactly K entries (those below the K-th distance plus as many ties at it as needed; ties
are broken by scan order, i.e. arbitrarily). A buffer that fills up (capacity 4 K + 64, or n + 1 if smaller, so that
a huge K costs no memory beyond the photon count) is compacted the same way mid-scan, and the bound
becomes "strictly closer than that K-th". Correctness never depends on the cell size: large cells cost
scanning, small ones loop overhead. Tiny geometric slacks (1e-9 h) guard against rounding at cell faces.

Threads: queries are processed in blocks of ``_BLOCK`` in Morton order of their cells (neighbouring
queries touch the same photons, which keeps the photon arrays in cache); ``prange`` runs one worker per
numba thread, worker t taking blocks t, t + T, ... (interleaving balances clustered work under the
static OpenMP schedule). Per-worker scratch is allocated once, outside the ``prange`` body.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import njit, prange

from photon_fields.runtime.numba_inlining import install
from photon_fields.runtime.photons.knn_select import band, compact_to_k, heapsort, keep_k, kth_value
from photon_fields.runtime.photons.photon_grid import PhotonGrid, cell_coord

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

_BLOCK = 64  # queries per work block
_SLACK = 1e-9  # relative (to the cell size) safety margin at cell faces


# ----------------------------------------------------------------------------------------------------------
# Numba kernels


@njit(cache=True)
def _gap(p: float, face_lo: float, h: float, slack: float) -> float:
    """Distance from coordinate p to the interval [face_lo, face_lo + h], shrunk by slack."""
    if p < face_lo:
        return max(face_lo - p - slack, 0.0)
    if p > face_lo + h:
        return max(p - face_lo - h - slack, 0.0)
    return 0.0


@njit(cache=True)
def _scan_chunk(pos: np.ndarray, j: int, n: int, x: float, y: float, z: float, d2: np.ndarray, idx: np.ndarray,
                count: int, bound: float) -> int:
    """Append sorted photons j..j+n-1 with distance^2 <= bound at d2/idx[count:] (room is the caller's job).

    Unsigned indices spare numba's negative-index wraparound code, which doubled the cost of this loop."""
    for t in range(n):
        p = np.uint64(j + t)
        dx = pos[p, 0] - x
        dy = pos[p, 1] - y
        dz = pos[p, 2] - z
        dd = dx * dx + dy * dy + dz * dz
        # Write unconditionally, keep conditionally: no mispredicted branch per photon.
        c = np.uint64(count)
        d2[c] = dd
        idx[c] = j + t
        count += dd <= bound
    return count


@njit(cache=True)
def _search(pos: np.ndarray, cell_start: np.ndarray, origin: np.ndarray, h: float, dims: np.ndarray, nb: int,
            bin_lo: int, bin_hi: int, x: float, y: float, z: float, k: int, r_max: float, d2: np.ndarray,
            idx: np.ndarray, tmp: np.ndarray) -> tuple[int, float]:
    """K nearest photons of (x, y, z) within r_max into d2/idx (sorted-photon indices), among the photons of bins
    bin_lo..bin_hi of a grid of nb bins per cell (a plain grid: nb = 1, bin_lo = bin_hi = 0).

    Returns (m, kth): m = min(k, count within r_max) entries in d2/idx[:m], unordered; kth = the K-th
    distance^2 if m == k, else inf."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    ox, oy, oz = origin[0], origin[1], origin[2]
    inv_h = 1.0 / h
    slack = _SLACK * h
    r2max = r_max * r_max
    cap = d2.shape[0]
    # The query's cell, clamped to [-1, dims]: a query outside the grid then sits in a virtual cell just
    # beyond it, which keeps the face distances below positive on the sides that still hold photons.
    cx = cell_coord(x, ox, inv_h, -1, nx)
    cy = cell_coord(y, oy, inv_h, -1, ny)
    cz = cell_coord(z, oz, inv_h, -1, nz)
    # Cells overlapping the r_max ball, clamped to the grid.
    lx = cell_coord(x - r_max - slack, ox, inv_h, 0, nx - 1)
    hx = cell_coord(x + r_max + slack, ox, inv_h, 0, nx - 1)
    ly = cell_coord(y - r_max - slack, oy, inv_h, 0, ny - 1)
    hy = cell_coord(y + r_max + slack, oy, inv_h, 0, ny - 1)
    lz = cell_coord(z - r_max - slack, oz, inv_h, 0, nz - 1)
    hz = cell_coord(z + r_max + slack, oz, inv_h, 0, nz - 1)
    gx = _gap(x, ox, nx * h, slack)
    gy = _gap(y, oy, ny * h, slack)
    gz = _gap(z, oz, nz * h, slack)
    if gx * gx + gy * gy + gz * gz > r2max:
        return 0, math.inf  # the ball misses the grid box
    s_start = max(max(lx - cx, cx - hx, 0), max(ly - cy, cy - hy, 0), max(lz - cz, cz - hz, 0))
    s_end = max(max(cx - lx, hx - cx), max(cy - ly, hy - cy), max(cz - lz, hz - cz))
    all_bins = bin_lo == 0 and bin_hi == nb - 1
    count = 0
    bound = r2max
    # After the loop, if finite: the K-th distance^2 lies in (lower, limit], n_lower candidates <= lower.
    limit = math.inf
    lower = -1.0
    n_lower = 0
    for s in range(s_start, s_end + 1):
        for ix in range(max(cx - s, lx), min(cx + s, hx) + 1):
            gx = _gap(x, ox + ix * h, h, slack)
            gx2 = gx * gx
            if gx2 > bound:
                continue
            on_x = ix == cx - s or ix == cx + s
            row = ix * ny
            for iy in range(max(cy - s, ly), min(cy + s, hy) + 1):
                gy = _gap(y, oy + iy * h, h, slack)
                gxy2 = gx2 + gy * gy
                if gxy2 > bound:
                    continue
                # Trim the row to the cells the current ball reaches along z.
                rz = math.sqrt(bound - gxy2) + slack
                z0 = max(cell_coord(z - rz, oz, inv_h, 0, nz - 1), cz - s)
                z1 = min(cell_coord(z + rz, oz, inv_h, 0, nz - 1), cz + s)
                base = (row + iy) * nz
                shell = on_x or iy == cy - s or iy == cy + s
                # A shell row of ring s is one contiguous span of photons (cells z0..z1); an interior row
                # contributes only its two end cells. One scanning site for both on purpose: each site of
                # a call taking arrays costs numba reference-count traffic (~8 atomics) per span.
                # With every bin of a cell wanted, cells za..zb are one span; otherwise one span per cell.
                for part in range(1 if shell else 2):
                    za = z0 if shell else (cz - s if part == 0 else cz + s)
                    zb = z1 if shell else za
                    if za < z0 or zb > z1 or za > zb:
                        continue
                    spans = 1 if all_bins else zb - za + 1
                    for sp in range(spans):
                        if all_bins:
                            j = np.int64(cell_start[(base + za) * nb])
                            b = np.int64(cell_start[(base + zb + 1) * nb])
                        else:
                            key = (base + za + sp) * nb
                            j = np.int64(cell_start[key + bin_lo])
                            b = np.int64(cell_start[key + bin_hi + 1])
                        while j < b:
                            if count == cap:
                                count, bound = compact_to_k(d2, idx, count, k, tmp, bound)
                            n = min(b - j, cap - count)  # cannot overflow the buffer
                            count = _scan_chunk(pos, j, n, x, y, z, d2, idx, count, bound)
                            j += n
        # Radius certainly covered by the cells searched so far (faces at the grid's edge: infinite).
        safe = math.inf
        if cx - s > 0:
            safe = min(safe, x - (ox + (cx - s) * h))
        if cx + s + 1 < nx:
            safe = min(safe, ox + (cx + s + 1) * h - x)
        if cy - s > 0:
            safe = min(safe, y - (oy + (cy - s) * h))
        if cy + s + 1 < ny:
            safe = min(safe, oy + (cy + s + 1) * h - y)
        if cz - s > 0:
            safe = min(safe, z - (oz + (cz - s) * h))
        if cz + s + 1 < nz:
            safe = min(safe, oz + (cz + s + 1) * h - z)
        safe = max(safe - slack, 0.0)
        if safe >= r_max:
            break  # the whole r_max ball has been searched
        if count >= k:
            # Counts at a few radii around the searched one instead of a selection (one pass of compares).
            # K within the searched radius: done, and the smallest radius a_i holding K together with the
            # one below it bracket the K-th distance, so the selection runs on that band only. Otherwise
            # tighten the bound to the smallest radius beyond that holds K, so the next ring scans less.
            a0 = max(safe - h, 0.0) ** 2
            a1 = max(safe - 0.75 * h, 0.0) ** 2
            a2 = max(safe - 0.5 * h, 0.0) ** 2
            a3 = max(safe - 0.25 * h, 0.0) ** 2
            a4 = safe * safe
            b1 = (safe + 0.5 * h) ** 2
            b2 = (safe + h) ** 2
            b3 = (safe + 2.0 * h) ** 2
            n0 = 0
            n1 = 0
            n2 = 0
            n3 = 0
            n4 = 0
            m1 = 0
            m2 = 0
            m3 = 0
            for j in range(count):
                v = d2[j]
                n0 += v <= a0
                n1 += v <= a1
                n2 += v <= a2
                n3 += v <= a3
                n4 += v <= a4
                m1 += v <= b1
                m2 += v <= b2
                m3 += v <= b3
            if n4 >= k:
                if n0 >= k:
                    limit, lower, n_lower = a0, -1.0, 0
                elif n1 >= k:
                    limit, lower, n_lower = a1, a0, n0
                elif n2 >= k:
                    limit, lower, n_lower = a2, a1, n1
                elif n3 >= k:
                    limit, lower, n_lower = a3, a2, n2
                else:
                    limit, lower, n_lower = a4, a3, n3
                break
            if m1 >= k:
                bound = min(bound, b1)
            elif m2 >= k:
                bound = min(bound, b2)
            elif m3 >= k:
                bound = min(bound, b3)
    if count < k:
        return count, math.inf
    if limit < math.inf:
        # Everything <= lower is in, everything > limit out: select within the band (lower, limit].
        nb = band(d2, count, lower, limit, tmp[2])
        kth, below = kth_value(tmp[2], nb, k - n_lower, tmp)  # its later passes may reuse row 2
        below += n_lower
    else:
        kth, below = kth_value(d2, count, k, tmp)
    return keep_k(d2, idx, count, k, kth, below), kth


@njit(cache=True, inline="always")
def _worker_scratch(nw: int, cap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    # Per-worker candidate buffers of a query kernel: squared distances, photon indices, selection scratch.
    return np.empty((nw, cap)), np.empty((nw, cap), dtype=np.int64), np.empty((nw, 3, cap))


@njit(cache=True, inline="always")
def _worker_slots(w: int, nw: int, q: int) -> np.ndarray:
    # The query slots worker w handles: blocks w, w + nw, w + 2 nw, ... of _BLOCK slots each (Morton order).
    nblocks = (q + _BLOCK - 1) // _BLOCK
    mine = max(0, (nblocks - w + nw - 1) // nw)
    slots = np.empty(mine * _BLOCK, dtype=np.int64)
    n = 0
    for blk in range(w, nblocks, nw):
        for t in range(blk * _BLOCK, min(q, (blk + 1) * _BLOCK)):
            slots[n] = t
            n += 1
    return slots[:n]


@njit(cache=True, parallel=True)
def _knn_query_kernel(pos: np.ndarray, order: np.ndarray, cell_start: np.ndarray, origin: np.ndarray, h: float,
                      dims: np.ndarray, nb: int, queries: np.ndarray, qorder: np.ndarray, k: int,
                      r_max: float, nw: int, cap: int) -> tuple[np.ndarray, np.ndarray]:
    q = queries.shape[0]
    out_i = np.full((q, k), -1, dtype=np.int64)
    out_d = np.full((q, k), np.inf)
    d2, idx, tmp = _worker_scratch(nw, cap)
    for w in prange(nw):
        for t in _worker_slots(w, nw, q):
            i = qorder[t]
            m, _ = _search(pos, cell_start, origin, h, dims, nb, 0, nb - 1, queries[i, 0], queries[i, 1],
                           queries[i, 2], k, r_max, d2[w], idx[w], tmp[w])
            heapsort(d2[w], idx[w], m)
            for j in range(m):
                out_d[i, j] = d2[w, j]
                out_i[i, j] = order[idx[w, j]]
    return out_i, out_d


# ----------------------------------------------------------------------------------------------------------
# Python API


def _morton_order(grid: PhotonGrid, queries: np.ndarray) -> np.ndarray:
    """Query permutation along a Z-order curve of their grid cells (clamped), for cache locality."""
    q = queries.shape[0]
    if q <= _BLOCK:
        return np.arange(q, dtype=np.int64)
    cell = np.floor((queries - grid.origin) / grid.cell_size)
    cell = np.clip(cell, 0, grid.dims - 1).astype(np.uint64)
    code = np.zeros(q, dtype=np.uint64)
    for bit in range(21):  # 3 x 21 bits fit a uint64
        for axis in range(3):
            code |= ((cell[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable").astype(np.int64)


def _n_workers(q: int) -> int:
    """One worker per numba thread (numba's get_num_threads inside a kernel would defeat its cache)."""
    return max(1, min(numba.get_num_threads(), -(-q // _BLOCK)))


def _capacity(k: int, n: int) -> int:
    """Candidate buffer per worker: room for ~3K candidates between compactions, but never more than the
    n + 1 that can never fill up (so a huge k costs no memory beyond the photon count)."""
    return min(4 * k + 64, n + 1)


def _check_query_args(queries: np.ndarray, k: int, r_max: float) -> tuple[np.ndarray, int, float]:
    qs = np.ascontiguousarray(queries, dtype=np.float64)
    if qs.ndim != 2 or qs.shape[1] != 3:
        raise ValueError(f"queries must have shape (q, 3), got {qs.shape}")
    if not np.isfinite(qs).all():
        raise ValueError("queries must be finite")
    if int(k) != k or k < 1:
        raise ValueError(f"k must be a positive integer, got {k!r}")
    r = float(r_max)
    if not r > 0.0:  # also rejects NaN; inf is allowed
        raise ValueError(f"r_max must be > 0, got {r_max!r}")
    return qs, int(k), r


def knn_query(grid: PhotonGrid, queries: np.ndarray, k: int, r_max: float = math.inf) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest photons within r_max of each query (the general query, for tests and small q).

    Returns (indices (q, k) int64 into the ORIGINAL photon order, padded with -1; dist2 (q, k) float64
    squared distances sorted ascending, padded with inf). Memory is O(q k): use knn_radiance for the
    estimate over many queries."""
    qs, k, r = _check_query_args(queries, k, r_max)
    return _knn_query_kernel(grid.positions, grid.order, grid.cell_start, grid.origin, float(grid.cell_size),
                             grid.dims, int(grid.bins), qs, _morton_order(grid, qs), k, r, _n_workers(qs.shape[0]),
                             _capacity(k, grid.order.shape[0]))
