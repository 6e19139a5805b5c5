"""Environment maps: radiance from an equirectangular (latitude-longitude) image, importance-sampled.

Convention (Mitsuba 3's ``envmap`` plugin, y up)
------------------------------------------------
An image of H rows and W = 2 H columns, row 0 at the top, covers the sphere of directions ``w`` (the direction a
ray travels when it escapes: the light arrives from ``w``, travelling along ``-w``). In the map's own frame::

    u = phi / (2 pi) in [0, 1)   (column: j = floor(u W)),   phi = atan2(x, -z) wrapped to [0, 2 pi)
    v = theta / pi   in [0, 1]   (row:    i = floor(v H)),   theta = acos(y)
    w_local = (sin theta sin phi, cos theta, -sin theta cos phi)

so the top row is +y (the zenith), the bottom row -y, u = 0 (the left edge) looks along -z, u = 1/4 along +x,
u = 1/2 (the image's centre column) along +z and u = 3/4 along -x. The world direction is ``w = R w_local`` with
``R`` = :func:`rotation_matrix` (yaw about +y, then pitch about +x, roll about +z): rotating the environment only
changes ``R`` (:attr:`EnvMap.to_world`), none of the tables below, so it is a cheap parameter (PVRT relights by
rotating the environment).

The radiance is piecewise constant: the pixel a direction falls in (no filtering), so the sampling density below
follows the radiance exactly within each pixel but for a sin(theta) factor.

Importance sampling (pbrt-v3 ``InfiniteAreaLight`` with ``Distribution2D``, pbrt-v4 ``PiecewiseConstant2D``)
---------------------------------------------------------------------------------------------------------
A direction is sampled in (u, v) from the piecewise-constant 2-D density proportional to

    f_ij = luminance(L_ij) sin(theta_i),     theta_i = pi (i + 1/2) / H   (the row's centre)

(the sin(theta) makes the density follow the pixels' solid angles: rows near the poles cover less of the sphere).
The marginal over rows is sampled first (``u1``), then the column within the row (``u2``), each by inverting a
piecewise-linear CDF, so (u, v) is continuous inside its pixel with

    p_uv(u, v) = f_ij / mean(f)            (a density on [0, 1]^2)

and, since dw = sin(theta) dtheta dphi = 2 pi^2 sin(theta) du dv, the solid-angle density is

    p_w(w) = p_uv(u, v) / (2 pi^2 sin theta)

(theta of the sample itself, not of the row's centre; 0 at the poles where sin theta = 0). A map whose f is 0
everywhere (black) is sampled with f_ij = sin(theta_i) (uniform over the sphere) so the tables stay valid.
Every pixel with radiance > 0 has f_ij > 0 (luminance weights are positive, sin(theta_i) > 0 at row centres), so
NEE with this density is unbiased.

The integral of the radiance over the sphere, needed by photon emission (flux pi R^2 int L dw, as for the
constant environment's 4 pi^2 R^2 L), is exact for the piecewise-constant radiance::

    int L dw = sum_ij L_ij (2 pi / W) (cos theta_i0 - cos theta_i1),   theta_i0 = pi i / H, theta_i1 = pi (i + 1) / H.

The kernels are numba functions over :class:`EnvMap`, a NamedTuple of arrays like the medium, so they can be
called inside the renderers' ``prange`` loops; a scene without an environment map passes :data:`NO_ENV_MAP`.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numba import njit

from photon_fields.runtime.borrowed import borrowed
from photon_fields.runtime.numba_inlining import install

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

#: Rec. 709 luminance weights of the sampling density (the same as the image tonemapper's).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
#: Jacobian of the lat-long map: dw = JACOBIAN sin(theta) du dv.
JACOBIAN = 2.0 * math.pi * math.pi
#: Radiance tables kept by :func:`cached_env_map` (by key): rotating a map rebuilds nothing.
_CACHE_SIZE = 8


class EnvMap(NamedTuple):
    """The arrays the kernels read (module docstring). ``radiance`` is the final radiance (image x colour x
    power, plus any constant environment merged into it)."""

    radiance: np.ndarray  # float64 (H, W, 3)
    row_cdf: np.ndarray  # float64 (H + 1,): marginal CDF over rows, row_cdf[0] = 0, row_cdf[H] = 1
    col_cdf: np.ndarray  # float64 (H, W + 1): each row's conditional CDF over columns
    pdf_uv: np.ndarray  # float64 (H, W): the density on [0, 1]^2 of (u, v) samples, f_ij / mean(f)
    to_world: np.ndarray  # float64 (3, 3): w_world = to_world @ w_local (a rotation)
    integral: np.ndarray  # float64 (3,): int L dw over the sphere, per channel


@njit(cache=True, inline="always")
def borrowed_env(env: EnvMap) -> EnvMap:
    """``env`` with its arrays borrowed (:mod:`photon_fields.runtime.borrowed`), for a serial task kernel's own use
    while its caller holds ``env``."""
    return EnvMap(borrowed(env.radiance), borrowed(env.row_cdf), borrowed(env.col_cdf), borrowed(env.pdf_uv),
                  borrowed(env.to_world), borrowed(env.integral))


def rotation_matrix(yaw_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """``R = R_y(yaw) R_x(pitch) R_z(roll)`` (degrees, right-handed, counter-clockwise looking down each axis):
    the map's frame in the world. A yaw of 90 degrees turns the map's -z (u = 0) to -x."""
    a, b, c = (math.radians(float(x)) for x in (yaw_deg, pitch_deg, roll_deg))
    ry = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(b), -math.sin(b)], [0.0, math.sin(b), math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0.0], [math.sin(c), math.cos(c), 0.0], [0.0, 0.0, 1.0]])
    return ry @ rx @ rz


def sphere_integral(radiance: np.ndarray) -> np.ndarray:
    """int L dw (3,) of a piecewise-constant lat-long radiance (H, W, 3) (module docstring)."""
    h, w = radiance.shape[:2]
    edges = np.cos(np.pi * np.arange(h + 1) / h)
    solid = (2.0 * np.pi / w) * (edges[:-1] - edges[1:])  # per pixel of each row
    return np.einsum("ijc,i->c", radiance.astype(np.float64), solid)


_tables: OrderedDict[str, tuple[np.ndarray, ...]] = OrderedDict()


def _distribution(radiance: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(row_cdf, col_cdf, pdf_uv, integral) of ``radiance`` (H, W, 3), see the module docstring."""
    h, w = radiance.shape[:2]
    sin_theta = np.sin(np.pi * (np.arange(h) + 0.5) / h)
    f = (radiance @ LUMINANCE) * sin_theta[:, None]
    if not float(f.sum()) > 0.0:  # a black map: uniform over the sphere, the tables must stay valid
        f = np.broadcast_to(sin_theta[:, None], (h, w)).copy()
    row_sum = f.sum(axis=1)
    col_cdf = np.zeros((h, w + 1))
    col_cdf[:, 1:] = np.cumsum(f, axis=1)
    nonzero = row_sum > 0
    col_cdf[nonzero] /= row_sum[nonzero, None]
    col_cdf[~nonzero] = np.linspace(0.0, 1.0, w + 1)[None, :]  # never selected: its marginal mass is 0
    col_cdf[:, -1] = 1.0
    row_cdf = np.zeros(h + 1)
    row_cdf[1:] = np.cumsum(row_sum) / row_sum.sum()
    row_cdf[-1] = 1.0
    pdf_uv = f / f.mean()
    return row_cdf, col_cdf, pdf_uv, sphere_integral(radiance)


