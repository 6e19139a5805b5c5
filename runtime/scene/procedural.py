"""Deterministic procedural scalar volumes: the embedded scenes (nothing is ever downloaded).

Every generator takes ``n`` (voxels per axis, default 96) and returns a float32 array of shape
``(n, n, n)`` indexed ``[x, y, z]`` (the :mod:`runtime.scene.volume` convention) with values in [0, 1]: the
minimum is exactly 0 (empty space) and the maximum exactly 1. Positions below are in box units:
voxel ``i`` sits at ``(i + 0.5) / n - 0.5``, so the box is [-0.5, 0.5]^3. ``+y`` is "up".

Generators (see :data:`GENERATORS`):

``vortex``
    Vorticity magnitude of turbulent vortex structures, in the spirit of the VORTICES dataset: a few
    wavy (Widnall-unstable) vortex rings plus many worm-like vortex tubes of varying core size and
    strength, modulated by fractal value noise. Each tube is a Lamb-Oseen core: its vorticity is the
    vortex line convolved with a 3-D Gaussian, which is how it is built (splat + separable blur).
    Wispy, with ~17 % of the voxels non-zero.
``blobs``
    A cumulus-like cloud: 32 soft Gaussian blobs of different sizes on a flat base, big towers low
    in the middle, smaller turrets and billows on top, lightly roughened by noise, fitted to the box.
    ~25 % of the voxels non-zero.
``shell``
    A hard-edged ellipsoidal shell (outer semi-axes ~0.4, thickness 0.06) with cylindrical holes
    drilled through it, enclosing a dense core and three satellite spheres. Piecewise constant with
    1-voxel edges (levels 0, 0.45, 0.75, 1), for testing how renderers handle sharp boundaries.
``head``
    A CT-like head phantom, the structured medium real scans are: skin, a skull, a thin CSF layer, a brain
    whose outer layer is folded by sulci (clefts about 1.5 voxels wide along the zero set of a noise field),
    two ventricles and ten wavy vessels of radius 1-1.5 voxels. Piecewise constant (levels 0.12 CSF,
    0.25 skin, 0.45 brain, 0.75 vessels, 1 bone) with 1-voxel edges; skin and skull are cut away in the
    octant facing the default camera, as a clipping plane would, so the folds are in view. Clefts and
    vessels are sized in voxels, not box units: they stay at the scale where a density estimate blurs.

Determinism: randomness comes from ``np.random.default_rng`` with a fixed seed per generator, and the
result is quantized to multiples of 2**-16 after float64 computation, so ulp-level differences between
BLAS/libm builds on different machines do not change the output bits (barring astronomically rare
ties). Sizes are in box units and thresholds are relative (a quantile, or a fraction of the peak), so
each volume looks the same and has the same fill fraction at every resolution; ``n = 128`` takes a
fraction of a second (the vortex blur dominates).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from photon_fields.runtime.errors import InputError

__all__ = ["GENERATORS", "blobs", "head", "shell", "vortex"]

_QUANT = 2.0**-16


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------


def _check_n(n: int) -> int:
    n = int(n)
    if n < 8:
        raise InputError("procedural volume resolution", f"must be at least 8 voxels per axis, got {n}")
    return n


def _centres(n: int) -> np.ndarray:
    """Cell-centred voxel positions along one axis, in box units [-0.5, 0.5]."""
    return (np.arange(n, dtype=np.float64) + 0.5) / n - 0.5


def _apply_axes(grid: np.ndarray, mats: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Contract each axis of ``grid`` (a, b, c) with matrices (n, a), (n, b), (n, c): separable filtering.

    Matrix products are used (instead of scipy.ndimage) because they vectorize to a few BLAS calls and
    let the output grid differ from the input grid (padding, lattice upsampling).
    """
    out = np.tensordot(mats[0], grid, axes=(1, 0))  # (n, b, c)
    out = np.tensordot(out, mats[1], axes=(1, 1))  # (n, c, n)
    out = np.tensordot(out, mats[2], axes=(1, 1))  # (n, n, n), axes now [x, y, z]
    return out


