"""After a light change: the radiance volume (paper Sec. 7.1-7.2, Eq. 17-21) and the light volumes of the
directional lights' direct term (the NEE fall-back).

Early evaluation (Sec. 7.2). With the lighting's coefficients ``L_in`` (m, 3), every cluster's mean and basis
matrices are first reduced to radiance vectors, ``I_mean^k = T_mean^k L_in`` and ``I_i^k = T_i^k L_in`` (Eq. 17-18;
K (N + 1) small products instead of one per cell). Each cell then evaluates them towards the camera,
``L_V = Y(w_v) . (I_mean^k + sum_i w_i I_i^k) / D_v`` (Eq. 19-21; CPCA holds the photon energy, D_v the
extinction it is divided by, ``runtime/pvrt/precompute.py``; the volume keeps numerator and D_v apart and the
division happens at the camera's sample, :data:`CHANNELS`), where the SH coefficients carry the HG phase's band
factors ``g^l`` and ``w_v`` is the direction from the cell to the eye: one value per channel and cell, never the
full radiance vector. Channels: multiple scattering (RGB) and D_v. The transfer's direct part (first collisions)
is not evaluated: the direct term comes from the optical-depth volumes of ``runtime/pvrt/direct.py`` (Sec. 6.2),
which resolve the lit skin of the medium that the transfer's coarse grid smooths away.

Light volume. A directional light's direct term is NEE: its transmittance ``T(x -> light)`` is marched (the ray
marcher's shadow rays with empty-space skipping) from the centre of every cell of a grid (``DEFAULT_LIGHT_GRID``
along the longest side) once per light change, and camera samples interpolate it. Shadows are as sharp as that grid.
Only the cells that a camera sample with sigma_t > 0 can read are marched (the trilinear stencils of the occupied
macrocells, :func:`_needed_cells`): on sparse volumes most cells lie in empty space, where the camera adds nothing.
All lights' cells are one parallel loop.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.pvrt.lighting import Lighting
from photon_fields.runtime.pvrt.precompute import grid_shape
from photon_fields.runtime.pvrt.sh import hg_band_factors, sh_count, sh_eval
from photon_fields.runtime.pvrt.transfer import Transfer
from photon_fields.runtime.transport.cell_grid import grid_coord
from photon_fields.runtime.transport.marching import march_transmittance
from photon_fields.runtime.transport.medium import Medium, borrowed_medium
from photon_fields.runtime.transport.tracking import TASK_ITEMS, task_stride

#: Radiance-volume channels: multiple-scattering RGB radiance towards the eye times each cell's interpolation
#: weight s_v, and s_v itself (:func:`interpolation_weights`). The camera divides the trilinear interpolations of the
#: two (``runtime/renderers/pvrt.py``): a trilinear interpolation of the cells' radiance, each cell weighted by s_v.
#: Plain quotients (s_v = 1 wherever D_v > 0) weighed a cell that holds a thin wisp as much as a full one, and
#: CPCA's error in such a cell's numerator, divided by its small D_v, became a radiance error that did not average
#: out (on the vortex, 48^3, 32^3 grid: the L_i mean 1.17 with 32 CPCA clusters, 0.19 with 128); s_v = D_v (the
#: ratio estimate carried on to the sample) fixed that but weighed a dense medium's dark inside over its lit skin,
#: which the camera sees (head: L_i 0.81 / 0.78 of the path tracer's at 0 / 180 degrees, grid 40). s_v = D_v /
#: (D_v + D_0), D_0 = ``MASS_KNEE`` x the median D_v, is D_v-weighted where cells hold little medium and equal where
#: they hold much: head 0.87 / 0.93, and the vortex's L_i error 7 % lower (bench/README.md, PVRT, 2026-11-29). A
#: cell's 4 channels fill 16 bytes, which the camera's interpolation sums as one vector of 4 floats.
CHANNELS = 4
#: D_0 / median D_v of :func:`interpolation_weights` (0.03 and 0.1 gave the same errors on the vortex).
MASS_KNEE = 0.1
#: A light volume's shadow ray stops where its optical depth passes this (transmittance 1e-4, the camera march's
#: stopping point, runtime/renderers/pvrt.py) and counts as dark: the light it would still let through is at most
#: 1e-4 of the light's (the same bound the camera march accepts for what lies behind its end). On the head, the skull
#: makes many shadow rays this deep, and not marching their rest saves a third of the light volume's time.
SHADOW_TAU_MAX = -math.log(1e-4)


def cluster_responses(transfer: Transfer, lighting: Lighting) -> np.ndarray:
    """Eq. 17-18: (K, N + 1, 3, n) multiple-scattering radiance vectors (the first 3 of :data:`CHANNELS`) of every
    cluster's mean (index 0) and basis matrices."""
    m = transfer.basis.size
    n = sh_count(transfer.exitance_order)
    mats = np.concatenate([transfer.mean[:, None], transfer.basis_matrices], axis=1)  # (K, N + 1, D)
    mats = mats.reshape(mats.shape[0], mats.shape[1], m, 4, n).astype(np.float64)
    return np.ascontiguousarray(np.einsum("abkcj,kc->abcj", mats[:, :, :, 1:], lighting.coeffs))