def cached_env_map(key: str, make_radiance: Callable[[], np.ndarray], to_world: np.ndarray | None = None) -> EnvMap:
    """The :class:`EnvMap` of the lat-long radiance (H, W, 3) (finite, >= 0) that ``make_radiance`` returns,
    rotated by ``to_world`` (default: identity). Radiance and tables are kept under ``key`` (it must identify
    the radiance: the scene uses the image's hash, color, power and merged constants), so a map that differs only
    in its rotation costs a dictionary lookup: ``make_radiance`` is not even called."""
    if key in _tables:
        _tables.move_to_end(key)
    else:
        radiance = np.ascontiguousarray(make_radiance(), dtype=np.float64)
        if radiance.ndim != 3 or radiance.shape[2] != 3 or radiance.shape[0] < 1 or radiance.shape[1] < 1:
            raise ValueError(f"radiance must be (H, W, 3), got {radiance.shape}")
        radiance.setflags(write=False)
        _tables[key] = (radiance, *_distribution(radiance))
        while len(_tables) > _CACHE_SIZE:
            _tables.popitem(last=False)
    radiance, row_cdf, col_cdf, pdf_uv, integral = _tables[key]
    r = np.eye(3) if to_world is None else np.ascontiguousarray(to_world, dtype=np.float64)
    return EnvMap(radiance, row_cdf, col_cdf, pdf_uv, r, integral)


def build_env_map(radiance: np.ndarray, to_world: np.ndarray | None = None) -> EnvMap:
    """:func:`cached_env_map` keyed by the hash of ``radiance`` itself."""
    radiance = np.ascontiguousarray(radiance, dtype=np.float64)
    return cached_env_map(hashlib.sha256(radiance.tobytes()).hexdigest() + str(radiance.shape), lambda: radiance,
                          to_world)


