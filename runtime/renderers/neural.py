"""The neural wavefront renderer (paper Alg. 2, Sec. 3.6): global illumination from a trained photon field.

Stages (each timed under its own name in ``RenderResult.timings_ms``; code in
:mod:`runtime.wavefront.first_interaction`, shared with the photon-map renderer so the two differ only in stage 3):

1. ``sample_first_interactions``: one jittered camera ray per (pixel, sample) work item, clipped to the
   volume box and delta-tracked to its first interaction, in one fused numba pass; rays that miss the box
   or leave it without an interaction leave a hole (and add the environment to L_e);
2. ``compact``: holes are removed before anything reaches the field;
3. ``estimate_indirect``: the field :class:`photon_fields.runtime.field.field.PhotonField` predicts Q(x, d, g) at every
   interaction (hash encoding, batched onnxruntime inference, Eq. 7 decode), at the render's g, which may
   be any value in [-1, 1]: the field interpolates between the phases G it was trained on;
4. ``estimate_direct``: next-event estimation with ratio-tracked shadow rays to every light;
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
  result after n frames equals one render with n * spp, sample for sample);
- :func:`render_orbit`: a fly-around of N frames orbiting the volume, written to numbered files, with
  per-frame timings (the paper's 2000-frame timing protocol in miniature).

Performance (paper Table 2 on this machine, 512x512, 1 spp, max path length 16): 2 cores with a training job
keeping ~1 of them busy throughout (``other_cores`` 1.0-1.1), so each figure is what about one free core does.
``bench/bench_render.py``'s protocol (warm-up, best of 3 renders), run in 3 processes per code version,
alternating with the code before this section's changes; the figures are the minima.
``.venv/bin/python bench/bench_render.py --scenes vortex blobs shell --no-hd`` agrees within its noise:

=======  ===========================  ==========================  ===========================
scene    neural L_d / L_i / L (s)     path tracer L_d / L (s)     speedup L_d / L_i / L
=======  ===========================  ==========================  ===========================
vortex   0.225 / 0.203 / 0.249        0.220 / 0.382               1.0 / 1.9 / 1.5
blobs    0.295 / 0.261 / 0.410        0.324 / 1.400               1.1 / 5.4 / 3.4
shell    0.355 / 0.338 / 0.408        0.361 / 0.943               1.0 / 2.8 / 2.3
=======  ===========================  ==========================  ===========================

(before: vortex L 0.301, blobs 0.455, shell 0.397 s; the fusion of stages 1-2 and the film's numba splat and
read-out saved 20-50 ms per frame, within the machine's run-to-run noise of ~10 % for shell.) Per-stage ms of
the fastest vortex / blobs frame: sample_first_interactions 178 / 173, compact 1 / 4, estimate_indirect 26 / 85
(encode position 12 / 33, direction 4 / 10, onnxruntime 9 / 33, decode 1 / 4), estimate_direct 29 / 131,
compose 1 / 2; the film's allocation and read-out add ~15 ms outside ``total``. Of the issue's goals, the
0.25 s frame is met by vortex's best frames only (blobs and shell ~0.41 s), and L_i >= 15x, L >= 5x are out
of reach here for a structural reason: delta tracking every camera
ray to its first interaction is 55-75 % of the frame, and it is the path tracer's first bounce, the same
kernel and the same random numbers (the layers must agree bit for bit), so the neural renderer can only
save the path tracer's later bounces: L_i is bounded by (path tracer L) / (first-interaction stage), ~2x
(vortex, where 89 % of the in-box rays escape) to ~8x (blobs). 1 and 2 numba / onnxruntime threads measured
equal here, the second core being taken; an idle machine was not available to measure.

Memory: work is processed in batches of ``batch_size`` work items (default 2^18): the first interactions, the
field's input buffer (chunked again inside the field) and the film (3 layers x 3 float64 per pixel) bound
it, so a 1280x720, 16 spp render needs a few hundred MB whatever the spp.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.io.atomic import atomic_write_text
from photon_fields.runtime.scene.camera import orbit_camera
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.wavefront.batches import DEFAULT_BATCH, RenderResult
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.first_interaction import IndirectEstimator, render_first_interaction


def render_neural(scene: Scene, estimator: IndirectEstimator | None, *, spp: int = 1, seed: int = 0,
                  batch_size: int = DEFAULT_BATCH, progress: bool = True, direct: bool = True,
                  film: Film | None = None, first_sample: int = 0) -> RenderResult:
    """Alg. 2 with ``estimator`` (normally ``PhotonField.estimator()``) for L_i; see the module docstring.
    ``estimator=None`` renders L_d only, ``direct=False`` L_i only (for timing the terms separately)."""
    stats_before = _field_seconds(estimator)
    result = render_first_interaction(scene, estimator, spp=spp, seed=seed, batch_size=batch_size, progress=progress,
                                      desc="neural rendering", direct=direct, film=film, first_sample=first_sample)
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
    frame's timings; ``samples`` is the samples per pixel accumulated."""

    def __init__(self, scene: Scene, estimator: IndirectEstimator | None, *, spp: int = 1, seed: int = 0,
                 batch_size: int = DEFAULT_BATCH) -> None:
        self.scene, self.estimator, self.spp, self.seed, self.batch_size = scene, estimator, int(spp), seed, batch_size
        self.film = Film(scene.camera.width, scene.camera.height)
        self.frames = 0

    @property
    def samples(self) -> int:
        return self.film.samples

    def frame(self) -> RenderResult:
        result = render_neural(self.scene, self.estimator, spp=self.spp, seed=self.seed, batch_size=self.batch_size,
                               progress=False, film=self.film, first_sample=self.film.samples)
        self.frames += 1
        return result