@njit(cache=True, parallel=True)
def _evaluate_cells(cluster: np.ndarray, mass: np.ndarray, interp: np.ndarray, weights: np.ndarray,
                    resp: np.ndarray, band: np.ndarray, lmax: int, eye: np.ndarray, bmin: np.ndarray,
                    bsize: np.ndarray, gx: int, gy: int, gz: int) -> np.ndarray:
    out = np.zeros((gx, gy, gz, CHANNELS), dtype=np.float32)
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
                out[ix, iy, iz, resp.shape[2]] = interp[v]
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
                scale = interp[v] / mass[v]  # photon energy -> radiance (/ D_v), times the cell's weight s_v
                for c in range(resp.shape[2]):
                    acc = 0.0
                    for j in range(n):
                        s = resp[k, 0, c, j]
                        for i in range(nb):
                            s += weights[v, i] * resp[k, 1 + i, c, j]
                        acc += y[j] * s
                    out[ix, iy, iz, c] = acc * scale
    return out


def radiance_volume(transfer: Transfer, lighting: Lighting, eye: np.ndarray, g: float) -> np.ndarray:
    """The view-dependent radiance volume (gx, gy, gz, CHANNELS) float32 (module docstring): multiply scattered
    radiance towards ``eye`` per unit albedo (before the camera's own albedo) times each cell's interpolation weight,
    and the weight (:data:`CHANNELS`)."""
    resp = cluster_responses(transfer, lighting)
    gx, gy, gz = transfer.grid
    box = transfer.manifest["box"]
    lmax = transfer.exitance_order
    return _evaluate_cells(transfer.cluster, transfer.mass.astype(np.float64),
                           interpolation_weights(transfer).reshape(-1).astype(np.float64),
                           transfer.weights.astype(np.float64), resp, hg_band_factors(g, lmax),
                           lmax, np.asarray(eye, dtype=np.float64), np.asarray(box["min"], np.float64),
                           np.asarray(box["size"], np.float64), gx, gy, gz)


def interpolation_weights(transfer: Transfer) -> np.ndarray:
    """s_v = D_v / (D_v + D_0) per cell, (gx, gy, gz) float32 (:data:`CHANNELS`; 0 where D_v = 0): the radiance
    volume's last channel, which does not depend on the lighting. Kept on the transfer."""
    if "interpolation_weights" not in transfer.cache:
        mass = np.maximum(transfer.mass.astype(np.float64), 0.0)
        occupied = mass[mass > 0]
        d0 = MASS_KNEE * float(np.median(occupied)) if occupied.size else 1.0
        transfer.cache["interpolation_weights"] = (mass / (mass + d0)).astype(np.float32).reshape(transfer.grid)
    return transfer.cache["interpolation_weights"]


