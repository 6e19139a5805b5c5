"""The direct (single-scattering) term of the lighting a basis represents (paper Sec. 6.2, Alg. 1 "Part1"), and the
grid lookups the camera march shares with the light volumes of the NEE fall-back (``runtime/pvrt/radiance.py``).

Sec. 6.2: "For direct illumination, the incident energy for each voxel is just the reduced radiance L_ri (Eq. 2),
so photon tracing is unnecessary": per voxel and basis light, transmittances tau_inf(p, w) along sampled
directions are accumulated at the point itself. The photons' first collisions splatted into the transfer grid
(``runtime/pvrt/precompute.py``) estimate the same quantity averaged over the splatting kernel instead, 1.5 cells
of a grid a few voxels a cell; the direct term falls steeply across the lit skin of the medium, within a mean free
path, and the camera sees mostly that skin, so that average was low (issue 18; measurements in bench/README.md,
PVRT). Here, per quadrature direction w_q, the optical depth
tau_q towards w_q is marched from the centres of a fine grid (the light grid of the NEE light volumes, 64 cells
along the longest side by default) once per transfer (:func:`direct_volumes`, cached on it: the volumes depend on
the medium only, which :meth:`Transfer.check_scene` pins), and a camera sample at x with view direction w_o adds,
per unit albedo,

    L_d(x) = sum_q W_q f_g(w_o, w_q) exp(-tau_q(x)),       W_q = integral L(w) phi_q(w) dw

(Eq. 5 with a quadrature over directions; f_g the HG phase, ``runtime/transport/phase.py``). tau_q is interpolated
trilinearly *before* the exponential: across a thin dense feature the optical depth grows about linearly while the
transmittance falls exponentially, so interpolating the transmittance between a lit empty cell and a dark one
over-estimates the light at a sample between them (as the NEE light volume does), and interpolating the optical
depth errs less (low, where the optical depth has its kink at the lit skin).

Quadrature (:func:`quadrature`): a DSF basis of order <= :data:`QUADRATURE_ORDER` uses its own directions w_k and
solid angles, ``W_k = Omega_k s_k`` (``s_k = L(w_k)``: Eq. 7's interpolation property; the paper's N_s directions
per basis light, with N_s = 1 at the basis direction); any other basis is projected onto the DSF partition of
unity of that order, ``phi_q = wbar_q`` (Eq. 7), which keeps the lighting's power. Either way a constant sky L gives
``W_q = L Omega_q``, summing to 4 pi L.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit, prange

from photon_fields.runtime.pvrt.basis import LightingBasis, make_basis
from photon_fields.runtime.pvrt.radiance import SHADOW_TAU_MAX, light_volumes
from photon_fields.runtime.pvrt.transfer import Transfer
from photon_fields.runtime.transport.cell_grid import Grid, grid_of, stencil, trilinear
from photon_fields.runtime.transport.medium import Medium
from photon_fields.runtime.transport.phase import hg_eval

#: DSF order of the direct term's quadrature directions: 42 optical-depth volumes (44 MB on a 64^3 light grid, a
#: shadow ray per direction from every cell a camera sample in the medium can read, once per transfer). Higher DSF
#: orders and SH lightings are projected onto these directions (module docstring).
QUADRATURE_ORDER = 1

#: The basis lighting's direct term as the camera march takes it: the optical-depth volumes (gx, gy, gz, Q) float32,
#: the active quadrature directions (A,) int64, their travel directions (A, 3) and weights W (A, 3).
BasisDirect = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
#: No basis lighting's direct term (a lighting of directional lights by NEE only, or the marches that count samples).
NO_BASIS_DIRECT: BasisDirect = (np.zeros((2, 2, 2, 1), dtype=np.float32), np.zeros(0, dtype=np.int64),
                                np.zeros((0, 3)), np.zeros((0, 3)))


@njit(cache=True, inline="always")
def phases(g: float, travel: np.ndarray, dx: float, dy: float, dz: float, ph: np.ndarray) -> None:
    """ph[l] = the HG phase between travel direction l and the camera ray's way back (one per ray)."""
    for li in range(travel.shape[0]):
        ph[li] = hg_eval(g, -(dx * travel[li, 0] + dy * travel[li, 1] + dz * travel[li, 2]))


