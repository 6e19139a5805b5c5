"""Judging a trained field by the images it makes (paper Sec. 4.2, Fig. 8 / 10).

:class:`TorchFieldEstimator` puts a torch :class:`train.field.network.TorchPhotonField` behind the runtime's
:class:`runtime.wavefront.first_interaction.IndirectEstimator` interface, so the field renders through exactly the
code path (Alg. 2 stages, same random streams) that the photon-map renderer uses. Rendered with the same
seed, the two renderers see *identical* first interactions; the only difference between their L_i
images is the estimate Q(x, d, g) at those points: field versus photon map (Eq. 5). That is the error
:func:`evaluate_field` reports, per held-out view and per g:

- relative L2 of the linear L_i images (:func:`photon_fields.runtime.eval.metrics.relative_l2`);
- SSIM after tone mapping both with the photon-map image's exposure (:func:`photon_fields.runtime.eval.metrics.ssim`).

For g in the training set G the reference is the training map itself (what the field was fitted to);
for g outside G (the paper's Fig. 10: -0.35, 0.35) it is a separate map traced at those g, with as many
photons per phase as the training map has (:func:`reference_maps`), so the field's interpolation across
g is judged against ground truth of the same photon density. That independent map carries its own
noise (two independent 1M-photon maps differ by ~0.13-0.15 relative L1 on vortex and blobs), which the
training map's score does not see: pass it also as ``independent`` (traced at G too) to score g in G
against it (``*_in_G_independent``), the like-for-like partner of the outside-G score.

Held-out views: :func:`held_out_cameras` orbits the scene camera about its target by angles that training
never sees (training draws points and directions, not views; "held out" means these views are not used
to choose anything else either).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from photon_fields.models_spec.encoding import direction_input, normalize_position
from photon_fields.runtime.eval.metrics import relative_l2, ssim
from photon_fields.runtime.photons.estimate import DEFAULT_K, DEFAULT_RADIUS
from photon_fields.runtime.photons.photon_map import PhotonMap, find_phase
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped
from photon_fields.runtime.scene.camera import Camera, orbit_camera
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.medium import Medium
from photon_fields.runtime.wavefront.first_interaction import render_first_interaction
from photon_fields.train.field.network import TorchPhotonField
from photon_fields.train.photons.tracing import trace_photons

HELD_OUT_ANGLES = (35.0, 160.0)  # degrees about the camera's up axis; neither is the scene camera's view
OUTSIDE_G = (-0.35, 0.35)  # Fig. 10's phase values that are not in the default G


class TorchFieldEstimator:
    """Q(x, d, g) from a torch photon field (decoded with Eq. 7), in chunks, without gradients; ``light_scale``: as
    :meth:`photon_fields.runtime.field.field.PhotonField.query`'s (RGB (3,), or (C, 3) one factor per light channel)."""

    def __init__(self, model: TorchPhotonField, medium: Medium, chunk: int = 1 << 15,
                 light_scale: np.ndarray | None = None) -> None:
        self.model, self.medium, self.chunk = model.eval(), medium, int(chunk)
        self.factors = None if light_scale is None else torch.from_numpy(np.asarray(light_scale, np.float32))
        self.seconds = 0.0
        self.queries = 0

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        t0 = time.perf_counter()
        n = x.shape[1]
        pos = normalize_position(x.T, self.medium.bmin, self.medium.bsize)
        dirs = direction_input(np.ascontiguousarray(d.T))
        out = np.empty((3, n))
        with torch.no_grad():
            for a in range(0, n, self.chunk):
                b = min(n, a + self.chunk)
                gg = torch.full((b - a, 1), float(g), dtype=torch.float32)
                q = self.model.radiance(torch.from_numpy(pos[a:b]), torch.from_numpy(dirs[a:b]), gg, self.factors)
                out[:, a:b] = q.numpy().T
        self.seconds += time.perf_counter() - t0
        self.queries += n
        return out


def held_out_cameras(scene: Scene, size: int, angles: tuple[float, ...] = HELD_OUT_ANGLES) -> list[Camera]:
    """The scene camera orbited by ``angles`` (degrees), at ``size`` x ``size`` pixels."""
    return [orbit_camera(scene.camera, a).with_resolution(size, size) for a in angles]


def reference_maps(scene: Scene, train_map: PhotonMap, gs: tuple[float, ...] = OUTSIDE_G, *, seed: int = 1,
                   progress: bool = False) -> PhotonMap:
    """A map traced at ``gs`` with the training map's photons per phase (another seed: independent noise)."""
    per_phase = len(train_map) // len(train_map.phases)
    return trace_photons(scene, per_phase * len(gs), phases=list(gs), seed=seed, progress=progress)


