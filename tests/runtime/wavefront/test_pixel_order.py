"""The order work is taken in (runtime/wavefront/rays.py, ``tile_order`` / ``tiled_work``): a permutation of the
pixels in square tiles, which changes which rays run together and nothing about any ray."""

from __future__ import annotations

import numpy as np
import pytest

from photon_fields.runtime.wavefront.rays import tile_order, tiled_work


@pytest.mark.parametrize(("width", "height", "tile"), [(64, 48, 16), (100, 37, 16), (17, 5, 4), (3, 40, 16),
                                                       (1, 1, 16), (33, 31, 8)])
def test_tile_order_is_a_permutation_of_squares(width: int, height: int, tile: int) -> None:
    """Every pixel once; consecutive positions fill one tile after another, each tile the rectangle of the image
    it covers (a full tile: tile x tile pixels), bands from the top and tiles from the left."""
    order = tile_order(width, height, tile)
    np.testing.assert_array_equal(np.sort(order), np.arange(width * height))
    y, x = order // width, order % width
    pos = 0
    for y0 in range(0, height, tile):
        for x0 in range(0, width, tile):
            h, w = min(tile, height - y0), min(tile, width - x0)
            ys, xs = y[pos:pos + h * w], x[pos:pos + h * w]
            np.testing.assert_array_equal(ys, y0 + np.repeat(np.arange(h), w), err_msg=f"tile at {x0}, {y0}")
            np.testing.assert_array_equal(xs, x0 + np.tile(np.arange(w), h), err_msg=f"tile at {x0}, {y0}")
            pos += h * w
    assert pos == width * height


def test_tiled_work_takes_each_sample_whole_and_batches_without_repeats() -> None:
    """Position ``sample * n + i`` is item ``sample * n + order[i]``: the positions of whole samples are those
    samples' items; any n consecutive positions, across a sample's end too, hold each pixel once."""
    width, height, spp = 20, 12, 3
    n = width * height
    order = tile_order(width, height, 8)
    work = tiled_work(0, n * spp, order)
    for s in range(spp):
        np.testing.assert_array_equal(np.sort(work[s * n:(s + 1) * n]), s * n + np.arange(n))
        np.testing.assert_array_equal(work[s * n:(s + 1) * n] - s * n, order)
    for first in (0, 7, n - 5, n + 100):
        batch = tiled_work(first, n, order)
        np.testing.assert_array_equal(batch, work[first:first + n])
        assert np.unique(batch % n).size == n