def _quantize(field: np.ndarray) -> np.ndarray:
    """Clip to [0, 1] and snap to multiples of 2**-16 (see module docstring), as float32."""
    return (np.round(np.clip(field, 0.0, 1.0) / _QUANT) * _QUANT).astype(np.float32)


def _fill_to_fraction(field: np.ndarray, fraction: float, gamma: float = 1.0) -> np.ndarray:
    """Zero everything below the ``1 - fraction`` quantile, rescale the rest to end at 1 (max = 1).

    Subtracting the threshold (not just masking) keeps the density continuous at the edge of the
    empty space, so soft structures stay soft.
    """
    lo = float(np.quantile(field, 1.0 - fraction))
    hi = float(field.max())
    out = np.clip((field - lo) / max(hi - lo, 1e-300), 0.0, 1.0)
    return out**gamma if gamma != 1.0 else out


def _value_noise(n: int, cells: int, rng: np.random.Generator) -> np.ndarray:
    """Smooth value noise in [0, 1]: a random lattice of ``cells`` per axis, smoothstep-interpolated."""
    lattice = rng.random((cells + 1,) * 3)
    u = (np.arange(n, dtype=np.float64) + 0.5) / n * cells
    j0 = np.minimum(np.floor(u).astype(np.int64), cells - 1)
    f = u - j0
    s = f * f * (3.0 - 2.0 * f)  # smoothstep: C1 continuous across lattice cells, no grid creases
    W = np.zeros((n, cells + 1))
    W[np.arange(n), j0] = 1.0 - s
    W[np.arange(n), j0 + 1] = s
    return _apply_axes(lattice, (W, W, W))


def _fractal_noise(n: int, base_cells: int, octaves: int, rng: np.random.Generator) -> np.ndarray:
    """Sum of value-noise octaves (frequency x2, amplitude x0.5), centred on 0, roughly in [-1, 1]."""
    total = np.zeros((n, n, n))
    amp, norm = 1.0, 0.0
    for o in range(octaves):
        total += amp * (_value_noise(n, base_cells * 2**o, rng) - 0.5)
        norm += amp
        amp *= 0.5
    return total * (2.0 / norm)


def _blur_crop(grid: np.ndarray, pad: int, sigma_vox: float) -> np.ndarray:
    """Gaussian blur (sigma in voxels, kernel cut at ``pad`` voxels) of an (n + 2 pad)^3 grid, cropped to n^3.

    Separable, one axis at a time, as products with the (n, n + 2 pad) kernel matrix. z goes first and
    only over the z-rows that hold any deposit (a splatted curve touches few of them), which shrinks the
    data before the dense y and x passes: ~10x faster than contracting the full padded grid first.
    """
    m = grid.shape[0]
    n = m - 2 * pad
    taps = np.arange(-pad, pad + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (taps / sigma_vox) ** 2) / (np.sqrt(2.0 * np.pi) * sigma_vox)
    K = np.zeros((n, m))
    for r in range(n):
        K[r, r : r + 2 * pad + 1] = kernel
    rows = grid.reshape(m * m, m)
    hit = np.flatnonzero(rows.any(axis=1))
    zb = np.zeros((m * m, n))
    zb[hit] = rows[hit] @ K.T
    yb = np.matmul(K, zb.reshape(m, m, n))  # (m, n, n): batched over x
    return (K @ yb.reshape(m, n * n)).reshape(n, n, n)