def orbit_frame_paths(out: Path, frames: int) -> list[Path]:
    """``dir/name.exr`` -> ``dir/name_0000.exr`` ... for ``frames`` frames."""
    width = max(4, len(str(frames - 1)))
    return [out.with_name(f"{out.stem}_{i:0{width}d}{out.suffix}") for i in range(frames)]


def orbit_timings_path(out: Path) -> Path:
    """``dir/name.exr`` -> ``dir/name_timings.json``, the orbit's timings and exposure."""
    return out.with_name(f"{out.stem}_timings.json")


def render_orbit(scene: Scene, estimator: IndirectEstimator | None, out: Path, *, frames: int, spp: int = 1,
                 seed: int = 0, batch_size: int = DEFAULT_BATCH, degrees: float = 360.0, exposure: float | None = None,
                 progress: bool = True) -> dict[str, Any]:
    """Render ``frames`` views orbiting the scene camera's target by ``degrees`` in all, each to a numbered
    EXR + PNG beside ``out``; the exposure of the first frame is kept for all (no flicker). Returns and
    writes (``<out stem>_timings.json``) per-frame wall times and their mean / median / 95th percentile."""
    from tqdm import tqdm

    from photon_fields.runtime.io.images import auto_exposure_stops, write_image_set

    paths = orbit_frame_paths(out, frames)
    walls: list[float] = []
    stages: dict[str, float] = {}
    for i in tqdm(range(frames), desc="orbit", unit="frame", disable=not progress, leave=False):
        cam = orbit_camera(scene.camera, degrees * i / frames)
        t0 = time.perf_counter()
        result = render_neural(scene.with_overrides(camera=cam), estimator, spp=spp, seed=seed,
                               batch_size=batch_size, progress=False)
        walls.append(time.perf_counter() - t0)
        for k, v in result.timings_ms.items():
            stages[k] = stages.get(k, 0.0) + v
        if exposure is None:
            exposure = auto_exposure_stops(result.layers["L"])
        write_image_set(paths[i], result.layers, metadata={"photon_fields.frame": str(i)}, exposure=exposure)
    w = np.asarray(walls)
    summary = {"frames": frames, "spp": spp, "size": [scene.camera.width, scene.camera.height], "degrees": degrees,
               "exposure_stops": exposure, "frame_s": walls, "mean_s": float(w.mean()), "median_s": float(np.median(w)),
               "p95_s": float(np.percentile(w, 95)), "fps": float(1.0 / w.mean()),
               "stage_ms_per_frame": {k: v / frames for k, v in stages.items()},
               "files": [str(p) for p in paths]}
    timing_path = orbit_timings_path(out)
    atomic_write_text(timing_path, json.dumps(summary, indent=2) + "\n")
    summary["timings_file"] = str(timing_path)
    return summary