@njit(cache=True)
def _needed_cells(m: Medium, gx: int, gy: int, gz: int) -> np.ndarray:
    """Which cells of a (gx, gy, gz) cell-centred grid a camera sample with sigma_t > 0 can read: every corner of
    the trilinear stencil (:func:`grid_coord`) of any point of a macrocell whose majorant is > 0. A sample with
    sigma_t > 0 lies in such a macrocell, so the cells left out are only ever read by samples that add nothing."""
    cx, cy, cz = m.majorant.shape
    out = np.zeros((gx, gy, gz), dtype=np.bool_)
    lo = np.empty(3, dtype=np.int64)
    hi = np.empty(3, dtype=np.int64)
    for a in range(cx):
        for b in range(cy):
            for c in range(cz):
                if m.majorant[a, b, c] <= 0.0:
                    continue
                for ax, (j, cells, n) in enumerate(((a, cx, gx), (b, cy, gy), (c, cz, gz))):
                    x0 = m.bmin[ax] + j / cells * m.bsize[ax]
                    x1 = m.bmin[ax] + (j + 1) / cells * m.bsize[ax]
                    lo[ax] = grid_coord(x0, m.bmin[ax], n / m.bsize[ax], n)[0]
                    hi[ax] = grid_coord(x1, m.bmin[ax], n / m.bsize[ax], n)[0] + 1  # the stencil's upper corner
                out[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] = True
    return out


@njit(cache=True)
def _light_cells(m: Medium, lights: np.ndarray, cells: np.ndarray, h: float, skip: bool, out: np.ndarray, lo: int,
                 hi: int) -> None:
    """Entries lo..hi-1 of ``cells`` ((light, ix, iy, iz) rows) of :func:`_light_volumes`, serially."""
    m = borrowed_medium(m)  # no reference counting in the loop (runtime/borrowed.py)
    _, gx, gy, gz = out.shape
    for v in range(lo, hi):
        li, ix, iy, iz = cells[v, 0], cells[v, 1], cells[v, 2], cells[v, 3]
        px = m.bmin[0] + (ix + 0.5) / gx * m.bsize[0]
        py = m.bmin[1] + (iy + 0.5) / gy * m.bsize[1]
        pz = m.bmin[2] + (iz + 0.5) / gz * m.bsize[2]
        out[li, ix, iy, iz] = march_transmittance(m, px, py, pz, -lights[li, 0], -lights[li, 1], -lights[li, 2],
                                                  math.inf, h, skip, SHADOW_TAU_MAX)


@njit(cache=True, parallel=True)
def _light_volumes(m: Medium, lights: np.ndarray, cells: np.ndarray, h: float, skip: bool, out: np.ndarray) -> None:
    """All lights' cells in one parallel region (``TASK_ITEMS`` tasks, spread by ``task_stride``)."""
    n = cells.shape[0]
    tasks = (n + TASK_ITEMS - 1) // TASK_ITEMS
    stride = task_stride(tasks)
    for task in prange(tasks):
        b = (task * stride) % tasks
        _light_cells(m, lights, cells, h, skip, out, b * TASK_ITEMS, min(n, (b + 1) * TASK_ITEMS))


def light_volumes(m: Medium, travel_dirs: np.ndarray, grid: int, step: float, skip_empty: bool = True,
                  cells: np.ndarray | None = None) -> np.ndarray:
    """Transmittance towards each directional light (travel direction rows of ``travel_dirs``) from the centres of
    a grid with ``grid`` cells along the longest side: (lights, gx, gy, gz) float32; ``step`` in world units.
    ``skip_empty``: only the cells a camera sample in the medium can read are marched (:func:`_needed_cells`; the
    others hold 1), skipping empty macrocells; False: every cell, every midpoint (the tests' reference). ``cells``
    (a boolean mask of the grid) names the cells to march instead: those that known camera samples read."""
    shape = grid_shape(m.bsize, grid)
    out = np.ones((len(travel_dirs), *shape), dtype=np.float32)
    if len(travel_dirs) == 0:
        return out
    if cells is None:
        cells = _needed_cells(m, *shape) if skip_empty else np.ones(shape, dtype=np.bool_)
    needed = np.argwhere(cells)
    cells_all = np.concatenate([np.column_stack([np.full(len(needed), i), needed]) for i in range(len(travel_dirs))])
    _light_volumes(m, np.ascontiguousarray(travel_dirs, dtype=np.float64), np.ascontiguousarray(cells_all), step,
                   skip_empty, out)
    return out