def _splat(points: np.ndarray, weights: np.ndarray, n: int, pad: int) -> np.ndarray:
    """Trilinear deposit of weighted points (box units) onto an (n + 2 pad)^3 grid (padding kept so
    that tubes crossing the box boundary are blurred as if they continued, instead of being cut)."""
    m = n + 2 * pad
    g = (points + 0.5) * n - 0.5 + pad  # continuous voxel index in the padded grid
    i0 = np.floor(g).astype(np.int64)
    f = g - i0
    keep = np.all((i0 >= 0) & (i0 < m - 1), axis=1)
    i0, f, w = i0[keep], f[keep], weights[keep]
    flat, wts = [], []
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1.0 - f[:, 0]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1.0 - f[:, 1]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1.0 - f[:, 2]
                flat.append(((i0[:, 0] + dx) * m + (i0[:, 1] + dy)) * m + (i0[:, 2] + dz))
                wts.append(w * wx * wy * wz)
    # One bincount (a sequential, hence deterministic, sum) instead of eight full-grid additions.
    grid = np.bincount(np.concatenate(flat), weights=np.concatenate(wts), minlength=m * m * m)
    return grid.reshape(m, m, m)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``normal`` and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = _unit(np.cross(normal, helper))
    return u, np.cross(normal, u)


# ----------------------------------------------------------------------------------------------
# vortex
# ----------------------------------------------------------------------------------------------


def _vortex_ring(rng: np.random.Generator, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """A wavy vortex ring (Widnall instability: azimuthal waves in radius and along the normal)."""
    centre = rng.uniform(-0.15, 0.15, 3)
    normal = _unit(rng.normal(size=3))
    u, v = _frame(normal)
    radius = rng.uniform(0.17, 0.24)
    k = int(rng.integers(4, 8))  # number of azimuthal waves
    phase = rng.uniform(0, 2 * np.pi, 2)
    th = np.linspace(0.0, 2 * np.pi, samples, endpoint=False)
    r = radius * (1.0 + 0.08 * np.sin(k * th + phase[0]))
    pts = centre + r[:, None] * (np.cos(th)[:, None] * u + np.sin(th)[:, None] * v)
    pts += (0.04 * np.sin(k * th + phase[1]))[:, None] * normal
    strength = 1.0 + 0.35 * np.sin(2 * th + phase[0]) * np.cos(3 * th + phase[1])
    return pts, strength


def _vortex_worm(rng: np.random.Generator, samples: int, length: float) -> tuple[np.ndarray, np.ndarray]:
    """A worm-like vortex tube: a straight segment bent by a few random sine modes, tapered at its ends."""
    centre = rng.uniform(-0.42, 0.42, 3)
    axis = _unit(rng.normal(size=3))
    t = np.linspace(0.0, 1.0, samples)
    pts = centre + (length * (t - 0.5))[:, None] * axis
    for mode in range(1, 4):
        direction = _unit(np.cross(axis, rng.normal(size=3)))
        amp = length * rng.uniform(0.08, 0.2) / mode
        pts += (amp * np.sin(np.pi * mode * t + rng.uniform(0, 2 * np.pi)))[:, None] * direction
    # Vortex stretching concentrates vorticity unevenly along a tube; the ends fade out (a real tube
    # would close or spread into background vorticity rather than stop abruptly).
    taper = np.sin(np.pi * t) ** 0.6
    strength = taper * (1.0 + 0.7 * np.sin(2 * np.pi * rng.uniform(1.0, 3.0) * t + rng.uniform(0, 2 * np.pi)))
    return pts, strength


def vortex(n: int = 96) -> np.ndarray:
    """Turbulent vortex field (vorticity magnitude of rings and worm-like tubes); see module docstring."""
    n = _check_n(n)
    rng = np.random.default_rng(0x5EED_0001)
    # Core sizes (Gaussian sigma, box units): tubes are grouped by core size so each group is one blur.
    core_sigmas = (0.010, 0.016, 0.026)
    step = 0.25 / n  # curve sample spacing: a quarter voxel, so the splatted line has no beads
    lines: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in core_sigmas]

    for _ in range(2):  # rings: the larger coherent structures, medium/thick cores
        pts, s = _vortex_ring(rng, samples=int(2 * np.pi * 0.25 / step))
        lines[int(rng.integers(1, 3))].append((pts, s))
    for _ in range(26):  # worms: the hallmark of developed turbulence, mostly thin
        length = rng.uniform(0.25, 0.8)
        pts, s = _vortex_worm(rng, samples=int(length * 1.6 / step), length=length)
        group = int(rng.choice(3, p=(0.45, 0.4, 0.15)))
        lines[group].append((pts, rng.uniform(0.5, 1.1) * s))

    field = np.zeros((n, n, n))
    for sigma, group in zip(core_sigmas, lines, strict=True):
        if not group:
            continue
        pts = np.concatenate([p for p, _ in group])
        # Weight = circulation * arc length. A line of circulation G blurred by a 3-D Gaussian of width
        # sigma has the Lamb-Oseen peak vorticity G / (2 pi sigma^2). The extra factor sigma tempers
        # that 1/sigma^2 so that thin tubes stand out without making the thick ones invisible.
        seg = np.concatenate([np.linalg.norm(np.gradient(p, axis=0), axis=1) for p, _ in group])
        w = np.concatenate([s for _, s in group]) * seg * sigma
        pad = int(np.ceil(4.0 * sigma * n))  # kernel cut at 4 sigma (< 0.04 % of the peak)
        field += _blur_crop(_splat(pts, w * n**2, n, pad), pad, sigma * n)

    # Small-scale turbulence: multiplicative fractal noise breaks the tubes' smoothness into wisps.
    noise = _fractal_noise(n, 5, 3, rng)
    field *= np.clip(1.0 + 0.9 * noise, 0.0, None)
    field /= np.quantile(field, 0.9995)  # a few hot crossings must not compress everything else
    field = np.minimum(field, 1.0)
    return _quantize(_fill_to_fraction(field, 0.17, gamma=1.3))


