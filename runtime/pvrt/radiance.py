"""After a light change: the radiance volume (paper Sec. 7.1-7.2, Eq. 17-21) and the light volumes of the
directional lights' direct term (the NEE fall-back).

Early evaluation (Sec. 7.2). With the lighting's coefficients ``L_in`` (m, 3), every cluster's mean and basis
matrices are first reduced to radiance vectors, ``I_mean^k = T_mean^k L_in`` and ``I_i^k = T_i^k L_in`` (Eq. 17-18;
K (N + 1) small products instead of one per cell). Each cell then evaluates them towards the camera,
``L_V = Y(w_v) . (I_mean^k + sum_i w_i I_i^k) / D_v`` (Eq. 19-21; CPCA holds the photon energy, D_v the
extinction it is divided by, ``runtime/pvrt/precompute.py``; the volume keeps numerator and D_v apart and the
division happens at the camera's sample, :data:`CHANNELS`), where the SH coefficients carry the HG phase's band
factors ``g^l`` and ``w_v`` is the direction from the cell to the eye: one value per channel and cell, never the
full radiance vector. Channels: direct (RGB: the scalar direct transfer times the lighting's colour) and multiple
scattering (RGB).

Light volume. A directional light's direct term is NEE: its transmittance ``T(x -> light)`` is marched (the ray
marcher's shadow rays with empty-space skipping) from the centre of every cell of a grid (``DEFAULT_LIGHT_GRID``
along the longest side) once per light change, and camera samples interpolate it. Shadows are as sharp as that grid.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.pvrt.lighting import Lighting
from photon_fields.runtime.pvrt.precompute import grid_shape
from photon_fields.runtime.pvrt.sh import hg_band_factors, sh_count, sh_eval
from photon_fields.runtime.pvrt.transfer import Transfer
from photon_fields.runtime.renderers.ray_marcher import march_transmittance
from photon_fields.runtime.transport.medium import Medium

#: Radiance-volume channels: direct RGB and multiple-scattering RGB *photon energy* towards the eye (the CPCA
#: numerators, not divided by D_v), and D_v itself. The camera divides the trilinear interpolations of the two
#: (``runtime/renderers/pvrt.py``): the precomputation's ratio estimate carried on to the sample point, i.e. a
#: D_v-weighted interpolation of the per-cell radiance. Interpolating the per-cell quotients instead weighed a cell
#: that holds a thin wisp as much as a full one, and CPCA's error in such a cell's numerator, divided by its small
#: D_v, became a radiance error that did not average out: on the vortex (48^3, 32^3 grid) the L_i mean went from
#: 1.01 of the path tracer's uncompressed to 1.17 with 32 CPCA clusters and 0.19 with 128; D_v-weighted it is
#: 1.04, 1.08 and 1.08 (bench/README.md, PVRT). Cells without medium (D_v = 0) weigh nothing.
CHANNELS = 7


def cluster_responses(transfer: Transfer, lighting: Lighting) -> np.ndarray:
    """Eq. 17-18: (K, N + 1, CHANNELS, n) radiance vectors of every cluster's mean (index 0) and basis matrices."""
    m = transfer.basis.size
    n = sh_count(transfer.exitance_order)
    mats = np.concatenate([transfer.mean[:, None], transfer.basis_matrices], axis=1)  # (K, N + 1, D)
    mats = mats.reshape(mats.shape[0], mats.shape[1], m, 4, n).astype(np.float64)
    direct = np.einsum("abkj,kc->abcj", mats[:, :, :, 0], lighting.direct_coeffs)
    ms = np.einsum("abkcj,kc->abcj", mats[:, :, :, 1:], lighting.coeffs)
    return np.ascontiguousarray(np.concatenate([direct, ms], axis=2))


