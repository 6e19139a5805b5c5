"""Suns: the compact bright parts of an environment map that a lighting basis cannot represent.

PVRT renders an environment map's direct term from its projection into the basis (Sec. 6.2, ``runtime/pvrt/
direct.py``), and a DSF basis light is a cone (15.9 degrees at order 2): a sun a few degrees wide, which carries
most of a real sky's power, comes out as a blurred disc whose shadows are soft and whose lit skin is dark (the
vortex under bench_envmap's sky: L_d 0.95 of the path tracer's, PVRT's error 2x the field's). So, as the issue's "a
light the basis cannot represent: say so and fall back to NEE for the direct part" asks, :func:`split_suns` finds
them and :mod:`photon_fields.runtime.pvrt.lighting` renders each as a directional light (NEE through a light volume
for its direct term, the basis for its multiple scattering) and projects only the rest of the map.

A sun is a 4-connected group of pixels (connected across the map's left and right edges) each brighter than
``SUN_RATIO`` times the map's mean radiance (its power over 4 pi, in luminance), whose pixel centres all lie within
the basis' angular resolution of the group's power-weighted mean direction: a group wider than that is light the
basis does resolve, and stays in the map. Its directional light has the group's irradiance, the sum of radiance
times solid angle over its pixels (RGB), so the map's power is kept exactly; its pixels are zero in the rest.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable

import numpy as np

from photon_fields.runtime.transport.environment_map import LUMINANCE

#: A pixel belongs to a sun when its luminance is more than this many times the map's mean radiance (bench_envmap's
#: sky: its sun ~370x; a studio's soft patches ~20x stay in the map).
SUN_RATIO = 100.0
#: Maps kept by :func:`cached_suns` (by the caller's key: a rotation or a colour edit of the same image reuses it).
_CACHE_SIZE = 8
_cache: OrderedDict[tuple[str, float], tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]] = OrderedDict()


def pixel_directions(h: int, w: int, flat: np.ndarray) -> np.ndarray:
    """Unit directions (n, 3) of the centres of the pixels ``flat`` (flat indices into an h x w map) in the map's
    own frame (``environment_map``'s convention)."""
    i, j = np.divmod(np.asarray(flat, dtype=np.int64), w)
    theta, phi = np.pi * (i + 0.5) / h, 2 * np.pi * (j + 0.5) / w
    return np.stack([np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], axis=-1)


def row_solid_angles(h: int, w: int) -> np.ndarray:
    """The solid angle (h,) of one pixel in each row of an h x w lat-long map."""
    return (2 * np.pi / w) * (np.cos(np.pi * np.arange(h) / h) - np.cos(np.pi * (np.arange(h) + 1) / h))


def _groups(mask: np.ndarray) -> list[np.ndarray]:
    """4-connected groups of True pixels (flat indices), connected across the left and right edges."""
    h, w = mask.shape
    seen = np.zeros_like(mask)
    out = []
    for start in np.flatnonzero(mask):
        if seen.flat[start]:
            continue
        stack, members = [int(start)], []
        seen.flat[start] = True
        while stack:
            p = stack.pop()
            members.append(p)
            i, j = divmod(p, w)
            for a, b in ((i - 1, j), (i + 1, j), (i, (j - 1) % w), (i, (j + 1) % w)):
                if 0 <= a < h and mask[a, b] and not seen[a, b]:
                    seen[a, b] = True
                    stack.append(a * w + b)
        out.append(np.array(sorted(members), dtype=np.int64))
    return out


def split_suns(radiance: np.ndarray, resolution: float) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """([(direction the light arrives from in the map's frame (3,), irradiance RGB (3,)), ...], the rest of the map
    (H, W, 3)) of ``radiance`` (module docstring); ``resolution``: the basis' angular resolution in radians."""
    radiance = np.asarray(radiance, dtype=np.float64)
    h, w = radiance.shape[:2]
    omega = row_solid_angles(h, w)
    lum = radiance @ LUMINANCE
    mean = float(np.sum(lum.sum(axis=1) * omega)) / (4 * math.pi)
    if not mean > 0:
        return [], radiance
    suns, rest = [], radiance
    cos_res = math.cos(resolution)
    for members in _groups(lum > SUN_RATIO * mean):
        px = pixel_directions(h, w, members)
        pixel_omega = omega[members // w]
        centre = (lum.reshape(-1)[members] * pixel_omega) @ px
        centre /= np.linalg.norm(centre)
        if float(np.min(px @ centre)) < cos_res:
            continue  # wider than the basis resolves: it stays in the map
        irradiance = (radiance.reshape(-1, 3)[members] * pixel_omega[:, None]).sum(axis=0)
        suns.append((centre, irradiance))
        if rest is radiance:
            rest = radiance.copy()
        rest.reshape(-1, 3)[members] = 0.0
    return suns, rest


def cached_suns(key: str, make_radiance: Callable[[], np.ndarray],
                resolution: float) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """:func:`split_suns` of the radiance ``make_radiance`` returns, kept under ``key`` (it must identify the
    radiance) for the next frames: a rotated map costs a dictionary lookup."""
    k = (key, float(resolution))
    if k not in _cache:
        _cache[k] = split_suns(make_radiance(), resolution)
        while len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    _cache.move_to_end(k)
    return _cache[k]
