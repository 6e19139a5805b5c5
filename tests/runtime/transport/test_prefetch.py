"""runtime/prefetch.py and its use by the marches: a prefetch changes no value, the ray marcher's and the marched
estimator's images are the same bit for bit with and without it, and only volumes past the threshold prefetch."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from photon_fields.runtime.prefetch import prefetch3
from photon_fields.runtime.renderers import ray_marcher
from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
from photon_fields.runtime.scene.scene import builtin_scene
from photon_fields.runtime.transport.medium import PREFETCH_MIN_BYTES, worth_prefetching
from photon_fields.runtime.wavefront import marched_camera


@njit(cache=True)
def _sum_with_prefetches(a: np.ndarray) -> float:
    s = 0.0
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            for k in range(a.shape[2]):
                prefetch3(a, min(i + 1, a.shape[0] - 1), j, k)
                s += a[i, j, k].sum() if a.ndim == 4 else a[i, j, k]
    return s


@pytest.mark.parametrize("shape", [(5, 4, 3), (5, 4, 3, 2)])
def test_a_prefetch_changes_nothing(shape: tuple[int, ...]) -> None:
    """The intrinsic compiles for 3- and 4-D arrays (a light volume's cells hold every light) and leaves the values
    as they are."""
    a = np.arange(np.prod(shape), dtype=np.float32).reshape(shape)
    before = a.copy()
    assert _sum_with_prefetches(a) == pytest.approx(float(before.astype(np.float64).sum()), rel=1e-12)
    assert np.array_equal(a, before)


def test_only_volumes_past_the_threshold_prefetch() -> None:
    """Small volumes stay in the caches, where prefetching only costs: the embedded 96^3 scenes do not prefetch, a
    256^3 one does."""
    assert not worth_prefetching(builtin_scene("vortex").medium())
    big = builtin_scene("vortex", 256).medium()
    assert big.density.nbytes >= PREFETCH_MIN_BYTES and worth_prefetching(big)


@pytest.mark.parametrize("on", [True, False])
def test_the_marches_give_the_same_images_with_and_without_prefetching(on: bool,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """The preview and the marched camera estimator (L_d, no field) render a small volume with prefetching forced on
    or off: both agree with the render at the volume's own setting (off, at this size) bit for bit."""
    scene = builtin_scene("blobs", 48).with_overrides(width=40, height=40)
    reference = {"preview": render_ray_marched(scene, progress=False).layers["L"],
                 "marched": render_neural(scene, None, spp=2, seed=3, camera="marched", progress=False).layers["L"]}
    monkeypatch.setattr(ray_marcher, "worth_prefetching", lambda m: on)
    monkeypatch.setattr(marched_camera, "worth_prefetching", lambda m: on)
    scene = builtin_scene("blobs", 48).with_overrides(width=40, height=40)  # fresh caches: the light volume refilled
    assert np.array_equal(render_ray_marched(scene, progress=False).layers["L"], reference["preview"])
    marched = render_neural(scene, None, spp=2, seed=3, camera="marched", progress=False).layers["L"]
    assert np.array_equal(marched, reference["marched"])
    assert float(reference["preview"].mean()) > 0.0 and float(reference["marched"].mean()) > 0.0
