"""Pure-numpy wavefront tracking: the baseline the numba kernels of :mod:`runtime.transport.tracking` must beat.

Product rule: "pure numpy wavefront code is the baseline; hot loops may be compiled with numba if a
benchmark shows it pays". This module is that baseline (``bench/bench_tracking.py`` measures the
difference) and an independent implementation the numba kernels are cross-checked against
(``tests/runtime/transport/test_tracking_numpy.py``). It contains no numba.

Functions
---------
scalar_numpy(m, p)
    The trilinearly interpolated normalized scalar (:func:`photon_fields.runtime.transport.medium.scalar_at`).
extinction_numpy(m, p)
    sigma_t at points ``p`` of shape (3, n): trilinear interpolation of the cell-centred density
    (clamped at the border), then the linearly interpolated transfer-function table; the same
    arithmetic, in the same order, as :func:`photon_fields.runtime.transport.medium.extinction_at`.
next_float_numpy(states)
    SplitMix64 step of :func:`photon_fields.runtime.transport.rng.next_float` on a uint64 array, advancing it in place:
    ``states`` evolve exactly as the numba streams do, so both back ends consume the same kind of
    per-ray streams (``photon_fields.runtime.transport.rng.stream_states``).
delta_track_numpy(m, o, d, tmin, tmax, states)
    Distance to the first real collision in [tmin, tmax) (within the box) per ray, inf on escape.
ratio_track_numpy(m, o, d, tmin, tmax, states)
    Unbiased transmittance estimate over [tmin, tmax] (within the box) per ray.

Parameters shared by the trackers: ``m`` a :class:`runtime.transport.medium.Medium`; ``o``, ``d`` (3, n) float64
origins and unit directions (structure of arrays); ``tmin``, ``tmax`` (n,) or scalars; ``states``
(n,) uint64, advanced in place by exactly the random numbers each ray used.

Differences from the numba kernels, on purpose: a single global majorant (the max of the majorant
grid) instead of the DDA over macrocells, because a per-ray walk does not vectorize; ratio tracking
has no Russian roulette (unbiasedness does not need it; it only saves work on rays whose estimate
is already small); and [tmin, tmax] is intersected with the world box first, so a ray
that starts outside the box or has tmax = inf sees no medium outside it (the lookups clamp to the
border voxels, and the numba kernels, which rely on callers clipping rays to the box, would extend
the border values outward). Rays with an empty interval draw no random numbers. Both estimators are
unbiased, so on clipped rays the results agree with the numba kernels in distribution, not sample by
sample. With a one-macrocell majorant grid the numba delta tracker draws the same numbers in the same
order, which the tests use for an exact check.

Each iteration processes all active rays at once and drops finished ones (compaction), so the cost
is proportional to the total number of tentative collisions, as in the scalar kernels.
"""

from __future__ import annotations

import numpy as np

from photon_fields.runtime.transport.medium import Medium
from photon_fields.runtime.transport.rng import GOLDEN

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S11, _S27, _S30, _S31 = np.uint64(11), np.uint64(27), np.uint64(30), np.uint64(31)
_INV_2_53 = 1.0 / 9007199254740992.0


# --- random numbers -------------------------------------------------------------------------------


def next_float_numpy(states: np.ndarray) -> np.ndarray:
    """Advance every uint64 state once (in place); return uniforms in [0, 1) at 53-bit resolution."""
    if states.dtype != np.uint64:
        raise TypeError(f"states must be uint64, got {states.dtype}")
    # Wrap-around multiplication is the algorithm; numpy would warn about it on 0-d arrays.
    with np.errstate(over="ignore"):
        states += GOLDEN
        z = states.copy()
        z ^= z >> _S30
        z *= _M1
        z ^= z >> _S27
        z *= _M2
        z ^= z >> _S31
    z >>= _S11
    return z.astype(np.float64) * _INV_2_53


# --- medium lookups -------------------------------------------------------------------------------