@njit(cache=True, inline="always")
def nee(lights: np.ndarray, grid: Grid, ph: np.ndarray, rgb: np.ndarray, x: float, y: float,
        z: float) -> tuple[float, float, float]:
    """The directional lights' direct term at x per unit albedo: each light's transmittance (its light volume,
    trilinear) times its phase value along the camera ray (``ph``) and its irradiance (``rgb``)."""
    n0 = n1 = n2 = 0.0
    if lights.shape[0] > 0:
        i, j, k, fx, fy, fz = stencil(grid, x, y, z)
        for li in range(lights.shape[0]):
            tr = trilinear(lights[li], i, j, k, fx, fy, fz) * ph[li]
            n0 += tr * rgb[li, 0]
            n1 += tr * rgb[li, 1]
            n2 += tr * rgb[li, 2]
    return n0, n1, n2


@njit(cache=True, inline="always")
def _extrapolating(p: float, lo: float, scale: float, n: int) -> tuple[int, float]:
    """:func:`grid_coord` (the same two cells) but linear beyond the outermost cell centres, in the half cell along
    the box's faces, instead of constant there: a fraction in [-0.5, 1.5]. The optical depth towards a light whose
    rays enter through a face falls to 0 at the face, about linearly; held at the value half a cell deep, it made the
    medium along the faces, which the camera sees first, too dark."""
    u = min(max((p - lo) * scale - 0.5, -0.5), n - 0.5)
    i = min(max(int(math.floor(u)), 0), n - 2)
    return i, u - i


@njit(cache=True, inline="always")
def _depths(depth: np.ndarray, grid: Grid, x: float, y: float, z: float, tau: np.ndarray) -> None:
    """tau[q] = the optical depths ``depth[..., q]`` at x, trilinear (every q: the 8 corners' rows are contiguous, a
    loop the compiler vectorizes; gathering only the active directions took twice as long), extrapolated linearly in
    the half cell along the box's faces (:func:`_extrapolating`)."""
    i, fx = _extrapolating(x, grid[0], grid[3], grid[6])
    j, fy = _extrapolating(y, grid[1], grid[4], grid[7])
    k, fz = _extrapolating(z, grid[2], grid[5], grid[8])
    ux, uy, uz = 1.0 - fx, 1.0 - fy, 1.0 - fz
    w0, w1, w2, w3 = ux * uy * uz, fx * uy * uz, ux * fy * uz, fx * fy * uz
    w4, w5, w6, w7 = ux * uy * fz, fx * uy * fz, ux * fy * fz, fx * fy * fz
    d0, d1, d2, d3 = depth[i, j, k], depth[i + 1, j, k], depth[i, j + 1, k], depth[i + 1, j + 1, k]
    d4, d5, d6, d7 = depth[i, j, k + 1], depth[i + 1, j, k + 1], depth[i, j + 1, k + 1], depth[i + 1, j + 1, k + 1]
    for q in range(tau.shape[0]):
        tau[q] = max(w0 * d0[q] + w1 * d1[q] + w2 * d2[q] + w3 * d3[q] + w4 * d4[q] + w5 * d5[q] + w6 * d6[q]
                     + w7 * d7[q], 0.0)


@njit(cache=True, inline="always")
def basis_direct(depth: np.ndarray, grid: Grid, active: np.ndarray, ph: np.ndarray, rgb: np.ndarray, tau: np.ndarray,
                 x: float, y: float, z: float) -> tuple[float, float, float]:
    """The basis lighting's direct term at x per unit albedo (module docstring): the optical depths at x into
    ``tau`` (Q,) (:func:`_depths`), then over the active quadrature directions ``active[a]`` (a nonzero W),
    exp(-tau) times the phase ``ph[a]`` and the weight ``rgb[a]`` (W_q)."""
    n0 = n1 = n2 = 0.0
    if active.shape[0] > 0:
        _depths(depth, grid, x, y, z, tau)
        for a in range(active.shape[0]):
            t = math.exp(-tau[active[a]]) * ph[a]
            n0 += t * rgb[a, 0]
            n1 += t * rgb[a, 1]
            n2 += t * rgb[a, 2]
    return n0, n1, n2


