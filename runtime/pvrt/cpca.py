"""Clustered PCA of the per-voxel transfer matrices (paper Sec. 6.4, Eq. 16; Sloan et al. 2003 [34]).

Each occupied cell's transfer matrix (``m x parts x n``, flattened to a vector of length D) is assigned to one of
K clusters by k-means in signal space ("vector quantization"); within cluster k, PCA gives the mean ``T_mean^k``
and N basis matrices ``T_i^k``, and each cell keeps its cluster index and N weights ``w_i``:

    T ~ T_mean^k + sum_i w_i T_i^k            (Eq. 16)

Cells whose matrix is all zero (no photon reached them: empty space) are left out and get cluster -1 and zero
weights ("empty voxels ... are excluded from the clustering and zero weights are assigned directly").
k-means is seeded (k-means++ from ``numpy.random.default_rng(seed)``) and runs a fixed number of Lloyd
iterations, so the same transfer and seed give the same bytes.

Parts of very different magnitude (the direct part is several times the multiple scattering) would leave the small
one to the truncation: the clustering and PCA run on the matrices with each part scaled to unit RMS (``groups``),
and the means and bases are scaled back, so the compressed form still reconstructs the original matrices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.pvrt.constants import KMEANS_ITERATIONS

#: Rows per block of the passes over a cluster's or the transfer's rows (bounded float64 temporaries).
_ROW_BLOCK = 4096


@dataclass
class CPCA:
    cluster: np.ndarray  # int32 (V,): cluster of each cell, -1 for empty cells
    weights: np.ndarray  # float32 (V, N)
    mean: np.ndarray  # float32 (K, D)
    basis: np.ndarray  # float32 (K, N, D)
    relative_error: float  # ||X - X_hat||_F / ||X||_F over all cells

    def reconstruct(self) -> np.ndarray:
        """The approximated matrices (V, D) (zero for empty cells)."""
        out = np.zeros((len(self.cluster), self.mean.shape[1]), np.float32)
        full = self.cluster >= 0
        c = self.cluster[full]
        out[full] = self.mean[c] + np.einsum("vn,vnd->vd", self.weights[full], self.basis[c])
        return out


def _kmeans(x: np.ndarray, k: int, rng: np.random.Generator, iterations: int) -> np.ndarray:
    """Labels (n,) of Lloyd's k-means with k-means++ seeding (distances in ``x``'s precision, centres in float64)."""
    n = len(x)
    sq = np.einsum("ij,ij->i", x, x, dtype=np.float64)

    def dot(c: np.ndarray) -> np.ndarray:  # x @ c in x's precision (no float64 copy of x), as float64
        return (x @ c.astype(x.dtype)).astype(np.float64)

    centres = [x[int(rng.integers(n))].astype(np.float64)]
    d2 = np.maximum(sq - 2 * dot(centres[0]) + centres[0] @ centres[0], 0)
    for _ in range(1, k):
        p = d2 / d2.sum() if d2.sum() > 0 else np.full(n, 1.0 / n)
        c = x[int(rng.choice(n, p=p))].astype(np.float64)
        centres.append(c)
        d2 = np.minimum(d2, np.maximum(sq - 2 * dot(c) + c @ c, 0))
    cen = np.array(centres)
    labels = np.zeros(n, np.int64)
    for _ in range(iterations):
        dist = sq[:, None] - 2 * dot(cen.T) + np.einsum("ij,ij->i", cen, cen)[None, :]
        labels = np.argmin(dist, axis=1)
        for j in range(k):
            sel = labels == j
            if sel.any():
                cen[j] = x[sel].mean(axis=0, dtype=np.float64)
    return labels


def _principal_axes(centred: np.ndarray, count: int) -> np.ndarray:
    """The first ``count`` principal axes (rows, by decreasing variance) of the centred rows ``centred`` (n, d).
    With more rows than columns, from the eigenvectors of the d x d scatter matrix (float64): an SVD of the rows
    held an (n, d) float64 factor besides them, a gigabyte for a large cluster of a head's 1512-long matrices."""
    n, d = centred.shape
    if n <= d:
        return np.linalg.svd(centred.astype(np.float64), full_matrices=False)[2][:count]
    scatter = np.zeros((d, d))
    for lo in range(0, n, _ROW_BLOCK):  # in blocks: no float64 copy of the rows
        block = centred[lo:lo + _ROW_BLOCK].astype(np.float64)
        scatter += block.T @ block
    _, vectors = np.linalg.eigh(scatter)
    return vectors[:, ::-1][:, :count].T


