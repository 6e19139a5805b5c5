"""The surface input (models_spec.surface): the grid points out of the medium at its surfaces and vanishes inside
and outside, the columns are g s and g s |s| of the trilinear grid, the runtime's numba rows are the same bit for
bit, a coarse volume's cells hold its voxels' means, and the field config carries the grid's cells."""

from __future__ import annotations

import numpy as np
import pytest

from photon_fields.models_spec.encoding import FieldConfig
from photon_fields.models_spec.surface import (
    SURFACE_MAX_CELLS,
    SURFACE_QUANT,
    surface_cells,
    surface_columns,
    surface_grid,
    surface_vectors,
    unit_direction,
    voxel_cells,
)
from photon_fields.runtime.field.inputs import surface_rows
from photon_fields.runtime.transport.medium import Medium, voxel_extinction


def ball(n: int = 24, radius: float = 7.0, sigma: float = 10.0) -> np.ndarray:
    i = np.arange(n) + 0.5 - n / 2
    r = np.sqrt(i[:, None, None] ** 2 + i[None, :, None] ** 2 + i[None, None, :] ** 2)
    return np.where(r < radius, sigma, 0.0)


def test_the_grid_points_out_of_a_ball_at_its_surface_and_vanishes_inside_and_far_outside() -> None:
    n = 24
    grid = surface_grid(ball(n), np.ones(3))
    assert grid.dtype == np.int8 and grid.shape == (n, n, n, 3)
    v = grid.astype(np.float64) / SURFACE_QUANT
    c = n // 2
    # the +x face of the ball (radius 7 cells from its centre, a cell corner): v points along the outward normal,
    # (6.5, 0.5, 0.5) from the centre, |v| ~ 1
    face = v[c + 6, c, c]
    normal = np.array([6.5, 0.5, 0.5]) / np.linalg.norm([6.5, 0.5, 0.5])
    assert np.linalg.norm(face) > 0.8 and face @ normal / np.linalg.norm(face) > 0.995
    back = v[c - 7, c, c]
    assert back[0] < -0.5
    assert np.linalg.norm(v[c, c, c]) < 0.05  # homogeneous inside
    assert np.linalg.norm(v[1, 1, 1]) < 0.05  # empty, far from the ball
    # a camera ray entering the +x face head on travels along -x: s = d . v < 0; leaving it, s > 0
    u = np.array([[(c + 6 + 0.5) / n, (c + 0.5) / n, (c + 0.5) / n]])
    enter = surface_columns(grid, u, np.array([[-1.0, 0.0, 0.0]]), np.array([1.0]))
    leave = surface_columns(grid, u, np.array([[1.0, 0.0, 0.0]]), np.array([1.0]))
    assert enter[0, 0] < -0.5 and leave[0, 0] > 0.5
    assert enter[0, 1] == pytest.approx(-enter[0, 0] ** 2, rel=1e-6)


