"""The MLP input's non-hash parts in numba (runtime/field/inputs.py) against models_spec's numpy definitions."""

from __future__ import annotations

import numpy as np
import pytest

from photon_fields.models_spec.encoding import direction_gains, normalize_position, phase_features
from photon_fields.runtime.field.inputs import finish_rows, normalized_positions

PHASES = tuple(float(g) for g in np.linspace(-0.8, 0.8, 16))


def test_normalized_positions_equal_models_spec_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    bmin, bsize = np.array([-0.5, -0.3, -0.45]), np.array([1.0, 0.6, 0.9])
    x = bmin + rng.uniform(-0.2, 1.2, (100_000, 3)) * bsize  # inside and outside the box
    x[:8] = bmin + np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)]) * bsize  # its corners
    # contiguous, float32, and the renderers' (3, n) arrays transposed (strided, read in place)
    for xs in (x, x.astype(np.float32), np.ascontiguousarray(x.T).T[5:900:3]):
        np.testing.assert_array_equal(normalized_positions(xs, bmin, bsize), normalize_position(xs, bmin, bsize))
    with pytest.raises(ValueError, match="bsize"):
        normalized_positions(x, bmin, np.array([1.0, 0.0, 1.0]))


@pytest.mark.parametrize("encoding", ["spline", "tent", "scalar"])
@pytest.mark.parametrize("gain", ["g", "none"])
def test_finish_rows_equals_the_numpy_columns(encoding: str, gain: str) -> None:
    """The direction columns times g and the phase features, per-query g and one g for all (one phase row copied)."""
    rng = np.random.default_rng(2)
    n, dir_col, dirs = 5000, 32, 12
    width = dir_col + dirs + phase_features(np.zeros(1), PHASES, encoding).shape[1]
    base = rng.standard_normal((n, width)).astype(np.float32)
    for g in (rng.uniform(-1, 1, n).astype(np.float32), np.full(n, 0.35, np.float32)):
        want = base.copy()
        gains = direction_gains(g, gain)
        if gains is not None:
            want[:, dir_col:dir_col + dirs] *= gains
        want[:, dir_col + dirs:] = phase_features(g, PHASES, encoding)
        got = base.copy()
        one = g[:1] if (g == g[0]).all() else g
        finish_rows(got, dir_col, dir_col + dirs, direction_gains(one, gain), phase_features(one, PHASES, encoding))
        np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="do not fit"):
        finish_rows(base, dir_col, dir_col + dirs, np.ones(3, np.float32), np.zeros((1, width - dir_col - dirs)))
