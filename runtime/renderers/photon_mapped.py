"""The photon-mapping renderer, the paper's baseline: first interactions + NEE + the photon-map estimate of L_i.

The same wavefront as the neural renderer (:mod:`photon_fields.runtime.wavefront.first_interaction`), with the
photon map's Eq. 5 estimate (:class:`photon_fields.runtime.photons.estimate.PhotonMapEstimator`) in the place of
the field, so the two differ only in where L_i comes from.
"""

from __future__ import annotations

import numpy as np

from photon_fields.runtime.photons.estimate import (
    DEFAULT_K,
    DEFAULT_RADIUS,
    PhotonMapEstimator,
    check_map_matches_scene,
)
from photon_fields.runtime.photons.phase_window import answerable, map_window
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.renderers.ray_marcher import camera_estimator_for
from photon_fields.runtime.renderers.registry import DEFAULT_GATHER_AFTER
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.wavefront.batches import DEFAULT_BATCH, RenderResult
from photon_fields.runtime.wavefront.camera_choice import AUTO
from photon_fields.runtime.wavefront.first_interaction import (
    DEFAULT_LIGHT_SAMPLING,
    render_first_interaction,
)


def render_photon_mapped(scene: Scene, pmap: PhotonMap, *, k: int = DEFAULT_K, radius: float = DEFAULT_RADIUS,
                         spp: int = 1, seed: int = 0, batch_size: int = DEFAULT_BATCH, progress: bool = True,
                         force: bool = False, g_window: float | str | None = "auto",
                         camera: str = AUTO,
                         final_gather_after: int | None = DEFAULT_GATHER_AFTER,
                         light_sampling: str = DEFAULT_LIGHT_SAMPLING) -> RenderResult:
    """Render ``scene`` with L_i from ``pmap`` (K nearest photons within ``radius`` of each first interaction),
    ``spp`` samples per pixel; layers L, L_d, L_i, L_e and ``stats`` on how many photons were found. A map
    traced for another scene is refused unless ``force``. The scene's g must be one of the map's phases or, read
    with a kernel in g of half-width ``g_window`` (:mod:`photon_fields.runtime.photons.phase_window`; "auto":
    for a map traced in narrow phase bins), have a bin within it. ``camera``: how first interactions are sampled
    (``first_interaction.CAMERA_ESTIMATORS``, or "auto", :mod:`photon_fields.runtime.wavefront.camera_choice`);
    samples from index ``final_gather_after`` on (None: none) take one real bounce before the map's estimate
    (:mod:`photon_fields.runtime.wavefront.final_gather`, Jensen's final gathering); ``light_sampling``: NEE to
    one light per sample or to all (``first_interaction.LIGHT_SAMPLINGS``)."""
    check_map_matches_scene(pmap, scene, force)
    window = map_window(pmap.phases, g_window)
    answerable(pmap.phases, scene.g, window)  # fail before rendering if g cannot be answered
    est = PhotonMapEstimator(pmap, scene.medium(), k=k, radius=radius, g_window=window)
    camera, light_volume = camera_estimator_for(scene, est, camera, light_sampling, spp)
    result = render_first_interaction(scene, est, spp=spp, seed=seed, batch_size=batch_size, progress=progress,
                                      desc="photon mapping", camera=camera, final_gather_after=final_gather_after,
                                      light_sampling=light_sampling, light_volume=light_volume)
    result.stats["camera_estimator"] = camera
    if est.found:
        found = np.concatenate(est.found)
        result.stats.update({"k_mean_found": float(found.mean()), "k_saturated": float(np.mean(found >= k))})
    return result
