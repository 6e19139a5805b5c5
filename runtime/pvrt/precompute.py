"""Precomputation of the radiance transfer (paper Alg. 1 lines 2-19, Sec. 6.2-6.3): basis-light photon tracing
and photon splatting into per-voxel transfer matrices.

For every basis light ``B_k`` (a distant radiance, ``runtime/pvrt/basis.py``) photon paths are traced through the
medium and each real collision splats the photon's energy into the transfer cells around it. The result holds,
per cell ``v`` of the transfer grid, the SH coefficients (Sec. 6.1: "we use SH to approximate L_re") of the radiance
*arriving* there under ``B_k`` = 1, as a function of its travel direction:

    T[v, k, part, j] = sum_photons K_v(x_p) Phi_p Y_j(d_p) / D_v,      D_v = integral K_v(x) sigma_t(x) dx

- ``part`` 0 (``direct``): first collisions: the reduced incident radiance L_ri of Eq. 2 at the voxel (Sec. 6.2's
  direct illumination; scalar, the light has not met an albedo yet); parts 1-3 (``ms_r/g/b``): later collisions,
  the multiple-scattering term of Eq. 6, RGB because earlier vertices' albedo colours it. The renderer no longer
  reads part 0: averaged over a kernel of coarse cells it smooths away the lit skin the camera sees, and the direct
  term comes from optical-depth volumes at the camera's samples instead (``runtime/pvrt/direct.py``, Sec. 6.2's own
  method); it stays in the file, whose layout ``models_spec/pvrt_transfer.py`` fixes.
- Collisions are sampled by delta tracking with density ``sigma_t L``, so the numerator estimates the kernel-weighted
  integral of ``sigma_t L`` and the quotient is the sigma_t-weighted mean of the radiance over the kernel (a ratio
  estimate; ``D_v`` is summed over the volume's voxels, deterministically). Dividing each photon by sigma_t at its
  collision instead (plain volume photon mapping) would under-estimate every cell that is partly empty, which on a
  coarse grid is most of them; and the camera weights the radiance by sigma_t anyway. D_v is integrated with at
  least ``MASS_POINTS`` points per voxel along each axis (a steep transfer function aliases with fewer, and D_v
  divides every value). The phase function and the
  albedo of the camera's own vertex are left to render time: the HG phase is a per-band factor ``g^l`` on these
  coefficients (``runtime/pvrt/sh.py``), and the albedo comes from the full-resolution transfer function.
- ``K_v`` is the paper's polynomial splatting kernel (Eq. 14), ``(h^2 - |d|^2)^3`` with radius ``h = c`` cells
  (``KERNEL_C``), normalized over the cells it reaches so that every photon's energy is kept whole (Eq. 14's
  analytic constant assumes a continuum of cells; at 1-2 cells it would not sum to 1).

Photon sampling (Sec. 6.3.1). The paper starts photons on the volume's boundary voxels with uniform directions and
energy ``B_k(w) dl^2 (w . n)``; we start them, as our photon tracer (``runtime/transport/emitters.py``) does for a
distant light, on a disk of the bounding sphere's radius R perpendicular to their direction, which is the same
estimator with no photon wasted on directions that leave at once. The direction is drawn where ``B_k`` is nonzero:
for a DSF basis light, uniformly in the cone of its support (radius h around ``w_k``; the paper's "restrict w
inside a small differential solid angle for each DSF basis light"), weight ``wbar_k(w) Omega_cone``; for an SH basis
light, uniformly on the sphere, weight ``Y_k(w) 4 pi`` (signed: negative lobes carry negative energy). A photon's
energy is ``weight * pi R^2 / paths``.

Transport (Sec. 6.3.2): delta tracking over the majorant grid (``runtime/transport/tracking.py``; the paper steps a
fixed ``dl``), Russian roulette on the albedo and HG importance sampling with the scene's g, up to ``MAX_BOUNCES``
collisions: the photon path of ``runtime/photons/photon_path.py``, the one ``train/photons/tracing.py`` (Alg. 1 of
the Photon Field Networks paper) follows too.

Determinism and memory: basis light k is one task (a serial kernel called from ``prange``), its path i uses random
stream ``k * 2^32 + i`` and writes only ``T[:, k]``: the transfer is the same bytes for any thread count. Memory is
the float32 transfer itself, ``R * m * 4 * (l_max + 1)^2`` floats for the R cells photons can reach
(:func:`reachable_cells`: within the kernel of an occupied macrocell, 30-50 % of the grid on the embedded scenes);
the default grid and DSF order keep it within ``TRANSFER_BUDGET_BYTES`` (:func:`auto_grid`, :func:`auto_dsf_order`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.photon_path import trace_path
from photon_fields.runtime.progress import progress_bar
from photon_fields.runtime.pvrt.basis import LightingBasis
from photon_fields.runtime.pvrt.constants import (
    DEFAULT_DSF_ORDER,
    DEFAULT_GRID,
    DEFAULT_PATHS_PER_BASIS,
    EXITANCE_ORDERS,
    EXITANCE_TOLERANCE,
    GRID_RANGE,
    KERNEL_C,
    KERNEL_DENSE_TAU,
    MASS_POINTS,
    MAX_BOUNCES,
    MIN_AUTO_GRID,
    PARTS,
    TRANSFER_BUDGET_BYTES,
)
from photon_fields.runtime.pvrt.dsf import dsf_weights
from photon_fields.runtime.pvrt.sh import auto_exitance_order, sh_count, sh_eval
from photon_fields.runtime.scene.lights import DIRECTIONAL
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.emitters import emit_photon, sample_uniform_sphere
from photon_fields.runtime.transport.environment_map import NO_ENV_MAP, EnvMap
from photon_fields.runtime.transport.medium import Medium, borrowed_medium, extinction_at
from photon_fields.runtime.transport.phase import orthonormal_basis
from photon_fields.runtime.transport.rng import next_float, stream_state

_STREAM_STRIDE = np.uint64(1 << 32)  # basis light k owns random streams k * 2^32 + path


def auto_grid(cells_for: Callable[[int], int], bytes_per_cell: int) -> int:
    """The transfer grid by default: the most cells along the longest side, up to ``DEFAULT_GRID``, whose
    uncompressed transfer, ``cells_for(grid)`` cells of ``bytes_per_cell`` each (the cells photons can reach:
    :func:`reachable_cells`), fits ``TRANSFER_BUDGET_BYTES`` (at least the least grid ``GRID_RANGE`` allows)."""
    for grid in range(DEFAULT_GRID, GRID_RANGE[0], -1):
        if cells_for(grid) * bytes_per_cell <= TRANSFER_BUDGET_BYTES:
            return grid
    return GRID_RANGE[0]


def auto_dsf_order(cells_for: Callable[[int], int], out_lmax: int, grid: int | None = None) -> int:
    """The DSF order by default: ``DEFAULT_DSF_ORDER`` where its transfer fits ``TRANSFER_BUDGET_BYTES`` with at
    least ``MIN_AUTO_GRID`` cells along the longest side (or at ``grid`` when one is given), else the next coarser
    order that does (at least 0). ``cells_for(grid)``: the cells photons can reach (:func:`reachable_cells`)."""
    for order in range(DEFAULT_DSF_ORDER, 0, -1):
        per_cell = dsf_size(order) * len(PARTS) * sh_count(out_lmax) * 4
        if grid is None and auto_grid(cells_for, per_cell) >= MIN_AUTO_GRID:
            return order
        if grid is not None and cells_for(grid) * per_cell <= TRANSFER_BUDGET_BYTES:
            return order
    return 0


def reachable_counter(m: Medium) -> Callable[[int], int]:
    """``cells_for(grid)``: how many cells of the transfer grid with ``grid`` cells along the box's longest side
    photons can splat into (:func:`reachable_cells`)."""
    counts: dict[int, int] = {}  # the order's and the grid's searches ask for the same grids

    def cells_for(grid: int) -> int:
        if grid not in counts:
            counts[grid] = int(np.count_nonzero(reachable_cells(m, *grid_shape(m.bsize, grid), KERNEL_C)))
        return counts[grid]

    return cells_for


@njit(cache=True)
def reachable_cells(m: Medium, gx: int, gy: int, gz: int, hc: float) -> np.ndarray:
    """Which cells (V,) bool, in C order, a photon can splat into: those within the kernel's radius ``hc`` (cells)
    of a macrocell whose majorant is > 0. A real collision needs sigma_t > 0, which only such macrocells hold, and
    :func:`_splat` reaches the cells less than ``hc`` from it; the rest of the grid, on sparse volumes most of it,
    is never written, and the transfer keeps no row for it."""
    out = np.zeros(gx * gy * gz, dtype=np.bool_)
    mx, my, mz = m.majorant.shape
    lo = np.empty(3, dtype=np.int64)
    hi = np.empty(3, dtype=np.int64)
    cells = (gx, gy, gz)
    macro = (mx, my, mz)
    for a in range(mx):
        for b in range(my):
            for c in range(mz):
                if m.majorant[a, b, c] <= 0.0:
                    continue
                idx = (a, b, c)
                for ax in range(3):  # cell coordinates (centres at integers) of the macrocell's faces, widened
                    u0 = idx[ax] / macro[ax] * cells[ax] - 0.5
                    u1 = (idx[ax] + 1) / macro[ax] * cells[ax] - 0.5
                    lo[ax] = max(0, int(math.floor(u0 - hc)))
                    hi[ax] = min(cells[ax] - 1, int(math.ceil(u1 + hc)))
                for i in range(lo[0], hi[0] + 1):
                    for j in range(lo[1], hi[1] + 1):
                        for k in range(lo[2], hi[2] + 1):
                            out[(i * gy + j) * gz + k] = True
    return out


def dsf_size(order: int) -> int:
    """Directions of the DSF of ``order`` (icosahedral subdivision: 10 * 4^order + 2)."""
    return 10 * 4**order + 2


def grid_shape(bsize: np.ndarray, grid: int) -> tuple[int, int, int]:
    """Transfer-grid cells per axis: ``grid`` along the box's longest side, cells as close to cubes as the box
    allows (at least 2 per axis)."""
    longest = float(np.max(bsize))
    return tuple(max(2, int(round(grid * float(s) / longest))) for s in bsize)  # type: ignore[return-value]


@njit(cache=True, inline="always")
def splat_radius(hc: float, sigma_cell: float, tau: float) -> float:
    """The splatting radius (cells) at a point where sigma_t times a cell's edge is ``sigma_cell``: ``hc``, shrunk
    as hc sqrt(tau / sigma_cell) down to 1 cell where the medium is denser than ``tau`` optical depths a cell
    (``KERNEL_DENSE_TAU``; tau <= 0: always ``hc``). Dense media have both the steepest radiance (it falls over a
    mean free path from a lit skin) and the most photons; thin ones need the wider kernel against photon noise."""
    if tau <= 0.0:
        return hc
    return min(hc, max(1.0, hc * math.sqrt(tau / max(sigma_cell, 1e-12))))


@njit(cache=True)
def _splat(acc: np.ndarray, row: np.ndarray, k: int, part0: int, nparts: int, vals: np.ndarray, y: np.ndarray,
           n_out: int, gx: int, gy: int, gz: int, ux: float, uy: float, uz: float, hc: float, cells: np.ndarray,
           weights: np.ndarray) -> None:
    """Eq. 14's kernel around the photon at cell coordinates (ux, uy, uz) (cell centres at integers), normalized
    over the cells it reaches; adds weight * vals[p] * y[j] to acc[row[cell], k, part0 + p, j] (``row``: each
    cell's row of ``acc``, :func:`reachable_cells`; every cell a photon reaches has one)."""
    r = int(math.ceil(hc))
    cx, cy, cz = int(math.floor(ux + 0.5)), int(math.floor(uy + 0.5)), int(math.floor(uz + 0.5))
    h2 = hc * hc
    n = 0
    total = 0.0
    for i in range(max(cx - r, 0), min(cx + r, gx - 1) + 1):
        for j in range(max(cy - r, 0), min(cy + r, gy - 1) + 1):
            for kk in range(max(cz - r, 0), min(cz + r, gz - 1) + 1):
                d2 = (i - ux) ** 2 + (j - uy) ** 2 + (kk - uz) ** 2
                if d2 < h2:
                    w = (h2 - d2) ** 3
                    cells[n] = (i * gy + j) * gz + kk
                    weights[n] = w
                    total += w
                    n += 1
    if total <= 0.0:
        return
    for c in range(n):
        w = weights[c] / total
        v = row[cells[c]]
        for p in range(nparts):
            wp = w * vals[p]
            for jj in range(n_out):
                acc[v, k, part0 + p, jj] += np.float32(wp * y[jj])


@njit(cache=True)
def _trace_basis_light(m: Medium, k: int, is_dsf: bool, dirs: np.ndarray, h: float, neighbours: np.ndarray,
                       light_lmax: int, out_lmax: int, paths: int, seed: int, g: float, max_bounces: int,
                       gx: int, gy: int, gz: int, hc: float, acc: np.ndarray, row: np.ndarray, env: EnvMap,
                       tau: float) -> None:
    """All photon paths of basis light ``k`` (module docstring), splatted into ``acc[:, k]`` (the rows ``row``
    gives the cells), each with the radius its collision's sigma_t gives (:func:`splat_radius`). ``env`` is the
    emitters' environment-map argument, unused by the directional photons traced here (``NO_ENV_MAP``)."""
    m = borrowed_medium(m)  # no reference counting in the loops below (runtime/borrowed.py)
    cx, cy, cz = m.bmin[0] + 0.5 * m.bsize[0], m.bmin[1] + 0.5 * m.bsize[1], m.bmin[2] + 0.5 * m.bsize[2]
    radius = 0.5 * math.sqrt(m.bsize[0] ** 2 + m.bsize[1] ** 2 + m.bsize[2] ** 2)
    n_out = (out_lmax + 1) ** 2
    y = np.empty(n_out)
    ylight = np.empty((light_lmax + 1) ** 2)
    idx = np.empty(neighbours.shape[1], dtype=np.int64)
    wts = np.empty(neighbours.shape[1])
    r = int(math.ceil(hc))
    cells = np.empty((2 * r + 1) ** 3, dtype=np.int64)
    kw = np.empty((2 * r + 1) ** 3)
    vals = np.empty(3)
    dvec = np.empty(3)
    hit_pos, hit_dir, hit_pow = np.empty((max_bounces, 3)), np.empty((max_bounces, 3)), np.empty((max_bounces, 3))
    hit_coll, hit_scalar = np.empty(max_bounces, dtype=np.int64), np.empty(max_bounces)
    cos_h = math.cos(h)
    if is_dsf:
        ax, ay, az = dirs[k, 0], dirs[k, 1], dirs[k, 2]
        tx, ty, tz, bx, by, bz = orthonormal_basis(ax, ay, az)
    scale = math.pi * radius * radius / paths
    for path in range(paths):
        st = stream_state(np.uint64(seed), np.uint64(k) * _STREAM_STRIDE + np.uint64(path))
        st, u1 = next_float(st)
        st, u2 = next_float(st)
        if is_dsf:  # uniform in the cone of B_k's support
            c = 1.0 - u1 * (1.0 - cos_h)
            s = math.sqrt(max(0.0, 1.0 - c * c))
            cp, sp = s * math.cos(2 * math.pi * u2), s * math.sin(2 * math.pi * u2)
            wx, wy, wz = cp * tx + sp * bx + c * ax, cp * ty + sp * by + c * ay, cp * tz + sp * bz + c * az
            nb = dsf_weights(dirs, h, wx, wy, wz, neighbours[k], idx, wts)
            weight = 0.0
            for i in range(nb):
                if idx[i] == k:
                    weight = wts[i]
            weight *= 2.0 * math.pi * (1.0 - cos_h)
        else:  # uniform on the sphere
            wx, wy, wz = sample_uniform_sphere(u1, u2)
            sh_eval(light_lmax, wx, wy, wz, ylight)
            weight = ylight[k] * 4.0 * math.pi
        if weight == 0.0:
            continue
        power = weight * scale
        dvec[0], dvec[1], dvec[2] = -wx, -wy, -wz
        st, u3 = next_float(st)
        st, u4 = next_float(st)
        ox, oy, oz, dx, dy, dz, _, _, _ = emit_photon(DIRECTIONAL, dvec, env, -1.0, cx, cy, cz, radius, u3, u4, 0.0,
                                                      0.0)
        n, _, _ = trace_path(m, g, ox, oy, oz, dx, dy, dz, 1.0, 1.0, 1.0, st, max_bounces, 0.0, hit_pos, hit_dir,
                             hit_pow, hit_coll, hit_scalar)  # no floor: the records are the collisions
        for bounce in range(n):
            px, py, pz = hit_pos[bounce, 0], hit_pos[bounce, 1], hit_pos[bounce, 2]
            sig = extinction_at(m, px, py, pz)
            if sig > 0.0:
                hp = splat_radius(hc, sig * m.bsize[0] / gx, tau)
                sh_eval(out_lmax, hit_dir[bounce, 0], hit_dir[bounce, 1], hit_dir[bounce, 2], y)
                ux = (px - m.bmin[0]) / m.bsize[0] * gx - 0.5
                uy = (py - m.bmin[1]) / m.bsize[1] * gy - 0.5
                uz = (pz - m.bmin[2]) / m.bsize[2] * gz - 0.5
                if bounce == 0:
                    vals[0] = power
                    _splat(acc, row, k, 0, 1, vals, y, n_out, gx, gy, gz, ux, uy, uz, hp, cells, kw)
                else:
                    for ch in range(3):
                        vals[ch] = power * hit_pow[bounce, ch]
                    _splat(acc, row, k, 1, 3, vals, y, n_out, gx, gy, gz, ux, uy, uz, hp, cells, kw)


@njit(cache=True, parallel=True)
def _trace_group(m: Medium, ks: np.ndarray, is_dsf: bool, dirs: np.ndarray, h: float, neighbours: np.ndarray,
                 light_lmax: int, out_lmax: int, paths: int, seed: int, g: float, max_bounces: int, gx: int,
                 gy: int, gz: int, hc: float, acc: np.ndarray, row: np.ndarray, env: EnvMap, tau: float) -> None:
    for i in prange(ks.shape[0]):
        _trace_basis_light(m, ks[i], is_dsf, dirs, h, neighbours, light_lmax, out_lmax, paths, seed, g,
                           max_bounces, gx, gy, gz, hc, acc, row, env, tau)


@njit(cache=True, inline="always")
def _empty_block(m: Medium, x0: float, y0: float, z0: float, x1: float, y1: float, z1: float) -> bool:
    """True when every macrocell that the box [x0, x1] x [y0, y1] x [z0, z1] touches has majorant 0 (sigma_t is
    exactly 0 in it: ``runtime/transport/medium.py``)."""
    cx, cy, cz = m.majorant.shape
    i0 = min(max(int((x0 - m.bmin[0]) / m.bsize[0] * cx), 0), cx - 1)
    i1 = min(max(int((x1 - m.bmin[0]) / m.bsize[0] * cx), 0), cx - 1)
    j0 = min(max(int((y0 - m.bmin[1]) / m.bsize[1] * cy), 0), cy - 1)
    j1 = min(max(int((y1 - m.bmin[1]) / m.bsize[1] * cy), 0), cy - 1)
    k0 = min(max(int((z0 - m.bmin[2]) / m.bsize[2] * cz), 0), cz - 1)
    k1 = min(max(int((z1 - m.bmin[2]) / m.bsize[2] * cz), 0), cz - 1)
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for k in range(k0, k1 + 1):
                if m.majorant[i, j, k] > 0.0:
                    return False
    return True


@njit(cache=True, parallel=True)
def _extinction_mass(m: Medium, gx: int, gy: int, gz: int, hc: float, sub: int, q: int, tau: float) -> np.ndarray:
    """D_v = integral of K_v(x) sigma_t(x) dx (the denominator of the ratio estimate). The volume's voxels are cut
    into ``sub``^3 blocks (fine enough that the kernel, a few cells wide, is resolved); sigma_t is integrated over
    each block by the midpoint rule on ``q``^3 points and splatted once, at the block's sigma_t-weighted centroid
    with the radius its mean sigma_t gives (:func:`splat_radius`, as each photon's at its collision).
    The points must be dense: sigma_t is the transfer function of the interpolated scalar, which a steep ramp
    concentrates near the voxel centres, and a few points per voxel alias with them (:data:`MASS_POINTS`).
    Blocks in empty macrocells are skipped (sigma_t is 0 there). Each x-slab of blocks splats into its own row,
    and the rows are summed in a fixed order."""
    nx, ny, nz = m.density.shape
    sx, sy, sz = nx * sub, ny * sub, nz * sub
    bx, by, bz = m.bsize[0] / sx, m.bsize[1] / sy, m.bsize[2] / sz
    dv = bx * by * bz / (q * q * q)
    rows = np.zeros((sx, gx * gy * gz))
    every = np.arange(gx * gy * gz)  # every cell its own row (D_v is kept for the whole grid)
    for i in prange(sx):
        r = int(math.ceil(hc))
        cells = np.empty((2 * r + 1) ** 3, dtype=np.int64)
        kw = np.empty((2 * r + 1) ** 3)
        vals = np.empty(1)
        one = np.ones(1)
        acc = np.zeros((gx * gy * gz, 1, 1, 1), dtype=np.float32)
        x0 = m.bmin[0] + i * bx
        for j in range(sy):
            y0 = m.bmin[1] + j * by
            for k in range(sz):
                z0 = m.bmin[2] + k * bz
                if _empty_block(m, x0, y0, z0, x0 + bx, y0 + by, z0 + bz):
                    continue
                s = sxw = syw = szw = 0.0
                for a in range(q):
                    x = x0 + (a + 0.5) / q * bx
                    for b in range(q):
                        y = y0 + (b + 0.5) / q * by
                        for c in range(q):
                            z = z0 + (c + 0.5) / q * bz
                            e = extinction_at(m, x, y, z)
                            s += e
                            sxw += e * x
                            syw += e * y
                            szw += e * z
                if s > 0.0:
                    vals[0] = s * dv
                    _splat(acc, every, 0, 0, 1, vals, one, 1, gx, gy, gz, (sxw / s - m.bmin[0]) / m.bsize[0] * gx - 0.5,
                           (syw / s - m.bmin[1]) / m.bsize[1] * gy - 0.5, (szw / s - m.bmin[2]) / m.bsize[2] * gz - 0.5,
                           splat_radius(hc, s / (q * q * q) * m.bsize[0] / gx, tau), cells, kw)
        rows[i] = acc[:, 0, 0, 0]
    return rows.sum(axis=0)


@dataclass
class RawTransfer:
    """The uncompressed transfer on a ``grid`` of cells: the numerators ``matrices[v, k, part, j]`` and the
    denominators ``mass[v]`` = D_v of the module docstring (T = matrices / mass). The numerators, the photon energy,
    are what CPCA compresses: weighted by the medium they cover, unlike the quotients, whose noisy values in cells
    that are barely occupied would take the least-squares fit over."""

    matrices: np.ndarray  # float32 (R, m, len(PARTS), (out_lmax + 1)^2): the R cells photons can reach
    mass: np.ndarray  # float32 (V,)
    grid: tuple[int, int, int]
    out_lmax: int
    seconds: float
    reachable: np.ndarray  # bool (V,): the cells ``matrices`` has rows for, in C order (reachable_cells)


def check_settings(grid: int, out_lmax: int, paths: int) -> None:
    """One-line errors for settings out of range (before any work)."""
    lo, hi = GRID_RANGE
    if isinstance(grid, bool) or not isinstance(grid, (int, np.integer)) or not lo <= grid <= hi:
        raise InputError("grid", f"transfer cells along the longest side must be an integer in [{lo}, {hi}], "
                         f"got {grid!r}")
    lo, hi = EXITANCE_ORDERS
    if isinstance(out_lmax, bool) or not isinstance(out_lmax, (int, np.integer)) or not lo <= out_lmax <= hi:
        raise InputError("exitance order", f"the radiant-exitance SH band limit must be an integer in [{lo}, {hi}], "
                         f"got {out_lmax!r}")
    if isinstance(paths, bool) or not isinstance(paths, (int, np.integer)) or not 1 <= paths < (1 << 32):
        raise InputError("paths", f"photon paths per basis light must be an integer in [1, 2^32), got {paths!r}")


def precompute_raw(scene: Scene, basis: LightingBasis, *, grid: int | None = None,
                   out_lmax: int | None = None, paths: int = DEFAULT_PATHS_PER_BASIS, seed: int = 0,
                   progress: bool = True, on_progress: Callable[[int, int], None] | None = None) -> RawTransfer:
    """Trace every basis light and splat (module docstring). ``out_lmax`` None: the least band limit the scene's
    g needs (:func:`photon_fields.runtime.pvrt.sh.auto_exitance_order`); ``grid`` None: :func:`auto_grid`.
    ``on_progress(done, total)`` after every group of basis lights."""
    if out_lmax is None:
        out_lmax = auto_exitance_order(scene.g, EXITANCE_TOLERANCE)
    check_settings(DEFAULT_GRID if grid is None else grid, out_lmax, paths)
    m = scene.medium()
    if grid is None:
        grid = auto_grid(reachable_counter(m), basis.size * len(PARTS) * sh_count(out_lmax) * 4)
    from photon_fields.runtime.threads import max_threads

    shape = grid_shape(m.bsize, grid)
    reachable = reachable_cells(m, shape[0], shape[1], shape[2], KERNEL_C)
    row = np.full(len(reachable), -1, dtype=np.int64)
    row[reachable] = np.arange(int(np.count_nonzero(reachable)))
    acc = np.zeros((int(np.count_nonzero(reachable)), basis.size, len(PARTS), sh_count(out_lmax)), dtype=np.float32)
    if basis.dsf is not None:
        dirs, h, neighbours, light_lmax = basis.dsf.dirs, basis.dsf.h, basis.dsf.neighbours, 0
    else:
        dirs, h, neighbours, light_lmax = np.zeros((1, 3)), 0.0, np.full((1, 1), -1, np.int64), basis.order
    group = 2 * max_threads()
    t0 = time.perf_counter()
    with progress_bar(total=basis.size, desc="pvrt basis lights", unit="light", enabled=progress) as bar:
        for start in range(0, basis.size, group):
            ks = np.arange(start, min(start + group, basis.size), dtype=np.int64)
            _trace_group(m, ks, basis.dsf is not None, dirs, h, neighbours, light_lmax, out_lmax, int(paths),
                         int(seed), float(scene.g), MAX_BOUNCES, shape[0], shape[1], shape[2], KERNEL_C, acc, row,
                         NO_ENV_MAP, KERNEL_DENSE_TAU)
            bar.update(len(ks))
            if on_progress is not None:
                on_progress(int(ks[-1]) + 1, basis.size)
    # Blocks at most a third of a cell wide; at least MASS_POINTS quadrature points per voxel along each axis, an
    # even number of them below 2 MASS_POINTS (an odd number puts one on every voxel centre: MASS_POINTS says why).
    sub = max(1, int(math.ceil(3.0 * max(g / n for g, n in zip(shape, m.density.shape, strict=True)))))
    q = -(-MASS_POINTS // sub)
    q += (sub * q) % 2 if sub < MASS_POINTS else 0
    mass = _extinction_mass(m, shape[0], shape[1], shape[2], KERNEL_C, sub, q, KERNEL_DENSE_TAU)
    return RawTransfer(acc, mass.astype(np.float32), shape, out_lmax, time.perf_counter() - t0, reachable)