@njit(cache=True, parallel=True)
def _evaluate_cells(cluster: np.ndarray, mass: np.ndarray, weights: np.ndarray, resp: np.ndarray,
                    band: np.ndarray, lmax: int,
                    eye: np.ndarray, bmin: np.ndarray, bsize: np.ndarray, gx: int, gy: int, gz: int) -> np.ndarray:
    out = np.zeros((gx, gy, gz, resp.shape[2] + 1), dtype=np.float32)
    n = resp.shape[3]
    nb = weights.shape[1]
    for ix in prange(gx):
        y = np.empty(n)
        for iy in range(gy):
            for iz in range(gz):
                v = (ix * gy + iy) * gz + iz
                k = cluster[v]
                if mass[v] <= 0.0:
                    continue  # no medium within the kernel's reach: weight 0 in the camera's interpolation
                out[ix, iy, iz, resp.shape[2]] = mass[v]
                if k < 0:
                    continue  # medium that no photon reached: photon energy 0 (and D_v, it counts as dark)
                px = bmin[0] + (ix + 0.5) / gx * bsize[0]
                py = bmin[1] + (iy + 0.5) / gy * bsize[1]
                pz = bmin[2] + (iz + 0.5) / gz * bsize[2]
                dx, dy, dz = eye[0] - px, eye[1] - py, eye[2] - pz
                inv = 1.0 / max(math.sqrt(dx * dx + dy * dy + dz * dz), 1e-12)
                sh_eval(lmax, dx * inv, dy * inv, dz * inv, y)
                for j in range(n):
                    y[j] *= band[j]
                for c in range(resp.shape[2]):
                    acc = 0.0
                    for j in range(n):
                        s = resp[k, 0, c, j]
                        for i in range(nb):
                            s += weights[v, i] * resp[k, 1 + i, c, j]
                        acc += y[j] * s
                    out[ix, iy, iz, c] = acc
    return out


def radiance_volume(transfer: Transfer, lighting: Lighting, eye: np.ndarray, g: float) -> np.ndarray:
    """The view-dependent radiance volume (gx, gy, gz, CHANNELS) float32 (module docstring): photon energy
    scattered towards ``eye`` per unit albedo (before the camera's own albedo), and D_v (:data:`CHANNELS`)."""
    resp = cluster_responses(transfer, lighting)
    gx, gy, gz = transfer.grid
    box = transfer.manifest["box"]
    lmax = transfer.exitance_order
    return _evaluate_cells(transfer.cluster, transfer.mass.astype(np.float64), transfer.weights.astype(np.float64),
                           resp, hg_band_factors(g, lmax),
                           lmax, np.asarray(eye, dtype=np.float64), np.asarray(box["min"], np.float64),
                           np.asarray(box["size"], np.float64), gx, gy, gz)


@njit(cache=True, parallel=True)
def _light_volume(m: Medium, lx: float, ly: float, lz: float, gx: int, gy: int, gz: int, h: float) -> np.ndarray:
    out = np.empty((gx, gy, gz), dtype=np.float32)
    for ix in prange(gx):
        for iy in range(gy):
            for iz in range(gz):
                px = m.bmin[0] + (ix + 0.5) / gx * m.bsize[0]
                py = m.bmin[1] + (iy + 0.5) / gy * m.bsize[1]
                pz = m.bmin[2] + (iz + 0.5) / gz * m.bsize[2]
                out[ix, iy, iz] = march_transmittance(m, px, py, pz, lx, ly, lz, math.inf, h, True)
    return out


def light_volumes(m: Medium, travel_dirs: np.ndarray, grid: int, step: float) -> np.ndarray:
    """Transmittance towards each directional light (travel direction rows of ``travel_dirs``) from the centres of
    a grid with ``grid`` cells along the longest side: (lights, gx, gy, gz) float32; ``step`` in world units."""
    shape = grid_shape(m.bsize, grid)
    out = np.empty((len(travel_dirs), *shape), dtype=np.float32)
    for i, t in enumerate(travel_dirs):
        out[i] = _light_volume(m, -float(t[0]), -float(t[1]), -float(t[2]), *shape, step)
    return out
