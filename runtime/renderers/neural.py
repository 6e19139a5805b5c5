"""The neural wavefront renderer (paper Alg. 2, Sec. 3.6): global illumination from a trained photon field.

Stages (each timed under its own name in ``RenderResult.timings_ms``; code in
:mod:`runtime.wavefront.first_interaction`, shared with the photon-map renderer so the two differ only in stage 3):

1. ``sample_first_interactions``: one jittered camera ray per (pixel, sample) work item, clipped to the
   volume box and tracked to its first interaction by the camera estimator ("forced" by default: a
   collision resampled from the whole ray, weighted by the ray's collision probability; "delta": the path
   tracer's delta tracking), in one fused numba pass; rays that miss the box or leave it without an
   interaction leave a hole (and add the environment to L_e);
2. ``compact``: holes are removed before anything reaches the field;
3. ``estimate_indirect``: the field :class:`photon_fields.runtime.field.field.PhotonField` predicts Q(x, d, g) at every
   interaction (hash encoding, batched onnxruntime inference, Eq. 7 decode), at the render's g, which may
   be any value in [-1, 1]: the field interpolates between the phases G it was trained on;
4. ``estimate_direct``: next-event estimation with ratio-tracked shadow rays, to one light per sample drawn by its
   unshadowed contribution (``light_sampling="one"``, the default) or to every light ("all");
5. ``compose``: per sample ``L_d = a(x) NEE(x)`` and ``L_i = a(x) Q(x, d, g)``, averaged over spp.

The estimator (Sec. 3.6's ``L = 1/spp sum (w_d L_d + w_i sigma_s L_i^pred)``): the paper's sigma_s becomes
the albedo a = sigma_s / sigma_t because delta tracking samples the first interaction with pdf
sigma_t T, whose 1 / sigma_t leaves sigma_s / sigma_t; both MIS weights are 1 because the two terms
estimate *disjoint* path sets: L_d the paths whose only scattering vertex is x (estimated by NEE alone),
L_i those with at least one more vertex (estimated by the field alone, which was trained on photons
stored from their second collision). That is exactly the reference path tracer's split of its paths
into its L_d and L_i layers (:mod:`runtime.renderers.path_tracer`), which is why the layers are compared one to one
(``tests/runtime/renderers/test_neural_renderer.py``). MIS is only needed where two strategies estimate the same
paths, as
NEE and phase sampling do for an environment light inside the path tracer; here the environment is
reached by NEE alone (the paper's renderer does the same).

APIs:

- :func:`render_neural`: one image (``spp`` samples per pixel), layers L, L_d, L_i, L_e;
- :class:`ProgressiveRender`: the same camera frame after frame, each adding ``spp`` new samples (the
  result after n frames equals one render with n * spp, sample for sample).

Fly-around sequences of any renderer are :mod:`photon_fields.runtime.renderers.orbit`.

Why it is faster than the path tracer, and by how much at most: it saves the path tracer's later bounces
only. Tracking every camera ray to its first interaction is the path tracer's first bounce (with the "delta"
camera estimator the same kernel and the same random numbers: the layers agree bit for bit), so L_i can be
at most (path tracer L) / (first-interaction stage) times faster. ``bench/bench_render.py`` measures it
(bench/README.md).

Memory: work is processed in batches of ``batch_size`` work items (default 2^18): the first interactions, the
field's input buffer (chunked again inside the field) and the film (3 layers x 3 float64 per pixel) bound
it, so a 1280x720, 16 spp render needs a few hundred MB whatever the spp.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from photon_fields.runtime.renderers.ray_marcher import camera_estimator_for
from photon_fields.runtime.renderers.registry import DEFAULT_GATHER_AFTER
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.wavefront.batches import DEFAULT_BATCH, RenderResult
from photon_fields.runtime.wavefront.camera_choice import AUTO
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.first_interaction import (
    DEFAULT_LIGHT_SAMPLING,
    IndirectEstimator,
    render_first_interaction,
)


def render_neural(scene: Scene, estimator: IndirectEstimator | None, *, spp: int = 1, seed: int = 0,
                  batch_size: int = DEFAULT_BATCH, progress: bool = True, direct: bool = True,
                  film: Film | None = None, first_sample: int = 0,
                  camera: str = AUTO,
                  final_gather_after: int | None = DEFAULT_GATHER_AFTER,
                  cancel: Callable[[], bool] | None = None,
                  light_sampling: str = DEFAULT_LIGHT_SAMPLING) -> RenderResult:
    """Alg. 2 with ``estimator`` (normally ``PhotonField.estimator()``) for L_i; see the module docstring.
    ``estimator=None`` renders L_d only, ``direct=False`` L_i only (for timing the terms separately).
    ``camera`` picks how first interactions are sampled (``first_interaction.CAMERA_ESTIMATORS``, or "auto": the
    forced or the marched one, whichever has less noise per unit of work on this scene,
    :mod:`photon_fields.runtime.wavefront.camera_choice`; ``stats["camera_estimator"]`` names the one used),
    ``light_sampling`` how NEE treats several lights (``first_interaction.LIGHT_SAMPLINGS``).
    Samples from index ``final_gather_after`` on (counting ``first_sample``'s; 0: all, None: none) take one real
    bounce before the field (:mod:`photon_fields.runtime.wavefront.final_gather`: the field's bias reaches the image
    attenuated and blurred, at about 1.5x the work per sample): a render of many samples converges to the less
    biased image while one of few stays plain (its noise is larger than the bias the gather removes).
    ``cancel``: asked before each batch; True stops the render with
    :class:`photon_fields.runtime.wavefront.batches.RenderCancelledError`."""
    camera, light_volume = camera_estimator_for(scene, estimator, camera, light_sampling, spp)
    stats_before = _field_seconds(estimator)
    result = render_first_interaction(scene, estimator, spp=spp, seed=seed, batch_size=batch_size, progress=progress,
                                      desc="neural rendering", direct=direct, film=film, first_sample=first_sample,
                                      camera=camera, final_gather_after=final_gather_after, cancel=cancel,
                                      light_sampling=light_sampling, light_volume=light_volume)
    result.stats["camera_estimator"] = camera
    after = _field_seconds(estimator)
    for key, value in after.items():  # the field's own split of stage 4: encoding / inference / decoding
        result.timings_ms[f"estimate_indirect.{key}"] = (value - stats_before.get(key, 0.0)) * 1e3
    return result


def _field_seconds(estimator: Any) -> dict[str, float]:
    """A field estimator's accumulated stage seconds (``runtime.field.field.FieldTimers``), else nothing."""
    timers = getattr(getattr(estimator, "field", None), "timers", None)
    if timers is None:
        return {}
    return {k.removesuffix("_s"): float(v) for k, v in timers.to_dict().items() if k.endswith("_s") and k != "total_s"}


class ProgressiveRender:
    """Accumulates frames of one camera: frame n adds ``spp`` samples per pixel to the same film.

    ``frame()`` returns the accumulated image so far (layers are means over all samples) with the new
    frame's timings; ``samples`` is the samples per pixel accumulated.

    ``denoiser``: a temporal denoiser for this camera's frames
    (:class:`photon_fields.runtime.denoise.wrls.WRLSDenoiser`), fed the *accumulated* L after every frame (its
    noise keeps falling, and the output with it; fed each frame's new samples alone it would stop at its
    feature's noise floor). The result's ``L`` is then the denoised image, ``L_noisy`` the accumulation, and
    ``timings_ms["denoise"]`` the denoiser's time; the other layers stay the accumulation's."""

    def __init__(self, scene: Scene, estimator: IndirectEstimator | None, *, spp: int = 1, seed: int = 0,
                 batch_size: int = DEFAULT_BATCH, camera: str = AUTO,
                 denoiser: Any = None, final_gather_after: int | None = DEFAULT_GATHER_AFTER,
                 light_sampling: str = DEFAULT_LIGHT_SAMPLING) -> None:
        self.scene, self.estimator, self.spp, self.seed, self.batch_size = scene, estimator, int(spp), seed, batch_size
        self.camera, self.final_gather_after, self.light_sampling = camera, final_gather_after, light_sampling
        self.film = Film(scene.camera.width, scene.camera.height)
        self.frames = 0
        self.denoiser = denoiser
        if denoiser is not None:
            denoiser.reset()

    @property
    def samples(self) -> int:
        return self.film.samples

    def frame(self) -> RenderResult:
        result = render_neural(self.scene, self.estimator, spp=self.spp, seed=self.seed, batch_size=self.batch_size,
                               progress=False, film=self.film, first_sample=self.film.samples, camera=self.camera,
                               final_gather_after=self.final_gather_after, light_sampling=self.light_sampling)
        self.frames += 1
        if self.denoiser is not None:
            t0 = time.perf_counter()
            noisy = result.layers["L"]
            result.layers = {"L": self.denoiser.denoise(noisy, camera=self.scene.camera), "L_noisy": noisy,
                             **{k: v for k, v in result.layers.items() if k != "L"}}
            result.timings_ms["denoise"] = (time.perf_counter() - t0) * 1e3
        return result
