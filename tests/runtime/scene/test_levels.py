"""Coarser levels of a volume (``runtime/scene/levels.py``): block means (label volumes: block centres) in the
same box, the level the viewer picks by size, and the preview of a level against the full volume's."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.levels import (
    MAX_LEVEL,
    check_level,
    coarser_volume,
    interactive_level,
    scene_at_level,
)
from photon_fields.runtime.scene.lights import DirectionalLight
from photon_fields.runtime.scene.scene import builtin_scene
from photon_fields.runtime.scene.volume import Volume, make_volume


def test_a_level_averages_blocks_in_the_same_box() -> None:
    rng = np.random.default_rng(3)
    vol = make_volume(rng.random((6, 5, 4)), spacing=(1.0, 2.0, 0.5))
    level = coarser_volume(vol, 1)
    assert level.dims == (3, 3, 2)
    d = vol.data.astype(np.float64)
    assert level.data[1, 0, 1] == pytest.approx(d[2:4, 0:2, 2:4].mean(), rel=1e-6)
    # the last y block (voxel 4 only) is padded with that voxel
    assert level.data[2, 2, 0] == pytest.approx(d[4:6, [4, 4], 0:2].mean(), rel=1e-6)
    np.testing.assert_allclose(level.bbox_min, vol.bbox_min, rtol=0, atol=1e-12)
    np.testing.assert_allclose(level.extent, vol.extent, rtol=0, atol=1e-12)
    assert level.window == vol.window and level.value_range == vol.value_range
    assert coarser_volume(vol, 1) is level and coarser_volume(vol, 0) is vol
    two = coarser_volume(vol, 2)
    assert two.dims == (2, 2, 1) and two.data[0, 0, 0] == pytest.approx(d[0:4, 0:4, 0:4].mean(), rel=1e-6)


def test_a_label_level_takes_block_centres_and_never_averages_labels() -> None:
    labels = np.zeros((7, 8, 8), np.uint8)
    labels[:, :4] = 3
    labels[1::2, 4:, 1::2] = 7  # a checkerboard of 7 in 0: any mean would give labels in between
    vol = make_volume(labels)
    level = coarser_volume(vol, 1, labels=True)
    assert level.dims == (4, 4, 4)
    for i, j, k in np.ndindex(level.dims):
        assert level.data[i, j, k] == vol.data[min(2 * i + 1, 6), 2 * j + 1, 2 * k + 1]
    assert set(np.unique(level.data)) <= set(np.unique(vol.data))
    assert coarser_volume(vol, 1) is not level  # the mean is another level


@pytest.mark.parametrize(("dims", "level"), [((96, 96, 96), 0), ((128, 40, 7), 0), ((129, 10, 10), 1),
                                             ((256, 256, 256), 1), ((40, 257, 40), 2), ((512, 512, 300), 2),
                                             ((10**6, 1, 1), MAX_LEVEL)])
def test_the_interactive_level_is_the_least_whose_longest_side_fits(dims: tuple[int, int, int], level: int) -> None:
    assert interactive_level(dims) == level
    assert max(-(-n // (1 << level)) for n in dims) <= 128 or level == MAX_LEVEL


def test_the_command_lines_levels_are_the_renderers() -> None:
    from photon_fields.runtime.renderers import registry

    assert registry.MAX_LEVEL == MAX_LEVEL


@pytest.mark.parametrize("bad", [-1, MAX_LEVEL + 1, 1.0, True, "1"])
def test_a_bad_level_is_refused(bad: object) -> None:
    with pytest.raises(ValueError, match="level"):
        check_level(bad)  # type: ignore[arg-type]


def test_the_preview_of_a_level_stays_close_to_the_full_volumes() -> None:
    """On a smooth medium a level's image differs from the full volume's by what averaging blocks changes (a few
    per cent at 128^3 -> 64^3; more on coarser or thinner structures, bench/README.md), not by a shifted or stretched
    box: the mean within 2.5 %, the relative L2 of 4-frame averages < 0.05 (measured 1.0 % and 0.023); the camera
    and g are the scene's."""
    scene = builtin_scene("blobs", 128).with_overrides(width=48, height=48, g=0.3)

    def mean_frames(level: int) -> np.ndarray:
        return np.mean([render_ray_marched(scene, spp=1, seed=s, progress=False, level=level).layers["L_d"]
                        for s in range(4)], 0)

    full, coarse = mean_frames(0), mean_frames(1)
    assert coarse.mean() == pytest.approx(full.mean(), rel=0.025)
    assert np.linalg.norm(coarse - full) / np.linalg.norm(full) < 0.05
    level = scene_at_level(scene, 1)
    assert level.volume.dims == (64, 64, 64) and level.camera == scene.camera and level.g == scene.g
    assert scene_at_level(scene, 1).medium() is level.medium()  # kept with the scene


def test_a_light_edit_keeps_a_levels_medium_and_renders_as_a_cold_level() -> None:
    scene = builtin_scene("blobs", 48).with_overrides(width=32, height=32)
    first = render_ray_marched(scene, spp=1, seed=2, progress=False, level=1).layers["L_d"]
    light = DirectionalLight(direction=(0.3, -1.0, 0.2), color=(1.0, 0.9, 0.8), power=2.0)
    lit = replace(scene, lights=(light,), _cache={})
    lit.adopt_medium(scene)
    assert scene_at_level(lit, 1).medium() is scene_at_level(scene, 1).medium()
    assert scene_at_level(lit, 1).lights == lit.lights
    warm = render_ray_marched(lit, spp=1, seed=2, progress=False, level=1).layers["L_d"]
    cold = render_ray_marched(replace(lit, _cache={}), spp=1, seed=2, progress=False, level=1).layers["L_d"]
    np.testing.assert_array_equal(warm, cold)
    assert np.abs(warm - first).mean() > 0.05 * np.abs(first).mean()


def test_a_label_levels_function_keeps_only_the_labels_it_has() -> None:
    labels = np.zeros((16, 16, 16), np.uint8)
    labels[4:12, 4:12, 4:12] = 3
    labels[0, 0, 0] = 9  # one voxel: gone at level 1 (blocks take their centre voxel)
    tf = LabelTransfer(np.array([3, 9]), np.array([[0.9, 0.2, 0.2], [0.2, 0.9, 0.2]]), np.array([1.0, 1.0]))
    scene = replace(builtin_scene("blobs", 16), volume=make_volume(labels), tf=tf, _cache={})
    level = scene_at_level(scene, 1)
    assert isinstance(level.volume, Volume) and level.volume.dims == (8, 8, 8)
    assert list(level.tf.labels) == [3]
    assert render_ray_marched(scene.with_overrides(width=16, height=16), spp=1, seed=0, progress=False,
                              level=1).layers["L_d"].max() > 0.0
    only_nine = replace(scene, tf=LabelTransfer(np.array([9]), np.array([[0.2, 0.9, 0.2]]), np.array([1.0])),
                        _cache={})
    assert scene_at_level(only_nine, 1) is only_nine  # no label of the function is left: the full volume
