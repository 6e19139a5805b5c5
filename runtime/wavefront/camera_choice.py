"""The "auto" camera estimator: the forced or the marched one, whichever gives this scene less noise per unit of work.

Parameters (module constants)
-----------------------------
PROBE_RAYS : int
    Camera rays per probe render (8192): a band of whole rows across the middle of the image at the render's own
    pixel size, so the probe costs about the same on any image size (a 256^2 frame's eighth, a 512^2 frame's
    32nd) and sees the pixel footprint the render will have (a larger pixel's own variation, which neither
    estimator removes, dilutes the ratio: docs/rendering.md).
COST_RATIO, COST_RESOLUTION, COST_EXPONENT : float
    The marched estimator's time per sample over the forced one's: 3.5 on volumes of ``COST_RESOLUTION`` (96) voxels
    across, from the embedded scenes' frames with a field (4 before the walks borrowed their medium, 2026-11-30),
    growing as (voxels across / 96) ^ ``COST_EXPONENT`` (0.3) on finer volumes (:func:`cost_ratio`: the marched
    walk's strata shorten at sharp walls, which a finer grid resolves, while the forced walk's cost follows the
    optical depth; docs/rendering.md). A model, not a timing of the probe, so that the choice, and with it the image,
    depends on the scene and the seed alone, never on the machine.

Which estimator has less noise per millisecond depends on the medium and the transfer function (docs/rendering.md,
"Which camera estimator"): marched sums the cached light over the whole ray and wins where rays cross thin or
partly lit matter, forced where a dense surface ends the ray and the field's noise at its one point is most of the
frame's. No cheaper statistic of the scene predicted it (the rays' mean transmittance puts a thin-walled shell,
where marched wins, with the opaque scenes), so the choice is measured: two probe renders per estimator with fixed
seeds, the variance of their difference (an unbiased estimate of twice a render's noise variance, whatever the
field's bias), and marched when var(forced) / var(marched) > :func:`cost_ratio`. The choice is kept in the scene's
cache (``"camera_estimator"``), keyed by g, the NEE's light sampling, the estimator's type and the pixel's size
(its angle, in half-octave classes: a pixel's own variation is part of the noise both estimators share), so a
camera move or a progressive render's next frame do not probe again; a viewer's smaller frames while dragging probe
once for their size, and a transfer-function or light edit (a new scene) probes anew. A render of fewer samples
than one probe render's rays (a 16x16 still, a thumbnail) is not worth four of them: it takes forced, the estimator
without a light volume, unless the scene's choice was made already.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.light_volume import LightVolume
from photon_fields.runtime.wavefront.first_interaction import IndirectEstimator, render_first_interaction

AUTO = "auto"
#: The estimators auto chooses between (:func:`choose_camera_estimator`); a caller that times a render compiles both
#: first (``pfn-demo``: the probe may take either, and an estimator's first use compiles its kernels).
AUTO_CHOICES = ("forced", "marched")
PROBE_RAYS = 8192
COST_RATIO = 3.5
COST_RESOLUTION = 96.0
COST_EXPONENT = 0.3
#: The probe renders' seeds (each estimator renders the band with both; fixed, so the choice is reproducible).
PROBE_SEEDS = (7919, 7920)


def probe_band(scene: Scene, rays: int = PROBE_RAYS) -> Scene:
    """``scene`` with its camera cut to the band of whole rows across the image's middle that holds about ``rays``
    pixels (the whole image if it has fewer): the same eye, direction and pixel size, so each of its rays is one of
    the full camera's middle rows' (up to rounding)."""
    cam = scene.camera
    rows = min(cam.height, max(1, math.ceil(rays / cam.width)))
    if rows == cam.height:
        return scene
    aspect = cam.width / cam.height
    half = math.tan(math.radians(cam.fov) * 0.5)
    half_w = half * aspect if cam.fov_axis == "y" else half
    band = replace(cam, fov=math.degrees(2.0 * math.atan(half_w)), fov_axis="x", height=rows)
    return scene.with_overrides(camera=band)


def cost_ratio(scene: Scene) -> float:
    """The marched estimator's modelled time per sample over the forced one's on ``scene``'s volume (module
    docstring): :data:`COST_RATIO` up to :data:`COST_RESOLUTION` voxels across the box's longest side (in its
    smallest voxel edge), growing as that count to the power :data:`COST_EXPONENT` beyond."""
    across = 1.0 / float(scene.volume.voxel_size)
    return COST_RATIO * max(1.0, across / COST_RESOLUTION) ** COST_EXPONENT


def pixel_class(scene: Scene) -> int:
    """The camera's pixel size as a class of half an octave: round(2 log2(the pixel's angle))."""
    _, _, dv = scene.camera.image_plane()
    return round(2.0 * math.log2(float(np.linalg.norm(dv))))


def noise_variance(scene: Scene, estimator: IndirectEstimator | None, camera: str, light_volume: LightVolume | None,
                   light_sampling: str) -> float:
    """Half the summed squared difference of two 1-spp renders of ``scene`` with ``camera`` (seeds
    :data:`PROBE_SEEDS`): an unbiased estimate of one render's noise variance, summed over pixels and channels."""
    a, b = (render_first_interaction(scene, estimator, spp=1, seed=seed, progress=False, camera=camera,
                                     light_sampling=light_sampling,
                                     light_volume=light_volume).layers["L"].astype(np.float64)
            for seed in PROBE_SEEDS)
    return 0.5 * float(np.sum((a - b) ** 2))