def test_the_columns_are_g_s_and_g_s_abs_s_of_the_trilinear_grid() -> None:
    """A grid linear in the cell index is reproduced exactly by trilinear interpolation between the outer cell
    centres and is constant beyond them; g = 0 gives zeros (the field stays isotropic there)."""
    cells = np.array([7, 5, 6])
    i, j, k = np.meshgrid(*(np.arange(c) for c in cells), indexing="ij")
    grid = np.stack([10 * (i - 3), -12 * (j - 2), 9 * (k - 2)], axis=-1).astype(np.int8)
    rng = np.random.default_rng(0)
    u = rng.uniform(-0.2, 1.2, (4000, 3)).astype(np.float32)
    t = np.clip(u.astype(np.float64) * cells - 0.5, 0.0, cells - 1.0)  # cell coordinates, clamped at the centres
    want_v = np.stack([10 * (t[:, 0] - 3), -12 * (t[:, 1] - 2), 9 * (t[:, 2] - 2)], axis=1) / SURFACE_QUANT
    np.testing.assert_allclose(surface_vectors(grid, u), want_v, atol=1e-12)
    d = rng.standard_normal((4000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    g = rng.uniform(-1, 1, 4000)
    s = (d * want_v).sum(axis=1)
    cols = surface_columns(grid, u, d, g)
    assert cols.dtype == np.float32 and cols.shape == (4000, 2)
    np.testing.assert_allclose(cols[:, 0], g.astype(np.float32) * s, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(cols[:, 1], g.astype(np.float32) * s * np.abs(s), rtol=1e-5, atol=1e-6)
    assert not np.any(surface_columns(grid, u, d, np.zeros(4000)))


def test_the_runtime_rows_equal_the_definition_bit_for_bit() -> None:
    rng = np.random.default_rng(1)
    grid = rng.integers(-127, 128, (9, 4, 13, 3)).astype(np.int8)
    u = rng.uniform(-0.1, 1.1, (3000, 3)).astype(np.float32)
    u[:8] = [[a & 1, (a >> 1) & 1, (a >> 2) & 1] for a in range(8)]  # box corners
    d = rng.standard_normal((3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    g = rng.uniform(-1, 1, 3000).astype(np.float32)
    buf = np.full((3000, 5), np.nan, np.float32)
    surface_rows(buf, 2, u, np.ascontiguousarray(d.T).T, g, grid)  # d with the renderers' transposed strides
    np.testing.assert_array_equal(buf[:, 2:4], surface_columns(grid, u, d, g))
    assert np.isnan(buf[:, :2]).all() and np.isnan(buf[:, 4]).all()
    surface_rows(buf, 0, u, d, g[:1], grid)  # one g for every row (a rendered frame)
    np.testing.assert_array_equal(buf[:, 0:2], surface_columns(grid, u, d, np.full(3000, g[0])))


def test_unit_direction_inverts_the_direction_input() -> None:
    from photon_fields.models_spec.encoding import direction_input

    rng = np.random.default_rng(2)
    d = rng.standard_normal((1000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(unit_direction(direction_input(d)), d, atol=2e-6)


def fake_medium(density: np.ndarray, ext_lut: np.ndarray, categorical: bool = False) -> Medium:
    shape = np.asarray(density.shape, np.float64)
    size = shape / 100.0
    return Medium(np.ascontiguousarray(density, np.float32), ext_lut, np.zeros((ext_lut.shape[0], 3)),
                  np.zeros((1, 1, 1)), np.zeros((8, 1, 1, 1), np.uint8), np.zeros(3), size, shape / size, categorical)


@pytest.mark.parametrize("shape", [(130, 5, 3), (300, 7, 260), (20, 30, 10)])
def test_a_coarse_volumes_cells_hold_the_mean_of_the_voxels_centred_in_them(shape: tuple[int, int, int]) -> None:
    from photon_fields.train.field.surface_grid import cell_extinction

    rng = np.random.default_rng(3)
    m = fake_medium(rng.random(shape), np.linspace(0.0, 50.0, 64) ** 1.5)
    cells = surface_cells(shape)
    assert max(cells) <= SURFACE_MAX_CELLS and (cells == shape) == (max(shape) <= SURFACE_MAX_CELLS)
    got = cell_extinction(m)
    ext = voxel_extinction(m)
    owners = [voxel_cells(n, c) for n, c in zip(shape, cells, strict=True)]
    for n, c, o in zip(shape, cells, owners, strict=True):  # the cell each voxel's centre falls in
        assert o.tolist() == [min(int((j + 0.5) * c / n), c - 1) for j in range(n)]
    want = np.zeros(cells)
    count = np.zeros(cells)
    np.add.at(want, np.ix_(*owners), ext)
    np.add.at(count, np.ix_(*owners), 1.0)
    np.testing.assert_allclose(got, want / count, rtol=1e-12)
    for n, c, o in zip(shape, cells, owners, strict=True):
        assert o[0] == 0 and o[-1] == c - 1 and np.all(np.diff(o) >= 0) and np.bincount(o).min() >= 1
        assert np.bincount(o).max() - np.bincount(o).min() <= 1 + (n % c > 0)


def test_the_field_config_carries_the_grids_cells() -> None:
    cfg = FieldConfig(surface=(4, 5, 6))
    assert cfg.surface_dims == 2 and cfg.input_dims == FieldConfig().input_dims + 2
    assert cfg.to_dict()["surface"] == [4, 5, 6] and "surface" not in FieldConfig().to_dict()
    assert FieldConfig.from_dict(cfg.to_dict()) == cfg
    for bad in [(0, 4, 4), (4, 4), (4, 4, SURFACE_MAX_CELLS + 1), (4.5, 4, 4), ("a", "b", "c"), (True, 4, 4)]:
        with pytest.raises(ValueError, match="FieldConfig.surface"):
            FieldConfig(surface=bad)  # type: ignore[arg-type]