#: The placeholder the kernels get when a scene has no environment map (never read: no light has its kind).
NO_ENV_MAP = build_env_map(np.zeros((1, 2, 3)))


# --- kernels ------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _interval(cdf: np.ndarray, u: float) -> int:
    """The largest k in [0, len(cdf) - 2] with cdf[k] <= u (bisection; pbrt's FindInterval). Intervals of zero
    width are never returned for u in [0, 1): a later k with the same cdf value wins."""
    lo, hi = 0, cdf.shape[0] - 2
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cdf[mid] <= u:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True, inline="always")
def direction_to_uv(env: EnvMap, dx: float, dy: float, dz: float) -> tuple[float, float, float]:
    """World direction -> (u, v, sin theta) in the map (module docstring)."""
    r = env.to_world  # local = R^T world
    x = r[0, 0] * dx + r[1, 0] * dy + r[2, 0] * dz
    y = r[0, 1] * dx + r[1, 1] * dy + r[2, 1] * dz
    z = r[0, 2] * dx + r[1, 2] * dy + r[2, 2] * dz
    y = min(1.0, max(-1.0, y))
    phi = math.atan2(x, -z)
    if phi < 0.0:
        phi += 2.0 * math.pi
    return phi / (2.0 * math.pi), math.acos(y) / math.pi, math.sqrt(max(0.0, 1.0 - y * y))


@njit(cache=True, inline="always")
def uv_to_direction(env: EnvMap, u: float, v: float) -> tuple[float, float, float, float]:
    """(u, v) in the map -> (world direction, sin theta) (module docstring)."""
    theta, phi = math.pi * v, 2.0 * math.pi * u
    st = math.sin(theta)
    x, y, z = st * math.sin(phi), math.cos(theta), -st * math.cos(phi)
    r = env.to_world
    return (r[0, 0] * x + r[0, 1] * y + r[0, 2] * z, r[1, 0] * x + r[1, 1] * y + r[1, 2] * z,
            r[2, 0] * x + r[2, 1] * y + r[2, 2] * z, st)


@njit(cache=True, inline="always")
def env_map_eval(env: EnvMap, dx: float, dy: float, dz: float) -> tuple[float, float, float, float]:
    """Radiance arriving from world direction w = (dx, dy, dz) and the solid-angle pdf with which
    :func:`env_map_sample` draws w: (r, g, b, pdf)."""
    u, v, st = direction_to_uv(env, dx, dy, dz)
    h, w = env.pdf_uv.shape
    i = min(int(v * h), h - 1)
    j = min(int(u * w), w - 1)
    pdf = env.pdf_uv[i, j] / (2.0 * math.pi * math.pi * st) if st > 0.0 else 0.0
    return env.radiance[i, j, 0], env.radiance[i, j, 1], env.radiance[i, j, 2], pdf


@njit(cache=True, inline="always")
def env_map_sample(env: EnvMap, u1: float, u2: float) -> tuple[float, float, float, float, float, float, float]:
    """A direction drawn from the map's density from two uniforms in [0, 1): (dx, dy, dz, r, g, b, pdf), pdf in
    solid angle; pdf 0 (and no contribution) at a pole."""
    h, w = env.pdf_uv.shape
    i = _interval(env.row_cdf, u1)
    du = env.row_cdf[i + 1] - env.row_cdf[i]
    v = (i + ((u1 - env.row_cdf[i]) / du if du > 0.0 else 0.5)) / h
    cdf = env.col_cdf[i]
    j = _interval(cdf, u2)
    dc = cdf[j + 1] - cdf[j]
    u = (j + ((u2 - cdf[j]) / dc if dc > 0.0 else 0.5)) / w
    dx, dy, dz, st = uv_to_direction(env, u, min(v, 1.0))
    if st <= 0.0:
        return dx, dy, dz, 0.0, 0.0, 0.0, 0.0
    pdf = env.pdf_uv[i, j] / (2.0 * math.pi * math.pi * st)
    return dx, dy, dz, env.radiance[i, j, 0], env.radiance[i, j, 1], env.radiance[i, j, 2], pdf


@njit(cache=True)
def env_map_eval_batch(env: EnvMap, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radiance (3, n) and sampling pdf (n,) of the map for the unit directions ``d`` (3, n): what escaping rays
    see, and the pdf their MIS weight against NEE needs."""
    n = d.shape[1]
    rgb = np.empty((3, n))
    pdf = np.empty(n)
    for k in range(n):
        rgb[0, k], rgb[1, k], rgb[2, k], pdf[k] = env_map_eval(env, d[0, k], d[1, k], d[2, k])
    return rgb, pdf
