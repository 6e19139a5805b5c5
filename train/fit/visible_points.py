"""Training points where a camera sees the medium: first collisions of rays entering from every direction.

The neural renderer asks the field for Q(x, d, g) at the first real collision x of a camera ray of travel
direction d (Alg. 2; :mod:`photon_fields.runtime.wavefront.first_interaction`). Those (x, d) pairs are not
uniform over the support and the sphere: x lies mostly within an optical depth or two of the surfaces a camera
can see, and d points into the medium there. A field fitted to (x, d) uniform over the support spends most of
its samples on the inside of dense structures, which no camera outside the volume sees, and on directions that
arrive from inside them; its error at the seen surfaces is then what the image shows.

:func:`visible_points` draws the pairs a camera anywhere around the volume would query: a travel direction d
uniform on the sphere, a ray of direction d through a point uniform on the disk that covers the box's bounding
sphere (so every line through the volume is equally likely: the measure of lines, the same for every camera
orbit), and its first real collision by delta tracking (pdf sigma_t T along the ray), as a camera's delta
estimator samples it. Rays that escape are drawn again.
"""

from __future__ import annotations

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.transport.medium import Medium
from photon_fields.runtime.transport.rng import stream_states
from photon_fields.runtime.transport.tracking import delta_track_batch

_MAX_RAYS = 1 << 26  # rays before giving up on a medium that (almost) nothing collides with


def uniform_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) uniform unit vectors: z uniform in [-1, 1], azimuth uniform (Archimedes)."""
    z = 1.0 - 2.0 * rng.random(n)
    phi = 2.0 * np.pi * rng.random(n)
    s = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def _orthonormal_frame(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (n, 3) orthogonal to d (n, 3) and to each other (Duff et al.'s branchless basis)."""
    sign = np.where(d[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + d[:, 2])
    b = d[:, 0] * d[:, 1] * a
    u = np.stack([1.0 + sign * d[:, 0] ** 2 * a, sign * b, -sign * d[:, 0]], axis=1)
    v = np.stack([b, sign + d[:, 1] ** 2 * a, -d[:, 1]], axis=1)
    return u, v


def _box_interval(m: Medium, o: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slab test: the ray parameters where rays o + t d (n, 3) enter and leave the medium's box."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (m.bmin - o) * inv
        t1 = (m.bmin + m.bsize - o) * inv
    t_near = np.nan_to_num(np.minimum(t0, t1), nan=-np.inf).max(axis=1)
    t_far = np.nan_to_num(np.maximum(t0, t1), nan=np.inf).min(axis=1)
    return np.maximum(t_near, 0.0), t_far


def visible_points(m: Medium, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n first collisions (n, 3) of rays entering the volume from every direction and the rays' unit travel
    directions (n, 3) (module docstring). Deterministic for a given ``rng`` state."""
    centre = m.bmin + 0.5 * m.bsize
    radius = 0.5 * float(np.linalg.norm(m.bsize))
    xs: list[np.ndarray] = []
    ds: list[np.ndarray] = []
    have = drawn = 0
    rate = 0.5
    while have < n:
        chunk = int(min(max(1.2 * (n - have) / rate, 1024), 1 << 20))
        d = uniform_directions(rng, chunk)
        u, v = _orthonormal_frame(d)
        r = radius * np.sqrt(rng.random(chunk))[:, None]
        phi = 2.0 * np.pi * rng.random(chunk)[:, None]
        o = centre + r * (np.cos(phi) * u + np.sin(phi) * v) - 2.0 * radius * d
        tmin, tmax = _box_interval(m, o, d)
        crosses = tmin < tmax
        o, d, tmin, tmax = o[crosses], d[crosses], tmin[crosses], tmax[crosses]
        states = stream_states(int(rng.integers(0, 2**63)), 0, o.shape[0])
        t = delta_track_batch(m, np.ascontiguousarray(o.T), np.ascontiguousarray(d.T), tmin, tmax, states)
        hit = np.isfinite(t)
        xs.append(o[hit] + t[hit, None] * d[hit])
        ds.append(d[hit])
        have += int(hit.sum())
        drawn += chunk
        rate = max(have / drawn, 1e-3)
        if have < n and drawn >= _MAX_RAYS:
            raise InputError("scene", f"rays into the volume almost never collide: {have} collisions in {drawn} rays")
    return np.concatenate(xs)[:n], np.concatenate(ds)[:n]