@njit(cache=True, inline="always")
def kept_direct(tr: np.ndarray, s: int, active: np.ndarray, ph: np.ndarray,
                rgb: np.ndarray) -> tuple[float, float, float]:
    """:func:`basis_direct` of a kept sample ``s`` whose transmittances ``tr[s]`` (:func:`sample_transmittances`)
    are known: the same sum without the lookups and exponentials."""
    n0 = n1 = n2 = 0.0
    for a in range(active.shape[0]):
        t = tr[s, active[a]] * ph[a]
        n0 += t * rgb[a, 0]
        n1 += t * rgb[a, 1]
        n2 += t * rgb[a, 2]
    return n0, n1, n2


@njit(cache=True, parallel=True)
def sample_transmittances(m: Medium, depth: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """exp(-tau_q) at the points ``pos`` (3, n), as :func:`basis_direct` computes them: (n, Q) float32."""
    n, nq = pos.shape[1], depth.shape[3]
    out = np.empty((n, nq), dtype=np.float32)
    grid = grid_of(m, depth.shape[0], depth.shape[1], depth.shape[2])
    for s in prange(n):
        tau = np.empty(nq)
        _depths(depth, grid, pos[0, s], pos[1, s], pos[2, s], tau)
        for q in range(nq):
            out[s, q] = math.exp(-tau[q])
    return out


@lru_cache(maxsize=8)
def quadrature(basis: LightingBasis) -> tuple[np.ndarray, np.ndarray]:
    """The direct term's directions (Q, 3) (the light arrives from them) and the matrix P (Q, m) that maps the
    lighting's coefficients to the weights W = P @ coeffs (module docstring). Computed once per basis (the
    arrays are shared: not to be written to)."""
    if basis.dsf is not None and basis.order <= QUADRATURE_ORDER:
        return basis.dsf.dirs, np.diag(basis.dsf.solid_angle)
    quad = make_basis("dsf", QUADRATURE_ORDER)
    q = basis._quad  # the equal-weight sphere quadrature both bases project skies with
    return quad.dsf.dirs, quad.evaluate(q).T @ basis.evaluate(q) * (4.0 * math.pi / len(q))


def direct_weights(basis: LightingBasis, coeffs: np.ndarray) -> np.ndarray:
    """W (Q, 3): the lighting ``coeffs`` (m, 3) on the quadrature directions (:func:`quadrature`)."""
    return quadrature(basis)[1] @ np.asarray(coeffs, dtype=np.float64).reshape(basis.size, -1)


def direct_volumes(transfer: Transfer, m: Medium, grid: int, step: float, skip_empty: bool = True) -> np.ndarray:
    """Optical depth towards every quadrature direction from the centres of a grid with ``grid`` cells along the
    longest side: (gx, gy, gz, Q) float32, capped at :data:`SHADOW_TAU_MAX` (where a shadow ray stops: transmittance
    1e-4, dark). Marched as the light volumes are (``skip_empty``: only the cells a camera sample in the medium can
    read; the others hold 0); computed once per transfer (checked against the scene before) and kept on it."""
    key = ("direct_volumes", int(grid), float(step), bool(skip_empty))
    cache = transfer.cache
    if key not in cache:
        dirs, _ = quadrature(transfer.basis)
        t = light_volumes(m, -dirs, grid, step, skip_empty)  # travel directions: the light arrives from dirs
        tau = np.where(t > 0.0, -np.log(np.maximum(t, 1e-30)), SHADOW_TAU_MAX)
        cache[key] = np.ascontiguousarray(np.moveaxis(np.minimum(tau, SHADOW_TAU_MAX), 0, -1), dtype=np.float32)
    return cache[key]