def _key(scene: Scene, estimator: IndirectEstimator | None, light_sampling: str) -> tuple:
    """The cache key of a choice (module docstring)."""
    return round(float(scene.g), 9), light_sampling, type(estimator).__name__, pixel_class(scene)


def made_choice(scene: Scene, estimator: IndirectEstimator | None, light_sampling: str) -> str | None:
    """The choice auto has made for this scene, g, light sampling, estimator type and pixel class, or None when it
    has not probed yet (a viewer's first frame of a scene renders forced rather than wait for the probe)."""
    return scene.shared_cache("camera_estimator").get(_key(scene, estimator, light_sampling))


def choose_camera_estimator(scene: Scene, estimator: IndirectEstimator | None,
                            light_volume: Callable[[], LightVolume], light_sampling: str, samples: int) -> str:
    """"forced" or "marched" for ``scene`` (module docstring), probed on :func:`probe_band` once per g, light
    sampling, estimator type and pixel class and kept in the scene's cache; for a render of fewer than
    :data:`PROBE_RAYS` ``samples`` without a choice made, "forced" unprobed. ``light_volume``: gives the marched
    estimator's (the scene's, ``ray_marcher.camera_light_volume``), asked only for a probe, which fills the cells its
    rays read (the render then finds them filled)."""
    key = _key(scene, estimator, light_sampling)
    choices = scene.shared_cache("camera_estimator")
    if key not in choices and samples < PROBE_RAYS:
        return "forced"
    if key not in choices:
        band = probe_band(scene)
        forced = noise_variance(band, estimator, "forced", None, light_sampling)
        marched = noise_variance(band, estimator, "marched", light_volume(), light_sampling)
        choices[key] = "marched" if forced > cost_ratio(scene) * marched else "forced"
    return choices[key]


def resolve_camera_estimator(scene: Scene, estimator: IndirectEstimator | None, camera: str,
                             light_volume: Callable[[], LightVolume], light_sampling: str, spp: int) -> str:
    """``camera`` itself, or for :data:`AUTO` the choice of :func:`choose_camera_estimator` for a render of
    ``spp`` samples per pixel of ``scene``'s camera (``light_volume`` gives the scene's, for the probe)."""
    if camera != AUTO:
        return camera
    samples = scene.camera.width * scene.camera.height * spp
    return choose_camera_estimator(scene, estimator, light_volume, light_sampling, samples)
