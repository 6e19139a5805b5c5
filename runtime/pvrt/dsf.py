"""The discrete spherical function (DSF, paper Sec. 5): interpolation-based, locally supported, rotation-invariant.

Directions ``w_1 .. w_n`` come from icosahedral subdivision (12, 42, 162, 642 ... for order 0, 1, 2, 3). A
spherical function is ``S(w) = sum_k wbar_k(w) s_k`` (Eq. 7) with the normalized weights

    wbar_k(w) = W_h(w, w_k) / sum_i W_h(w, w_i),     W_h(w_i, w_j) = (h^2 - theta_ij^2)^3 if theta_ij < h else 0 (Eq. 8)

and ``h`` the least angle between two sample directions, so ``W_h(w_i, w_j) = 0`` for ``i != j``: the coefficient
``s_k`` is the function's value at ``w_k`` (the interpolation property), and each basis function is nonzero only
within ``h`` of its direction (local support). The weights sum to 1 wherever some ``W_h`` is positive, which the
icosahedral mesh guarantees everywhere (every point of the sphere is within the circumradius of a mesh triangle of
a vertex, < h): constant functions are reproduced exactly.

:class:`DSF` also holds each basis function's solid angle ``Omega_k = integral wbar_k`` (the weights of the
projection of a directional light, Sec. 8.2) and each direction's neighbours within ``2 h`` (the directions whose
support can overlap its own: all the photon tracer needs to evaluate ``wbar_k`` inside the support of ``w_k``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from photon_fields.runtime.pvrt.constants import SPHERE_QUADRATURE


def icosphere(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit vertices (n, 3) and triangles (f, 3) of the icosahedron subdivided ``order`` times (Sec. 5.1)."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    verts = [np.array(p, dtype=np.float64) / np.linalg.norm(p) for p in v]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11),
             (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(order):
        mid: dict[tuple[int, int], int] = {}

        def midpoint(a: int, b: int, mid: dict[tuple[int, int], int] = mid) -> int:
            key = (min(a, b), max(a, b))
            if key not in mid:
                p = verts[a] + verts[b]
                verts.append(p / np.linalg.norm(p))
                mid[key] = len(verts) - 1
            return mid[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts), np.array(faces, dtype=np.int64)


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` near-uniform unit directions (n, 3): an equal-weight quadrature of the sphere (weights 4 pi / n)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


@njit(cache=True)
def dsf_weights(dirs: np.ndarray, h: float, x: float, y: float, z: float, cand: np.ndarray,
                out_idx: np.ndarray, out_w: np.ndarray) -> int:
    """Normalized DSF weights wbar_k (Eq. 7-8) at (x, y, z) over the candidate directions ``cand`` (indices;
    -1 ends the list): writes the nonzero ones to out_idx / out_w, returns how many."""
    n = 0
    total = 0.0
    h2 = h * h
    for c in range(cand.shape[0]):
        k = cand[c]
        if k < 0:
            break
        d = dirs[k, 0] * x + dirs[k, 1] * y + dirs[k, 2] * z
        th = math.acos(min(1.0, max(-1.0, d)))
        if th < h:
            w = (h2 - th * th) ** 3
            out_idx[n] = k
            out_w[n] = w
            total += w
            n += 1
    for i in range(n):
        out_w[i] /= total
    return n


@dataclass(frozen=True, eq=False)
class DSF:
    """The DSF basis of one order (module docstring)."""

    order: int
    dirs: np.ndarray  # (n, 3) float64 unit sample directions w_k
    faces: np.ndarray  # (f, 3) int64 icosahedral triangles (for the barycentric weights of Sec. 8.2)
    h: float  # kernel radius: the least angle between two directions (Eq. 8)
    neighbours: np.ndarray  # (n, max) int64: directions within 2 h of each (itself first), -1 padded
    solid_angle: np.ndarray  # (n,) Omega_k = integral of wbar_k over the sphere

    @classmethod
    def build(cls, order: int) -> DSF:
        dirs, faces = icosphere(order)
        cos = np.clip(dirs @ dirs.T, -1.0, 1.0)
        ang = np.arccos(cos)
        np.fill_diagonal(ang, np.inf)
        h = float(ang.min()) * (1.0 - 1e-9)  # W_h(w_i, w_j) = 0 for i != j exactly
        np.fill_diagonal(ang, 0.0)
        near = [np.concatenate([[k], np.flatnonzero((ang[k] < 2 * h) & (np.arange(len(dirs)) != k))])
                for k in range(len(dirs))]
        width = max(len(a) for a in near)
        neighbours = np.full((len(dirs), width), -1, dtype=np.int64)
        for k, a in enumerate(near):
            neighbours[k, : len(a)] = a
        basis = cls(order, dirs, faces, h, neighbours, np.zeros(len(dirs)))
        q = fibonacci_sphere(SPHERE_QUADRATURE)
        omega = basis.evaluate(q).sum(axis=0) * (4.0 * math.pi / len(q))
        return cls(order, dirs, faces, h, neighbours, omega)

    @property
    def size(self) -> int:
        return int(self.dirs.shape[0])

    def evaluate(self, w: np.ndarray) -> np.ndarray:
        """wbar_k(w) for unit directions ``w`` (q, 3): (q, n), rows summing to 1 (Eq. 7)."""
        w = np.asarray(w, dtype=np.float64).reshape(-1, 3)
        theta = np.arccos(np.clip(w @ self.dirs.T, -1.0, 1.0))
        k = np.where(theta < self.h, (self.h**2 - theta**2) ** 3, 0.0)
        return k / k.sum(axis=1, keepdims=True)

    def barycentric(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The icosahedral triangle holding direction ``w`` (3,) and the barycentric weights of ``w`` in it
        (Sec. 8.2: a directional light as the combination of three DSF basis lights): (indices (3,), weights (3,))."""
        w = np.asarray(w, dtype=np.float64)
        tri = self.dirs[self.faces]  # (f, 3 vertices, 3)
        lam = np.linalg.solve(np.transpose(tri, (0, 2, 1)), np.broadcast_to(w, (len(tri), 3))[..., None])[..., 0]
        f = int(np.argmax(lam.min(axis=1)))  # the face whose cone holds w: all three weights >= 0
        weights = np.maximum(lam[f], 0.0)
        return self.faces[f].copy(), weights / weights.sum()