def _voxel_coord(x: np.ndarray, lo: float, size: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell-centred voxel coordinate on one axis, clamped: (lower index, fraction), as in scalar_at."""
    v = np.clip((x - lo) / size * n - 0.5, 0.0, n - 1.0)
    i = np.minimum(v.astype(np.int64), n - 2)  # v >= 0, so truncation is floor
    return i, v - i


def scalar_numpy(m: Medium, p: np.ndarray) -> np.ndarray:
    """Trilinearly interpolated normalized scalar at points ``p`` (3, n), clamped at the border."""
    nx, ny, nz = m.density.shape
    i, fx = _voxel_coord(p[0], m.bmin[0], m.bsize[0], nx)
    j, fy = _voxel_coord(p[1], m.bmin[1], m.bsize[1], ny)
    k, fz = _voxel_coord(p[2], m.bmin[2], m.bsize[2], nz)
    flat = m.density.reshape(-1)
    base = (i * ny + j) * nz + k
    sx, sy = ny * nz, nz
    # Flat take() per corner: several times faster than 3-D fancy indexing.
    def corner(offset: int) -> np.ndarray:
        return flat.take(base + offset if offset else base)

    gx = 1.0 - fx
    # float32 voxels times float64 weights promote to float64, matching the numba kernel.
    c00 = corner(0) * gx + corner(sx) * fx
    c10 = corner(sy) * gx + corner(sx + sy) * fx
    c01 = corner(1) * gx + corner(sx + 1) * fx
    c11 = corner(sy + 1) * gx + corner(sx + sy + 1) * fx
    c0 = c00 * (1.0 - fy) + c10 * fy
    c1 = c01 * (1.0 - fy) + c11 * fy
    return c0 * (1.0 - fz) + c1 * fz


def extinction_numpy(m: Medium, p: np.ndarray) -> np.ndarray:
    """sigma_t at points ``p`` (3, n): same conventions as :func:`runtime.transport.medium.extinction_at`."""
    if m.categorical:  # the baseline mirrors the scalar kernels only (label media: bench/tests use numba's)
        raise ValueError("the numpy tracking baseline does not handle categorical (label) media")
    p = np.asarray(p, dtype=np.float64)
    lut = m.ext_lut
    n = lut.shape[0]
    f = np.clip(scalar_numpy(m, p), 0.0, 1.0) * (n - 1)
    i = np.minimum(f.astype(np.int64), n - 2)
    f -= i
    return lut[i] * (1.0 - f) + lut[i + 1] * f


# --- trackers -------------------------------------------------------------------------------------


def _prepare(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray | float, tmax: np.ndarray | float,
             states: np.ndarray) -> tuple[np.ndarray, ...]:
    """Validate the inputs and restrict each ray's interval to the box. Returns the active set
    (idx, o, d, t, tend) of rays with a non-empty interval [t, tend), densely packed."""
    o = np.asarray(o, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    n = o.shape[1]
    if o.shape != (3, n) or d.shape != (3, n):
        raise ValueError(f"o and d must have shape (3, n), got {o.shape} and {d.shape}")
    if states.shape != (n,) or states.dtype != np.uint64:
        raise ValueError(f"states must be uint64 of shape ({n},), got {states.dtype} {states.shape}")
    t = np.broadcast_to(np.asarray(tmin, dtype=np.float64), (n,)).copy()
    tend = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (n,)).copy()
    # The medium is the box: the lookups clamp to the border voxels, so without this clip a ray running
    # past the box would see the border values extended to infinity (and, through empty borders with
    # tmax = inf, never finish).
    lo, hi = m.bmin[:, None], (m.bmin + m.bsize)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        ta = (lo - o) / d
        tb = (hi - o) / d
    parallel = d == 0.0  # no slab crossing: inside the slab for all t, or never
    inside = (o >= lo) & (o <= hi)
    near = np.where(parallel, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
    far = np.where(parallel, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
    np.maximum(t, near.max(axis=0), out=t)
    np.minimum(tend, far.min(axis=0), out=tend)
    idx = np.flatnonzero(t < tend)
    return (idx, *_keep_idx(idx, o, d, t, tend))


def _keep_idx(keep: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(a.take(keep, axis=-1) for a in arrays)


def _keep(mask: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """Compact the active set: each array (ray index on the last axis) restricted to ``mask``."""
    # take() with explicit indices: boolean indexing along the last axis of a (3, n) array is ~5x slower.
    return _keep_idx(np.flatnonzero(mask), *arrays)


def delta_track_numpy(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray | float,
                      tmax: np.ndarray | float, states: np.ndarray) -> np.ndarray:
    """Delta tracking with the global majorant: distance to the first real collision, inf on escape.
    Advances ``states`` in place."""
    # Active set, densely packed; `idx` maps back to the caller's ray index.
    idx, o_a, d_a, t, tmax_a = _prepare(m, o, d, tmin, tmax, states)
    out = np.full(states.shape[0], np.inf)
    maj = float(m.majorant.max()) if m.majorant.size else 0.0
    if maj <= 0.0:
        return out  # nothing to collide with; like the numba kernel, no random number is drawn
    s = states[idx]
    while idx.size:
        # Same expression as the numba kernel (divide, not multiply by 1/maj), so that with a one-cell
        # majorant grid both produce identical distances.
        t -= np.log(1.0 - next_float_numpy(s)) / maj
        inside = t < tmax_a
        if not inside.all():
            gone = ~inside
            states[idx[gone]] = s[gone]  # escaped: out stays inf
            idx, t, o_a, d_a, tmax_a, s = _keep(inside, idx, t, o_a, d_a, tmax_a, s)
            if not idx.size:
                break
        sigma = extinction_numpy(m, o_a + t * d_a)
        # The acceptance number is drawn only by rays still inside, as in the scalar kernel.
        hit = next_float_numpy(s) * maj < sigma
        if hit.any():
            out[idx[hit]] = t[hit]
            states[idx[hit]] = s[hit]
            idx, t, o_a, d_a, tmax_a, s = _keep(~hit, idx, t, o_a, d_a, tmax_a, s)
    return out


def ratio_track_numpy(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray | float,
                      tmax: np.ndarray | float, states: np.ndarray) -> np.ndarray:
    """Ratio tracking with the global majorant (no Russian roulette): unbiased transmittance estimate
    over [tmin, tmax]. Advances ``states`` in place."""
    idx, o_a, d_a, t, tmax_a = _prepare(m, o, d, tmin, tmax, states)
    out = np.ones(states.shape[0])
    maj = float(m.majorant.max()) if m.majorant.size else 0.0
    if maj <= 0.0:
        return out
    s = states[idx]
    tr = np.ones(idx.size)
    while idx.size:
        t -= np.log(1.0 - next_float_numpy(s)) / maj
        inside = t < tmax_a
        if not inside.all():
            gone = ~inside
            out[idx[gone]] = tr[gone]
            states[idx[gone]] = s[gone]
            idx, t, o_a, d_a, tmax_a, s, tr = _keep(inside, idx, t, o_a, d_a, tmax_a, s, tr)
            if not idx.size:
                break
        # sigma <= maj everywhere (the global max bounds every macrocell), so the factor is in [0, 1].
        tr *= 1.0 - extinction_numpy(m, o_a + t * d_a) / maj
    return out