def map_at_g(scene: Scene, train_map: PhotonMap, g: float, *, seed: int = 1, progress: bool = False) -> PhotonMap:
    """A map that answers the photon-map estimate at ``g``: the training map if g is in its phase set, else
    a map traced at g alone with as many photons as one training phase (:func:`reference_maps`). The field
    interpolates between phases; a photon map cannot."""
    if find_phase(train_map.phases, g) is not None:
        return train_map
    return reference_maps(scene, train_map, (g,), seed=seed, progress=progress)


@dataclass
class ViewScore:
    view: int
    g: float
    rel_l2: float
    ssim: float
    field_s: float
    photon_map_s: float

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def evaluate_field(scene: Scene, model: TorchPhotonField, maps: list[PhotonMap], gs: tuple[float, ...], *,
                   size: int = 128, spp: int = 2, seed: int = 7, k: int = DEFAULT_K, radius: float = DEFAULT_RADIUS,
                   cameras: list[Camera] | None = None, cache: dict[Any, Any] | None = None,
                   independent: PhotonMap | None = None) -> dict[str, Any]:
    """Field L_i versus photon-map L_i on held-out views for every g in ``gs`` (each g must be in one of
    ``maps``); returns per-view scores and their means over views, per g and overall. ``cache`` (a dict
    the caller keeps) holds the photon-map images between calls with the same maps and settings."""
    cache = {} if cache is None else cache
    result = _scores(scene, model, maps, gs, size, spp, seed, k, radius, cameras, cache)
    if independent is not None:
        in_g = tuple(g for g in gs if find_phase(model.cfg.phases, g) is not None)
        indep = _scores(scene, model, [independent], in_g, size, spp, seed, k, radius, cameras, cache)
        result["rel_l2_in_G_independent"] = indep["rel_l2_in_G"]
        result["ssim_in_G_independent"] = indep["ssim_in_G"]
    return result


def _scores(scene: Scene, model: TorchPhotonField, maps: list[PhotonMap], gs: tuple[float, ...], size: int, spp: int,
            seed: int, k: int, radius: float, cameras: list[Camera] | None, cache: dict[Any, Any]) -> dict[str, Any]:
    cams = cameras if cameras is not None else held_out_cameras(scene, size)
    est = TorchFieldEstimator(model, scene.medium())
    scores: list[ViewScore] = []
    for g in gs:
        pmap = next((m for m in maps if find_phase(m.phases, g) is not None), None)
        if pmap is None:
            raise ValueError(f"no reference map was traced at g = {g}")
        for v, cam in enumerate(cams):
            sc = scene.with_overrides(g=g, camera=cam)
            key = (id(pmap), v, float(g), cam.width, cam.height, spp, seed, k, radius)
            if key not in cache:
                t0 = time.perf_counter()
                ref = render_photon_mapped(sc, pmap, k=k, radius=radius, spp=spp, seed=seed, progress=False,
                                           final_gather_after=None, camera="forced")  # the field's samples below
                cache[key] = (ref, time.perf_counter() - t0)
            ref, ref_s = cache[key]
            t1 = time.perf_counter()
            img = render_first_interaction(sc, est, spp=spp, seed=seed, progress=False,
                                           final_gather_after=None)
            t2 = time.perf_counter()
            scores.append(ViewScore(v, float(g), relative_l2(img.layers["L_i"], ref.layers["L_i"]),
                                    ssim(img.layers["L_i"], ref.layers["L_i"]), t2 - t1, ref_s))
    per_g = {f"{g:g}": {"rel_l2": float(np.mean([s.rel_l2 for s in scores if s.g == g])),
                        "ssim": float(np.mean([s.ssim for s in scores if s.g == g]))} for g in gs}
    in_g = [s for s in scores if find_phase(model.cfg.phases, s.g) is not None]
    out_g = [s for s in scores if s not in in_g]

    def mean(sel: list[ViewScore], key: str) -> float | None:
        return float(np.mean([getattr(s, key) for s in sel])) if sel else None

    return {"views": len(cams), "size": [cams[0].width, cams[0].height], "spp": spp, "seed": seed, "k": k,
            "radius": radius, "per_view": [s.to_dict() for s in scores], "per_g": per_g,
            "rel_l2_in_G": mean(in_g, "rel_l2"), "ssim_in_G": mean(in_g, "ssim"),
            "rel_l2_outside_G": mean(out_g, "rel_l2"), "ssim_outside_G": mean(out_g, "ssim")}