# ----------------------------------------------------------------------------------------------
# blobs
# ----------------------------------------------------------------------------------------------


def _attach(
    rng: np.random.Generator, parents: np.ndarray, parent_r: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    """Centres for child blobs sitting on the surface of random parents, mostly on their upper side."""
    idx = rng.integers(0, len(parents), len(radius))
    d = _unit(rng.normal(size=(len(radius), 3)) + np.array([0.0, 0.9, 0.0]))  # bias upwards: billows
    return parents[idx] + d * (parent_r[idx] + 0.4 * radius)[:, None]


def blobs(n: int = 96) -> np.ndarray:
    """Cumulus-like cloud of soft Gaussian blobs on a flat base (+y up); see module docstring."""
    n = _check_n(n)
    rng = np.random.default_rng(0x5EED_0002)
    base_y = -0.33
    # Hierarchy, as procedural cumulus is usually modelled: a few big towers along a flat base, medium
    # turrets on their surfaces, small billows on the turrets. 6 + 12 + 14 = 32 blobs.
    r_big = rng.uniform(0.11, 0.15, 6)
    x_big = np.linspace(-0.2, 0.2, 6) + rng.uniform(-0.03, 0.03, 6)
    z_big = rng.uniform(-0.25, 0.25, 6)
    towering = 0.3 * (1.0 - (x_big / 0.25) ** 2) * rng.uniform(0.5, 1.0, 6)  # taller in the middle
    y_big = base_y + 0.25 * r_big + towering  # low centres: the base cuts the blobs wide (flat)
    c_big = np.stack([x_big, y_big, z_big], axis=1)
    r_med = rng.uniform(0.06, 0.09, 12)
    c_med = _attach(rng, c_big, r_big, r_med)
    r_small = rng.uniform(0.035, 0.05, 14)
    c_small = _attach(rng, c_med, r_med, r_small)
    centres = np.concatenate([c_big, c_med, c_small])
    sigma = 0.45 * np.concatenate([r_big, r_med, r_small])  # a lone blob's edge (at r) is at ~2 sigma
    # Fit the cloud to the box (uniform scale, centred): a volume's box is its data's tight bounds.
    lo = np.min(centres - 2.2 * sigma[:, None], axis=0)
    hi = np.max(centres + 2.2 * sigma[:, None], axis=0)
    lo[1] = base_y
    scale = 0.94 / float(np.max(hi - lo))
    centres = (centres - 0.5 * (lo + hi)) * scale
    sigma = sigma * scale
    base_y = (base_y - 0.5 * (lo[1] + hi[1])) * scale

    # Separable Gaussians: sum_b gx_b(x) gy_b(y) gz_b(z) is a single tensor contraction (fast).
    x = _centres(n)
    G = [np.exp(-0.5 * ((x[None, :] - centres[:, a, None]) / sigma[:, None]) ** 2) for a in range(3)]
    # Smaller blobs are a little fainter, so billows read as texture on the towers, not as bright beads.
    weight = np.sqrt(sigma / sigma.max())
    field = np.einsum("bi,bj,bk->ijk", G[0] * weight[:, None], G[1], G[2], optimize=True)

    # Surface detail (cauliflower look) and a flat base at the condensation level.
    field *= 1.0 + 0.3 * _fractal_noise(n, 6, 2, rng)
    field *= np.clip((x[None, :, None] - base_y) / 0.03, 0.0, 1.0)
    # The cloud's edge is where the blob sum drops to 1.5 % of its typical peak (a relative, hence
    # resolution-independent, level); the Gaussians' far tails would otherwise fill the whole box.
    field /= float(np.percentile(field, 99.5))
    excess = np.maximum(field - 0.015, 0.0)
    # Where blobs overlap the sum keeps growing; a cloud's interior does not. Saturate it softly, so the
    # body is fairly even but the blobs' cores still show, with a soft (a few voxels) rim.
    dense = 1.0 - np.exp(-excess / 0.35)
    return _quantize(dense / dense.max())


# ----------------------------------------------------------------------------------------------
# shell
# ----------------------------------------------------------------------------------------------

SHELL_LEVELS = (0.45, 0.75, 1.0)  # shell, satellites, core (exact float32 values in the output)


def shell(n: int = 96) -> np.ndarray:
    """Hard-edged ellipsoidal shell with holes, a dense core and satellites; see module docstring."""
    n = _check_n(n)
    rng = np.random.default_rng(0x5EED_0003)
    c = _centres(n)
    X, Y, Z = c[:, None, None], c[None, :, None], c[None, None, :]
    outer = np.array([0.42, 0.38, 0.40])
    thickness = 0.06

    def inside(semi: np.ndarray, centre: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        # Tested at voxel centres with no anti-aliasing: this is what makes the edges 1 voxel sharp.
        q = ((X - centre[0]) / semi[0]) ** 2 + ((Y - centre[1]) / semi[1]) ** 2
        q = q + ((Z - centre[2]) / semi[2]) ** 2
        return q <= 1.0

    wall = inside(outer) & ~inside(outer - thickness)
    # Holes: cylinders through the centre; each one opens two windows on opposite sides.
    for _ in range(4):
        d = _unit(rng.normal(size=3))
        r = rng.uniform(0.08, 0.13)
        along = X * d[0] + Y * d[1] + Z * d[2]
        dist2 = X**2 + Y**2 + Z**2 - along**2
        wall &= dist2 > r * r

    out = np.zeros((n, n, n), dtype=np.float32)
    out[wall] = SHELL_LEVELS[0]
    for _ in range(3):  # satellites orbiting the core, visible through the holes
        d = _unit(rng.normal(size=3))
        out[inside(np.full(3, 0.05), tuple(0.2 * d))] = SHELL_LEVELS[1]
    out[inside(np.array([0.11, 0.11, 0.11]))] = SHELL_LEVELS[2]
    return out


HEAD_LEVELS = (0.12, 0.25, 0.45, 0.75, 1.0)  # CSF, skin, brain, vessels, bone (exact float32 values)


def head(n: int = 96) -> np.ndarray:
    """CT-like head phantom: skin, skull, folded brain, ventricles and vessels; see module docstring."""
    n = _check_n(n)
    rng = np.random.default_rng(0x5EED_0004)
    c = _centres(n)
    X, Y, Z = c[:, None, None], c[None, :, None], c[None, None, :]

    def ellipsoid(semi: tuple[float, float, float], centre: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        # The normalized radius: <= 1 inside. Tested at voxel centres, so edges are 1 voxel sharp.
        return np.sqrt(((X - centre[0]) / semi[0]) ** 2 + ((Y - centre[1]) / semi[1]) ** 2
                       + ((Z - centre[2]) / semi[2]) ** 2)

    head_r = ellipsoid((0.36, 0.42, 0.40))
    skin = head_r <= 1.0
    skull_outer = head_r <= 1.0 - 0.09
    skull_inner = head_r <= 1.0 - 0.09 - 0.11
    brain = ellipsoid((0.36 * 0.77, 0.42 * 0.77, 0.40 * 0.77), (0.0, 0.0, 0.0)) <= 1.0
    # Sulci: thin clefts 1-2 voxels wide, cut into the outer layer of the brain along the zero set of a noise
    # field, so the cortex folds the way light has to follow.
    folds = _fractal_noise(n, 9, 2, rng)
    slope = np.sqrt(sum(gr * gr for gr in np.gradient(folds)))  # per voxel
    cleft_voxels = np.abs(folds) / np.maximum(slope, 1e-12)  # distance to the zero set, in voxels
    cortex = brain & (ellipsoid((0.36 * 0.77, 0.42 * 0.77, 0.40 * 0.77)) > 0.5)
    sulci = cortex & (cleft_voxels < 0.8)
    ventricles = (ellipsoid((0.035, 0.09, 0.12), (-0.05, 0.03, 0.0)) <= 1.0) | \
        (ellipsoid((0.035, 0.09, 0.12), (0.05, 0.03, 0.0)) <= 1.0)
    out = np.zeros((n, n, n), dtype=np.float32)
    out[skin] = HEAD_LEVELS[1]
    out[skull_outer] = HEAD_LEVELS[4]
    out[skull_inner] = HEAD_LEVELS[0]  # the CSF layer between skull and brain
    out[brain] = HEAD_LEVELS[2]
    out[sulci | ventricles] = HEAD_LEVELS[0]
    # A cut-away of the skin and skull facing the default camera, as a clipping plane would show it.
    cut = (X > 0.02) & (Z > 0.02) & (Y > -0.12) & ~brain
    out[cut] = 0.0
    # Vessels: wavy tubes of radius 1-1.5 voxels winding over the brain's surface and through it.
    for _ in range(10):
        a = rng.uniform(0, 2 * np.pi)
        e = rng.uniform(-0.6, 0.6)
        start = np.array([np.cos(a) * np.cos(e), np.sin(e), np.sin(a) * np.cos(e)]) * 0.27
        direction = _unit(rng.normal(size=3) - start * 2.0)
        samples = 400
        t = np.linspace(0.0, 0.35, samples)
        wiggle = np.stack([np.sin(t * 40.0 + rng.uniform(0, 6)), np.cos(t * 33.0 + rng.uniform(0, 6)),
                           np.sin(t * 27.0 + rng.uniform(0, 6))], axis=1) * 0.015
        path = start + t[:, None] * direction + wiggle
        radius = rng.uniform(1.0, 1.5) / n
        for p in path[::2]:
            lo = np.clip(((p - 0.5 / n - radius + 0.5) * n).astype(int) - 1, 0, n - 1)
            hi = np.clip(((p + radius + 0.5) * n).astype(int) + 2, 0, n)
            sub = (X[lo[0]:hi[0]] - p[0]) ** 2 + (Y[:, lo[1]:hi[1]] - p[1]) ** 2 + (Z[:, :, lo[2]:hi[2]] - p[2]) ** 2
            block = out[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
            block[(sub <= radius * radius) & (block > 0)] = HEAD_LEVELS[3]
    return out


GENERATORS: dict[str, Callable[[int], np.ndarray]] = {"vortex": vortex, "blobs": blobs, "shell": shell, "head": head}
