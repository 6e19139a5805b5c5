"""The categorical medium of a label volume: no colour that no label has, exact per-voxel extinction, a
majorant that still bounds sigma_t, and tracking that sees the labels' optical depth."""

from __future__ import annotations

import math

import numpy as np
import pytest

from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import (
    Medium,
    albedo_batch,
    build_medium,
    extinction_batch,
    voxel_extinction,
)
from photon_fields.runtime.transport.rng import stream_states
from photon_fields.runtime.transport.tracking import ratio_track_batch

RED, BLUE, GREEN = (0.9, 0.1, 0.1), (0.1, 0.2, 0.9), (0.2, 0.9, 0.2)
DENSITY = 30.0


def side_by_side() -> np.ndarray:
    """Label 3 on the low-x half, label 7 on the high-x half (8 x 4 x 4 voxels)."""
    a = np.full((8, 4, 4), 3, dtype=np.uint8)
    a[4:] = 7
    return a


def two_label_tf() -> LabelTransfer:
    return LabelTransfer(np.array([3, 7]), np.array([RED, BLUE]), np.array([1.0, 0.4]), DENSITY)


def border_points(m: Medium, n: int = 20_000, seed: int = 0) -> np.ndarray:
    """Points (3, n) concentrated on the 3|7 border (x = 0), anywhere in y and z."""
    rng = np.random.default_rng(seed)
    p = m.bmin[:, None] + rng.random((3, n)) * m.bsize[:, None]
    p[0] = rng.normal(0.0, 0.08, n).clip(m.bmin[0], m.bmin[0] + m.bsize[0])
    return p


def test_no_false_colour_across_a_label_border() -> None:
    """Every albedo and extinction sampled across the border is label 3's or label 7's, and both occur."""
    m = build_medium(make_volume(side_by_side()), two_label_tf())
    assert m.categorical
    p = border_points(m)
    alb = albedo_batch(m, p).T
    sigma = extinction_batch(m, p)
    is_red = np.all(alb == RED, axis=1)
    is_blue = np.all(alb == BLUE, axis=1)
    assert np.all(is_red | is_blue)
    assert is_red.any() and is_blue.any()
    np.testing.assert_array_equal(sigma, np.where(is_red, DENSITY, 0.4 * DENSITY))
    assert np.all(is_red == (p[0] < 0))  # the border is where the voxels say


def test_trilinear_classification_shows_false_colours() -> None:
    """The test above is worth something: interpolating the labels before classifying them, as the scalar path
    does, blends the two labels' albedos at the border (on the same tables); and with a continuous TF that
    gives label 5 its own colour, the border between 3 and 7 turns green (the user report: 3 | 7 through 5)."""
    m = build_medium(make_volume(side_by_side()), two_label_tf())
    alb = albedo_batch(m._replace(categorical=False), border_points(m)).T
    assert not np.all(np.all(alb == RED, axis=1) | np.all(alb == BLUE, axis=1))
    a = side_by_side()
    a[0, 0, 0] = 5  # label 5 exists, far from the border
    tf = TransferFunction(np.array([0.0, 0.45, 0.5, 0.55, 1.0]), np.array([RED, RED, GREEN, BLUE, BLUE]),
                          np.ones(5), DENSITY)  # labels 3 -> s 0, 5 -> s 0.5, 7 -> s 1
    scalar = build_medium(make_volume(a), tf)
    x = np.linspace(-0.05, 0.05, 101)
    line = np.stack([x, np.zeros_like(x), np.zeros_like(x)])
    assert np.any(np.all(np.abs(albedo_batch(scalar, line).T - GREEN) < 0.02, axis=1))  # label 5 at the border


def random_labels(shape: tuple[int, int, int] = (11, 7, 9), seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    labels = np.array([0, 2, 5, 9, 40])
    a = labels[rng.integers(0, labels.size, size=shape)]
    a[:, :, : shape[2] // 3] = 0  # a background slab: empty macrocells
    return a


def random_tf() -> LabelTransfer:
    return LabelTransfer(np.array([0, 2, 5, 9, 40]), np.random.default_rng(2).random((5, 3)),
                         np.array([0.0, 0.3, 1.0, 0.05, 0.7]), 50.0)


def test_extinction_at_voxel_centres_is_the_labels() -> None:
    a = random_labels()
    vol = make_volume(a, spacing=(1.0, 1.5, 0.7))
    tf = random_tf()
    m = build_medium(vol, tf)
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in a.shape], indexing="ij")).reshape(3, -1)
    centres = m.bmin[:, None] + (idx + 0.5) / np.array(a.shape)[:, None] * m.bsize[:, None]
    expected = tf.opacity[np.searchsorted(tf.labels, a.reshape(-1))] * tf.density_scale
    np.testing.assert_array_equal(extinction_batch(m, centres), expected)
    np.testing.assert_array_equal(voxel_extinction(m).reshape(-1), expected)
    expected_albedo = tf.albedo[np.searchsorted(tf.labels, a.reshape(-1))]
    np.testing.assert_array_equal(albedo_batch(m, centres).T[expected > 0], expected_albedo[expected > 0])


