"""Selecting the K nearest among a query's candidate photons, for the search of
:mod:`photon_fields.runtime.photons.knn`: arrays of squared distances ``d2`` (and photon indices ``idx``) filled by
the scan, reduced in place. A quickselect on values only finds the K-th distance (out of place, branch-free
partitions, ties dropped and counted), then the buffer is compacted to exactly K entries; bands and filters narrow
what the selection looks at. All numba, called from the search's per-worker loops.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from photon_fields.runtime.numba_inlining import install

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

_SAMPLES = 15  # pivot sample size of the selection


@njit(cache=True, inline="always")
def _pivot(src: np.ndarray, n: int, kk: int, smp: np.ndarray) -> float:
    """Pivot for selecting rank kk of src[:n]: the sample quantile nearest kk of _SAMPLES evenly spaced
    entries (insertion-sorted into smp), or a median of 3 for short ranges."""
    if n < 4 * _SAMPLES:
        a = src[0]
        b = src[n >> 1]
        c = src[n - 1]
        return max(min(a, b), min(max(a, b), c))
    stride = n // _SAMPLES
    for s in range(_SAMPLES):
        v = src[stride // 2 + s * stride]
        t = s
        while t > 0 and smp[t - 1] > v:
            smp[t] = smp[t - 1]
            t -= 1
        smp[t] = v
    return smp[min(_SAMPLES - 1, kk * _SAMPLES // n)]


@njit(cache=True)
def kth_value(d2: np.ndarray, count: int, k: int, tmp: np.ndarray) -> tuple[float, int]:
    """The k-th smallest of d2[:count] and how many entries are strictly smaller; d2 is left untouched.

    Quickselect on values only, out of place: each pass streams the range once, appending the entries
    < pivot to one row of tmp and those > pivot to another, both unconditionally with conditional cursor
    increments -- no data-dependent branch and no store-to-load chain through the array (an in-place
    Lomuto partition was 3x slower). Only the side holding rank k is kept; it becomes the next source
    and the other two rows the next destinations. Entries equal to the pivot are dropped and counted,
    so runs of ties (duplicate photons) end the search at once."""
    kk = k - 1
    below = 0
    src_row = -1  # -1: d2 itself
    n = count
    while True:
        src = d2[:n] if src_row < 0 else tmp[src_row, :n]
        if n == 1:
            return src[0], below
        lo_row = 0 if src_row != 0 else 1
        hi_row = 3 - lo_row - src_row if src_row >= 0 else 1
        dlo = tmp[lo_row]
        dhi = tmp[hi_row]
        x = _pivot(src, n, kk, dlo)
        nlo = 0
        nhi = 0
        for j in range(n):
            v = src[j]
            dlo[nlo] = v
            dhi[nhi] = v
            nlo += v < x
            nhi += v > x
        if kk < nlo:
            src_row, n = lo_row, nlo
        elif kk < n - nhi:
            return x, below + nlo
        else:
            below += n - nhi
            kk -= n - nhi
            src_row, n = hi_row, nhi


@njit(cache=True)
def heapsort(d2: np.ndarray, idx: np.ndarray, m: int) -> None:
    """In-place ascending sort of d2/idx[:m] (no allocation: safe inside prange)."""
    for start in range(m // 2 - 1, -1, -1):
        _sift_down(d2, idx, start, m)
    for end in range(m - 1, 0, -1):
        d2[0], d2[end] = d2[end], d2[0]
        idx[0], idx[end] = idx[end], idx[0]
        _sift_down(d2, idx, 0, end)


@njit(cache=True, inline="always")
def _sift_down(d2: np.ndarray, idx: np.ndarray, root: int, m: int) -> None:
    while True:
        child = 2 * root + 1
        if child >= m:
            return
        if child + 1 < m and d2[child + 1] > d2[child]:
            child += 1
        if d2[root] >= d2[child]:
            return
        d2[root], d2[child] = d2[child], d2[root]
        idx[root], idx[child] = idx[child], idx[root]
        root = child


@njit(cache=True)
def keep_k(d2: np.ndarray, idx: np.ndarray, count: int, k: int, kth: float, below: int) -> int:
    """Compact d2/idx[:count] in place to exactly k entries: those < kth and the first k - below ties at
    kth. Branchless stream compactions (the write cursor never overtakes the read cursor); the usual case
    -- a single entry at kth -- needs one pass keeping d2 <= kth. Returns k."""
    w = filter_within(d2, idx, count, kth)
    if w == k:
        return k
    # More ties at kth than places: a second pass over the survivors (all <= kth) counts them.
    ties = k - below
    m = w
    w = 0
    for j in range(m):
        v = d2[j]
        t = idx[j]
        d2[w] = v
        idx[w] = t
        tie = v == kth
        keep = (v < kth) | (tie & (ties > 0))
        ties -= tie & keep
        w += keep
    return w


@njit(cache=True)
def filter_within(d2: np.ndarray, idx: np.ndarray, count: int, limit: float) -> int:
    """Keep the entries of d2/idx[:count] with d2 <= limit, in place and in order; returns their count."""
    w = 0
    for j in range(count):
        v = d2[j]
        t = idx[j]
        d2[w] = v
        idx[w] = t
        w += v <= limit
    return w


@njit(cache=True)
def band(d2: np.ndarray, count: int, lower: float, limit: float, out: np.ndarray) -> int:
    """Copy the values of d2[:count] in (lower, limit] to out (branch-free); returns how many."""
    nb = 0
    for j in range(count):
        v = d2[j]
        out[nb] = v
        nb += (v > lower) & (v <= limit)
    return nb


@njit(cache=True)
def compact_to_k(d2: np.ndarray, idx: np.ndarray, count: int, k: int, tmp: np.ndarray,
                 bound: float) -> tuple[int, float]:
    """Full buffer: keep the k closest; returns (k, new bound). Kept out of line: it runs rarely."""
    kth, below = kth_value(d2, count, k, tmp)
    # Strictly closer than the K-th from now on: a tie cannot improve the set.
    return keep_k(d2, idx, count, k, kth, below), min(bound, np.nextafter(kth, -np.inf))
