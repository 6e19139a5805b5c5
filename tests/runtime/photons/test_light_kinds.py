"""Independent checks per light kind: photon tracing + the first-interaction renderer against the path tracer.

The photon map (``train.photons.tracing``: emission, Russian roulette with a coloured albedo, storage from the
second collision; ``photon_fields.runtime.photons.estimate``: Eq. 5 with the phase of each photon) and the path tracer
(``runtime.renderers.path_tracer``) share no transport code beyond delta tracking and the HG formula, so their L_i agree
only if both are right. Each light kind gets its own scene, because each has its own emission code:

- a point light *outside* the volume's bounding sphere (the photons are emitted into the cone towards it, and
  their power is scaled by the cone's solid-angle fraction);
- a directional light (a disk of parallel rays);
- a constant environment light (a uniform direction, then a disk);
- an environment map (a sky with a warm glow, rotated: the direction from the map's importance sampling, then a
  disk, the photon's power scaled per channel by L / (p int L)).

The medium has a coloured albedo that varies with density (three transfer-function points with different RGB
albedo), so a missing or misapplied albedo factor (at the camera vertex or along the photon paths) shifts the
per-channel means (dropping it at the camera vertex: +11 %, +92 %, +53 % in R, G, B); g != 0 (-0.5, 0.75,
0.4), so a flipped phase convention in the photon estimate shifts them too (+25 %, +51-112 %, -9 to -16 %:
measured). L_i is rendered by :func:`photon_fields.runtime.renderers.neural.render_neural` with the
photon map in place of the field: the neural renderer's own composition (L_i = albedo x Q) is what is checked.

Bounds from measured noise: 5 seeds of everything (map, photon-map render, path tracer) per light kind. The
per-channel ratios of the L_i image means (photon map / path tracer) were 1.006-1.012 on average (the KNN blur's
bias) with a standard deviation of 0.4-1.4 %, worst |ratio - 1| 0.026 of 45; the relative L2 of 4x4-pixel block
means was at most 0.051. Bounds: 0.05 and 0.10. ~3 s per light kind.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import coloured_tf, small_camera, smooth_field

from photon_fields.runtime.photons.estimate import PhotonMapEstimator
from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, EnvironmentMap, Light, PointLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.train.photons.tracing import trace_photons


def sky_image(h: int = 16) -> np.ndarray:
    """A 2:1 sky: bright zenith fading to a dim ground, a warm glow: strongly directional but smooth."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(2 * h) + 0.5) / (2 * h)
    vv, uu = np.meshgrid(v, u, indexing="ij")
    glow = np.exp(-((vv - 0.3) ** 2 + (uu - 0.2) ** 2) / 0.02)
    base = np.where(vv < 0.5, 1.5 - vv, 0.1)
    return (base[..., None] * [0.5, 0.7, 1.0] + glow[..., None] * [4.0, 2.5, 1.0]).astype(np.float32)


#: (light, g): the point light at distance 1.1 from the centre, outside the bounding sphere (radius 0.87);
#: dropping the cone's solid-angle fraction would make its photons 5.2x too strong.
LIGHT_KINDS: dict[str, tuple[Light, float]] = {
    "point_outside": (PointLight([0.9, 0.6, 0.2], [1.0, 0.9, 0.8], 0.6), -0.5),
    "directional": (DirectionalLight([-0.5, -1.0, -0.3], [1.0, 1.0, 1.0], 3.0), 0.75),
    "environment": (EnvironmentLight([0.9, 1.0, 1.1], 1.0), 0.4),
    "environment_map": (EnvironmentMap("sky", [1.0, 1.0, 1.0], 1.0, [40.0, 25.0, 0.0], sky_image()), 0.3),
}
PHOTONS = 1_000_000
PT_SPP = 4096
PM_SPP = 64
MEAN_BOUND = 0.05  # per-channel |mean ratio - 1|: measured worst 0.026 (5 seeds x 3 kinds x 3 channels)
BLOCK_BOUND = 0.10  # relative L2 of 4x4-pixel block means: measured worst 0.051


def coloured_scene(kind: str) -> Scene:
    light, g = LIGHT_KINDS[kind]
    vol = make_volume(smooth_field(24), window=(0.0, 1.0), name="smooth")
    return Scene(vol, coloured_tf(), (light,), small_camera(16), g, f"coloured-{kind}")


def block_means(img: np.ndarray, b: int = 4) -> np.ndarray:
    h, w = img.shape[:2]
    return img.reshape(h // b, b, w // b, b, -1).mean(axis=(1, 3))


def compare_li(scene: Scene, *, pt_seed: int = 11, map_seed: int = 3, render_seed: int = 5) -> tuple[np.ndarray, float]:
    """(per-channel L_i mean ratio photon map / path tracer, relative L2 of the 4x4 block means)."""
    ref = render_path_traced(scene, spp=PT_SPP, seed=pt_seed, progress=False).layers["L_i"]
    pmap = trace_photons(scene, PHOTONS, phases=(scene.g,), seed=map_seed, progress=False)
    est = PhotonMapEstimator(pmap, scene.medium())
    li = render_neural(scene, est, spp=PM_SPP, seed=render_seed, progress=False, direct=False).layers["L_i"]
    ratio = li.mean(axis=(0, 1)) / ref.mean(axis=(0, 1))
    a, b = block_means(li), block_means(ref)
    return ratio, math.sqrt(float(((a - b) ** 2).sum() / (b**2).sum()))


@pytest.mark.parametrize("kind", list(LIGHT_KINDS))
def test_photon_map_li_matches_path_tracer_per_light_kind(kind: str) -> None:
    scene = coloured_scene(kind)
    ratio, rel_l2 = compare_li(scene)
    assert np.all(np.abs(ratio - 1.0) < MEAN_BOUND), (kind, ratio)
    assert rel_l2 < BLOCK_BOUND, (kind, rel_l2)