@pytest.mark.parametrize("macrocell", [1, 2, 3, 4])
def test_majorant_bounds_extinction_and_empty_space_stays_empty(macrocell: int) -> None:
    """Random points (and points on macrocell faces, where rounding decides the cell) never exceed their
    macrocell's majorant; cells deep in the background slab have majorant 0, so they are leapt over."""
    m = build_medium(make_volume(random_labels(), spacing=(1.0, 1.5, 0.7)), random_tf(), macrocell)
    rng = np.random.default_rng(macrocell)
    cells = np.array(m.majorant.shape)
    p = rng.random((3, 200_000))
    p[0, ::2] = np.round(p[0, ::2] * cells[0]) / cells[0]  # on x faces of the macrocells
    p = m.bmin[:, None] + p * m.bsize[:, None]
    idx = np.minimum((((p - m.bmin[:, None]) / m.bsize[:, None]) * cells[:, None]).astype(int), cells[:, None] - 1)
    assert np.all(extinction_batch(m, p) <= m.majorant[idx[0], idx[1], idx[2]])
    assert m.majorant.max() <= 50.0 * (1 + 1e-5)
    nz = random_labels().shape[2]
    empty_cells = (nz // 3 - 1) // macrocell  # cells whose trilinear support lies inside the background slab
    if empty_cells:
        assert np.all(m.majorant[:, :, :empty_cells] == 0.0)
        assert np.all(m.leap[:, :, :, :empty_cells][[0, 1, 2, 3]] > 0)  # octants with dz < 0 leap


def test_majorant_is_tighter_than_an_index_range() -> None:
    """Label indices carry no order: a macrocell holding labels 0 and 2 (the 1st and 3rd present) is not bounded
    by label 1's extinction, which sits between them in index order but is absent from the cell."""
    a = np.zeros((8, 8, 8), dtype=np.int32)
    a[:4] = 2
    a[6:, 6:, 6:] = 1
    tf = LabelTransfer(np.array([0, 1, 2]), np.full((3, 3), 0.8), np.array([0.0, 1.0, 0.1]), 50.0)
    m = build_medium(make_volume(a), tf, macrocell=2)
    assert m.majorant[0, 0, 0] == pytest.approx(5.0, rel=1e-5)


def test_ratio_tracking_sees_the_labels_optical_depth() -> None:
    """Rays along x through the two half boxes (x extent 1): mean transmittance exp(-(3 * 0.5 + 1.2 * 0.5))
    within 4 standard errors (tracking goes through the categorical majorant grid and the nearest lookups)."""
    m = build_medium(make_volume(side_by_side()), LabelTransfer(np.array([3, 7]), np.array([RED, BLUE]),
                                                                 np.array([1.0, 0.4]), 3.0))
    n = 40_000
    rng = np.random.default_rng(3)
    o = np.stack([np.full(n, m.bmin[0]), m.bmin[1] + rng.random(n) * m.bsize[1],
                  m.bmin[2] + rng.random(n) * m.bsize[2]])
    d = np.tile(np.array([[1.0], [0.0], [0.0]]), (1, n))
    tr = ratio_track_batch(m, o, d, np.zeros(n), np.full(n, m.bsize[0]), stream_states(5, 0, n))
    assert m.bsize[0] == 1.0
    expected = math.exp(-(3.0 * 0.5 + 1.2 * 0.5))
    assert abs(tr.mean() - expected) < 4 * tr.std() / math.sqrt(n) + 1e-12


@pytest.mark.parametrize("labels", [False, True])
@pytest.mark.parametrize("block", [1, 2, 3])
def test_block_extinction_is_the_mean_of_the_voxels_sigma_t(labels: bool, block: int) -> None:
    """The denoisers' coarse grid (``medium.block_extinction``): each block's mean of sigma_t at its voxel centres,
    the far ends padded with their border voxels, for a continuous and a categorical medium of odd sides."""
    from photon_fields.runtime.transport.medium import block_extinction

    a = random_labels()
    if labels:
        m = build_medium(make_volume(a), random_tf())
    else:
        tf = TransferFunction(np.array([0.0, 0.3, 0.6, 1.0]), np.full((4, 3), 0.8), np.array([0.0, 0.9, 0.1, 1.0]),
                              20.0)
        m = build_medium(make_volume(a.astype(np.float64) + np.random.default_rng(4).random(a.shape)), tf)
    sigma = voxel_extinction(m)
    cells = [-(-n // block) for n in sigma.shape]
    padded = np.pad(sigma, [(0, c * block - n) for c, n in zip(cells, sigma.shape, strict=True)], mode="edge")
    expected = padded.reshape(cells[0], block, cells[1], block, cells[2], block).mean(axis=(1, 3, 5))
    assert expected.std() > 0.0
    np.testing.assert_allclose(block_extinction(m, block), expected, rtol=1e-12, atol=1e-12)