def compress(matrices: np.ndarray, clusters: int, bases: int, seed: int = 0,
             iterations: int = KMEANS_ITERATIONS, groups: np.ndarray | None = None) -> CPCA:
    """CPCA of ``matrices`` (V, ...) flattened per cell: ``clusters`` clusters (fewer if there are fewer occupied
    cells), ``bases`` PCA bases each (module docstring). ``groups`` (D,) ints: the part of each flattened entry,
    each scaled to unit RMS for the fit (None: one group)."""
    if isinstance(clusters, bool) or not isinstance(clusters, (int, np.integer)) or not 1 <= clusters <= 4096:
        raise InputError("clusters", f"must be an integer in [1, 4096], got {clusters!r}")
    if isinstance(bases, bool) or not isinstance(bases, (int, np.integer)) or not 0 <= bases <= 64:
        raise InputError("pca bases", f"must be an integer in [0, 64], got {bases!r}")
    v = matrices.shape[0]
    x32 = matrices.reshape(v, -1)
    d = x32.shape[1]
    occupied = np.flatnonzero(np.any(x32 != 0, axis=1))
    cluster = np.full(v, -1, np.int32)
    weights = np.zeros((v, bases), np.float32)
    if occupied.size == 0:
        return CPCA(cluster, weights, np.zeros((1, d), np.float32), np.zeros((1, bases, d), np.float32), 0.0)
    # One float32 working copy of the occupied rows, scaled in place: the transfer itself can be hundreds of MB
    # (constants.TRANSFER_BUDGET_BYTES), and float64 copies of it doubled and tripled the precomputation's memory.
    x = x32[occupied].astype(np.float32)
    grp = np.zeros(d, np.int64) if groups is None else np.asarray(groups).reshape(-1)
    scale = np.ones(d)
    for gi in np.unique(grp):
        rms = float(np.sqrt(np.mean(np.square(x[:, grp == gi], dtype=np.float64))))
        scale[grp == gi] = rms if rms > 0 else 1.0
    x /= scale.astype(np.float32)
    k = min(int(clusters), len(x))
    labels = _kmeans(x, k, np.random.default_rng(seed), iterations)
    mean = np.zeros((k, d))
    basis = np.zeros((k, bases, d))
    w = np.zeros((len(x), bases))
    for j in range(k):
        sel = np.flatnonzero(labels == j)
        if sel.size == 0:
            continue
        mean[j] = x[sel].mean(axis=0, dtype=np.float64)
        centred = x[sel] - mean[j].astype(x.dtype)
        if bases > 0 and sel.size > 1:
            vt = _principal_axes(centred, bases)
            nb = min(bases, vt.shape[0])
            # A deterministic sign per component: its largest entry positive.
            signs = np.sign(vt[np.arange(nb), np.argmax(np.abs(vt[:nb]), axis=1)])
            basis[j, :nb] = vt[:nb] * signs[:, None]
            w[sel] = centred @ basis[j].T.astype(centred.dtype)  # no float64 copy of the rows
        del centred
    del x
    cluster[occupied] = labels.astype(np.int32)
    weights[occupied] = w.astype(np.float32)
    out = CPCA(cluster, weights, (mean * scale).astype(np.float32), (basis * scale).astype(np.float32), 0.0)
    err2 = total2 = 0.0
    for lo in range(0, len(occupied), _ROW_BLOCK):  # the error a block of rows at a time (bounded memory)
        rows = occupied[lo:lo + _ROW_BLOCK]
        c = cluster[rows]
        approx = out.mean[c] + np.einsum("vn,vnd->vd", weights[rows], out.basis[c])
        err2 += float(np.sum(np.square(approx - x32[rows], dtype=np.float64)))
        total2 += float(np.sum(np.square(x32[rows], dtype=np.float64)))
    out.relative_error = float(np.sqrt(err2) / max(np.sqrt(total2), 1e-300))
    return out
