"""Label scenes end to end: path tracing and photon mapping of a small segmented volume show each label's own
colour and no blend of two (single scattering at 1 spp: each pixel's L_d is one vertex's albedo times a grey
factor under a white light, so its chromaticity names the label it scattered in)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import small_camera

from photon_fields.runtime.renderers.path_tracer import render_path_traced
from photon_fields.runtime.renderers.photon_mapped import render_photon_mapped
from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.lights import DirectionalLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.train.photons.tracing import trace_photons

RED, BLUE = (0.9, 0.1, 0.1), (0.1, 0.2, 0.9)


def checker_labels(n: int = 12) -> np.ndarray:
    """Labels 3 and 7 in a checkerboard of 2-voxel blocks (many borders) inside a one-voxel background shell."""
    i = np.arange(n) // 2
    a = np.where((i[:, None, None] + i[None, :, None] + i[None, None, :]) % 2 == 0, 3, 7).astype(np.uint8)
    a[[0, -1]] = 0
    a[:, [0, -1]] = 0
    a[:, :, [0, -1]] = 0
    return a


@pytest.fixture(scope="module")
def label_scene() -> Scene:
    tf = LabelTransfer(np.array([0, 3, 7]), np.array([(0.5, 0.5, 0.5), RED, BLUE]), np.array([0.0, 1.0, 1.0]), 6.0)
    return Scene(make_volume(checker_labels(), name="checker"), tf,
                 (DirectionalLight([-0.5, -1.0, -0.3], [1, 1, 1], 3.0),), small_camera(24), 0.0, "checker")


def chromaticity_error(img: np.ndarray) -> np.ndarray:
    """Per lit pixel, the distance of its chromaticity to the nearer of the two labels' albedo chromaticities."""
    lit = img.reshape(-1, 3)
    lit = lit[lit.sum(axis=1) > 0]
    c = lit / lit.sum(axis=1, keepdims=True)
    refs = np.array([RED, BLUE]) / np.array([RED, BLUE]).sum(axis=1, keepdims=True)
    return np.min(np.linalg.norm(c[:, None] - refs[None], axis=-1), axis=1)


def test_path_traced_labels_show_only_label_colours(label_scene: Scene) -> None:
    layers = render_path_traced(label_scene, spp=1, seed=4, progress=False).layers
    err = chromaticity_error(layers["L_d"])
    assert err.size > 100 and err.max() < 1e-6
    c = layers["L_d"].reshape(-1, 3)
    assert np.any(c[:, 0] > 2 * c[:, 2]) and np.any(c[:, 2] > 2 * c[:, 0])  # both labels are seen
    assert np.all(np.isfinite(layers["L"])) and layers["L_i"].mean() > 0


def test_interpolated_labels_would_render_false_colours(label_scene: Scene) -> None:
    """The test above is worth something: the same scene with the labels interpolated before classification
    (the scalar path, on the same tables) has single-scattering pixels coloured by a blend of 3 and 7."""
    scene = label_scene.with_overrides()
    scene._cache["medium"] = label_scene.medium()._replace(categorical=False)
    err = chromaticity_error(render_path_traced(scene, spp=1, seed=4, progress=False).layers["L_d"])
    assert err.max() > 0.05


def test_photon_mapped_labels(label_scene: Scene) -> None:
    """Photons traced through the categorical medium render: L_d as the path tracer's, L_i lit and finite."""
    pmap = trace_photons(label_scene, 20_000, seed=1, progress=False)
    pm = render_photon_mapped(label_scene, pmap, spp=1, seed=4, progress=False, camera="delta").layers
    pt = render_path_traced(label_scene, spp=1, seed=4, progress=False).layers
    np.testing.assert_array_equal(pm["L_d"], pt["L_d"])
    assert np.all(np.isfinite(pm["L_i"])) and pm["L_i"].mean() > 0
    assert chromaticity_error(pm["L_d"]).max() < 1e-6
