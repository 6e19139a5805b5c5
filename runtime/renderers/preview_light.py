"""The preview's second stage: the light at the samples a camera march buffered (:mod:`photon_fields.runtime.
renderers.ray_marcher`, whose module docstring has the sum).

The march of a camera ray is a chain: each sample's extinction gives its transmittance, which decides the next
sample and the ray's end. The light at a sample (its light-volume stencil, or a shadow ray) does not feed that
chain, so the march buffers its samples (scattering centroid, weight, albedo) and :func:`light_samples` looks up
their light in a separate loop. There, the samples are independent: the core overlaps their light-volume reads,
which in one loop with the march waited in line behind each sample's extinction (bench/README.md, "The preview's
light in a second loop": 0.89-0.95x the frame, the same sums bit for bit).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from photon_fields.runtime.scene.lights import DIRECTIONAL
from photon_fields.runtime.transport.cell_grid import Grid, stencil
from photon_fields.runtime.transport.emitters import delta_light_direction
from photon_fields.runtime.transport.light_volume import light_transmittance, want_stencil
from photon_fields.runtime.transport.marching import march_transmittance
from photon_fields.runtime.transport.medium import Medium
from photon_fields.runtime.transport.phase import hg_eval


@njit(cache=True)
def _shadow_ray(m: Medium, x: float, y: float, z: float, lx: float, ly: float, lz: float, tend: float, h: float,
                skip: bool) -> float:
    """``march_transmittance`` as a call, for the baseline: it keeps the preview's loop small (what a march inside
    it costs: ``light_volume.light_transmittance``), and a shadow ray costs far more than a call."""
    return march_transmittance(m, x, y, z, lx, ly, lz, tend, h, skip)


@njit(cache=True, inline="always")
def light_samples(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, h_shadow: float,
                  skip: bool, use_volume: bool, lv: np.ndarray, wanted: np.ndarray, grid: Grid, ld: np.ndarray,
                  missed: np.ndarray, samples: np.ndarray, ray_of: np.ndarray, count: int, dirs: np.ndarray,
                  phases: np.ndarray, lo: int) -> None:
    """The light at ``count`` buffered samples (rows of ``samples``: the scattering centroid x, y, z, the weight w
    = T (1 - e) and the albedo), added to their rays' L_d (``ld``) in the order they were marched (``ray_of``: each
    one's item index; ``dirs`` and ``phases``: each ray's direction and directional lights' phase values, rows
    from item ``lo``). With a light volume (``use_volume``), a sample that reads an unfilled cell marks its ray
    ``missed``, and from there on the ray's samples mark the cells they read (:func:`want_stencil`) instead of
    summing them; else a shadow ray is marched to every light (the paper's baseline)."""
    for n in range(count):
        i = ray_of[n]
        r = i - lo
        x, y, z, w = samples[0, n], samples[1, n], samples[2, n], samples[3, n]
        a0, a1, a2 = samples[4, n], samples[5, n], samples[6, n]
        ci, cj, ck, fx, fy, fz = stencil(grid, x, y, z)
        for k in range(kind.shape[0]):
            # The environment is not marched (ray_marcher's docstring): delta_light_direction gives it 0.
            lx, ly, lz, scale, tend = delta_light_direction(kind[k], vec[k], x, y, z)
            ph = phases[r, k] if kind[k] == DIRECTIONAL else hg_eval(g, dirs[0, r] * lx + dirs[1, r] * ly
                                                                     + dirs[2, r] * lz)
            c = w * scale * ph
            if c <= 0.0:
                continue
            if use_volume:
                tl = -1.0 if missed[i] else light_transmittance(lv, k, ci, cj, ck, fx, fy, fz)
                if tl < 0.0:
                    missed[i] = True
                    want_stencil(lv, wanted, k, ci, cj, ck)
                    continue
                c *= tl
            else:
                c *= _shadow_ray(m, x, y, z, lx, ly, lz, tend, h_shadow, skip)
            ld[0, i] += c * a0 * rgb[k, 0]
            ld[1, i] += c * a1 * rgb[k, 1]
            ld[2, i] += c * a2 * rgb[k, 2]


#: Samples a task of the camera march buffers before their light is looked up (:func:`light_samples`).
SAMPLE_BUFFER = 1024
