"""The ray marcher's empty-space skipping (runtime/renderers/ray_marcher.py, ``skip_empty``): camera and shadow
rays look nothing up where the majorant grid says the medium is empty, and the image is the same, bit for bit,
as the marcher that looks up every sample; on a sparse scene it does far fewer lookups.

(The marcher against the path tracer's single scattering: tests/runtime/renderers/test_path_tracer.py.)"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import small_camera

from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
from photon_fields.runtime.scene.lights import DirectionalLight, PointLight
from photon_fields.runtime.scene.scene import Scene, builtin_scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.tracking import empty_run


def _sparse_scene() -> Scene:
    """Two small dense blobs in a mostly empty box, a directional and a point light."""
    n = 40
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    field = (np.exp(-((X - 0.3) ** 2 + (Y - 0.4) ** 2 + (Z - 0.5) ** 2) / 0.004)
             + np.exp(-((X - 0.7) ** 2 + (Y - 0.6) ** 2 + (Z - 0.4) ** 2) / 0.006))
    tf = TransferFunction(np.array([0.0, 0.2, 1.0]), np.array([[0.9, 0.8, 0.7]] * 3), np.array([0.0, 0.0, 1.0]),
                          30.0, "sparse")
    lights = (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.9, 0.8], 2.0), PointLight([0.9, 0.8, 0.9], [1.0, 1.0, 1.0],
                                                                                     0.5))
    return Scene(make_volume(np.clip(field, 0, 1), window=(0.0, 1.0), name="two_blobs"), tf, lights,
                 small_camera(32), 0.3, "sparse")


@pytest.mark.parametrize("scene", ["sparse", "vortex", "shell"])
def test_skipping_empty_space_changes_no_pixel(scene: str) -> None:
    s = _sparse_scene() if scene == "sparse" else builtin_scene(scene).with_overrides(width=32, height=32)
    skipped = render_ray_marched(s, spp=2, seed=4, progress=False).layers
    every = render_ray_marched(s, spp=2, seed=4, progress=False, skip_empty=False).layers
    assert skipped["L_d"].max() > 0.0
    for layer in ("L", "L_d", "L_e"):
        np.testing.assert_array_equal(skipped[layer], every[layer], err_msg=f"{scene}: {layer}")


def test_empty_run_stays_in_empty_space_and_ends_at_the_medium() -> None:
    """Along random rays from random points: every point before the run's end has sigma_t = 0 (checked by
    lookups), and where the run is 0 the point's macrocell holds medium (its majorant is > 0)."""
    from photon_fields.runtime.transport.medium import extinction_at

    m = _sparse_scene().medium()
    rng = np.random.default_rng(1)
    runs = 0
    for _ in range(400):
        p = m.bmin + rng.random(3) * m.bsize
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        run = empty_run(m, *p, *d)
        cells = np.array(m.majorant.shape)
        cell = np.minimum(((p - m.bmin) / m.bsize * cells).astype(int), cells - 1)
        if run == 0.0:
            assert m.majorant[tuple(cell)] > 0.0
            continue
        runs += 1
        assert m.majorant[tuple(cell)] == 0.0
        for t in np.linspace(0.0, run, 50, endpoint=False):
            q = p + t * d
            if np.all((q >= m.bmin) & (q <= m.bmin + m.bsize)):
                assert extinction_at(m, *q) == 0.0
    assert runs > 100 and math.isfinite(run)
