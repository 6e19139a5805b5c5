"""The PVRT renderer's empty-space skipping (runtime/renderers/pvrt.py, ``skip_empty``): camera rays jump over
empty runs and the light volumes march only the cells a camera sample in the medium can read, and the image is
the same, bit for bit, as the renderer that looks up every sample and marches every cell. And its relighting
(:class:`Relighting`): frames from the kept camera samples are render_pvrt's frames under the same lights."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import small_camera

from photon_fields.runtime.pvrt.precompute import grid_shape
from photon_fields.runtime.pvrt.radiance import _needed_cells, grid_coord, light_volumes
from photon_fields.runtime.pvrt.transfer import Transfer, precompute_transfer
from photon_fields.runtime.renderers.pvrt import Relighting, render_pvrt
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import extinction_batch


def _sparse_scene(width: int = 32) -> Scene:
    """Two small dense blobs in a mostly empty, not quite cubic box (40 x 40 x 36 voxels), one directional light.
    The blobs are cut off at a small density and the extinction rises from 0 there, so that a sample just past an
    empty run is in the medium: a march that jumps too far loses light."""
    x = (np.arange(40) + 0.5) / 40
    z = (np.arange(36) + 0.5) / 36
    X, Y, Z = np.meshgrid(x, x, z, indexing="ij")
    field = (np.exp(-((X - 0.3) ** 2 + (Y - 0.4) ** 2 + (Z - 0.5) ** 2) / 0.004)
             + np.exp(-((X - 0.7) ** 2 + (Y - 0.6) ** 2 + (Z - 0.4) ** 2) / 0.006))
    tf = TransferFunction(np.array([0.0, 0.2, 1.0]), np.array([[0.9, 0.8, 0.7]] * 3), np.array([0.0, 0.2, 1.0]),
                          30.0, "sparse")
    return Scene(make_volume(np.clip(field - 0.05, 0, 1), window=(0.0, 1.0), name="two_blobs"), tf,
                 (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.9, 0.8], 2.0),), small_camera(width), 0.3, "sparse")


@pytest.fixture(scope="module")
def sparse() -> Scene:
    return _sparse_scene()


@pytest.fixture(scope="module")
def transfer(sparse: Scene) -> Transfer:
    return precompute_transfer(sparse, order=0, grid=8, paths=2000, clusters=4, seed=0, progress=False)


@pytest.mark.parametrize("sky", [0.0, 0.4])
def test_skipping_empty_space_changes_no_pixel(sparse: Scene, transfer: Transfer, sky: float) -> None:
    """Also with a sky, whose direct term reads the optical-depth volumes (runtime/pvrt/direct.py), marched at the
    needed cells only as the light volumes are."""
    scene = _lit(sparse, [-0.5, -0.8, 0.3], sky)
    skipped = render_pvrt(scene, transfer=transfer, progress=False).layers
    every = render_pvrt(scene, transfer=transfer, progress=False, skip_empty=False).layers
    assert skipped["L_d"].max() > 0.0 and skipped["L_i"].max() > 0.0
    for layer in ("L", "L_d", "L_i", "L_e"):
        np.testing.assert_array_equal(skipped[layer], every[layer], err_msg=layer)


@pytest.mark.parametrize("grid", [13, 24, 64])
def test_light_volume_marches_every_cell_a_sample_in_the_medium_reads(sparse: Scene, grid: int) -> None:
    """At random points where sigma_t > 0, the eight corners of the light volume's trilinear stencil were marched
    and hold what marching every cell gives; the cells left out are most of the box."""
    m = sparse.medium()
    dirs = np.array([[0.5, 0.8, -0.3], [-0.6, -0.7, -0.4]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    h = float(sparse.volume.voxel_size)
    fast = light_volumes(m, dirs, grid, h)
    every = light_volumes(m, dirs, grid, h, skip_empty=False)
    shape = grid_shape(m.bsize, grid)
    needed = _needed_cells(m, *shape)
    assert needed.mean() < 0.5
    np.testing.assert_array_equal(fast[:, needed], every[:, needed])
    p = m.bmin[:, None] + np.random.default_rng(3).random((3, 100000)) * m.bsize[:, None]
    p = p[:, extinction_batch(m, p) > 0.0]
    assert p.shape[1] > 300
    for x in p.T:
        lower = [grid_coord(x[a], m.bmin[a], shape[a] / m.bsize[a], shape[a])[0] for a in range(3)]
        corners = needed[lower[0]:lower[0] + 2, lower[1]:lower[1] + 2, lower[2]:lower[2] + 2]
        assert corners.all(), f"a stencil corner at {x} was not marched"


def _lit(scene: Scene, direction: list[float], sky: float) -> Scene:
    """``scene`` under one directional light from ``direction`` and a constant sky (shares the medium)."""
    from dataclasses import replace

    out = replace(scene, lights=(DirectionalLight(direction, [1.0, 0.9, 0.8], 2.0),
                                 EnvironmentLight([0.3, 0.5, 1.0], sky)), _cache={})
    out._cache["medium"] = scene.medium()
    return out


@pytest.mark.parametrize(("spp", "batch_size"), [(1, 1 << 18), (2, 700)])
def test_relighting_gives_render_pvrts_frames(sparse: Scene, transfer: Transfer, spp: int, batch_size: int) -> None:
    """Each frame from the kept samples matches render_pvrt's under the same lights to the float32 precision
    of the kept positions and weights (also over several batches and samples per pixel); the light volume cells
    it marches are a fraction of the needed ones."""
    relit = Relighting(sparse, transfer, seed=5, spp=spp, batch_size=batch_size)
    assert relit.samples > 100
    m = sparse.medium()
    assert 0 < relit.cells.sum() < _needed_cells(m, *relit.cells.shape).sum()
    for direction, sky in (([-0.5, -0.8, 0.3], 0.2), ([0.7, -0.2, -0.6], 0.0), ([0.1, 0.9, 0.2], 0.5)):
        scene = _lit(sparse, direction, sky)
        want = render_pvrt(scene, transfer=transfer, seed=5, spp=spp, batch_size=batch_size, progress=False).layers
        got = relit.render(scene.lights).layers
        assert want["L_d"].max() > 0.0 and want["L_i"].max() > 0.0
        for layer in ("L", "L_d", "L_i", "L_e"):
            np.testing.assert_allclose(got[layer], want[layer], rtol=1e-5, atol=1e-6 * float(want[layer].max()),
                                       err_msg=f"{direction}: {layer}")


def test_relighting_keeps_nothing_beyond_max_samples(sparse: Scene, transfer: Transfer) -> None:
    relit = Relighting(sparse, transfer, seed=5, max_samples=10)
    assert relit.samples == 0
    scene = _lit(sparse, [0.7, -0.2, -0.6], 0.2)
    want = render_pvrt(scene, transfer=transfer, seed=5, progress=False).layers
    got = relit.render(scene.lights).layers
    for layer in ("L", "L_d", "L_i", "L_e"):
        np.testing.assert_array_equal(got[layer], want[layer], err_msg=layer)


def test_relighting_reuses_the_light_volumes_while_the_lights_stay(sparse: Scene, transfer: Transfer) -> None:
    """A frame whose directional lights did not move (only the sky changed) takes the last frame's light volumes,
    and is still render_pvrt's frame."""
    relit = Relighting(sparse, transfer, seed=5)
    relit.render(_lit(sparse, [0.7, -0.2, -0.6], 0.2).lights)
    shadows = relit._previous.lights
    scene = _lit(sparse, [0.7, -0.2, -0.6], 0.6)
    got = relit.render(scene.lights).layers
    assert relit._previous.lights is shadows
    want = render_pvrt(scene, transfer=transfer, seed=5, progress=False).layers
    for layer in ("L", "L_d", "L_i", "L_e"):
        np.testing.assert_allclose(got[layer], want[layer], rtol=1e-5, atol=1e-6 * float(want[layer].max()),
                                   err_msg=layer)
