"""The MLP output's decode and lights' sum in numba (runtime/field/outputs.py) against models_spec's numpy Eq. 7
and float32 sums in light order."""

from __future__ import annotations

import numpy as np
import pytest

from photon_fields.models_spec.encoding import decode_radiance
from photon_fields.runtime.field.outputs import decode_lights


def _reference(lp: np.ndarray, psi: float, lights: int, scale: np.ndarray | None) -> np.ndarray:
    parts = decode_radiance(lp, psi)
    factors = None if scale is None else np.broadcast_to(np.asarray(scale, np.float32), (lights, 3))
    out = np.empty((lp.shape[0], 3), np.float32)
    for light in range(lights):
        part = parts[:, 3 * light:3 * light + 3]
        if factors is not None:
            part = part * factors[light]
        if light == 0:
            out[:] = part
        else:
            out += part
    return out


@pytest.mark.parametrize("lights", [1, 2, 3])
@pytest.mark.parametrize("scale", ["none", "rgb", "per-light"])
def test_decode_lights_equals_numpy_bit_for_bit(lights: int, scale: str) -> None:
    """Every decoded and summed value equals numpy's, over outputs from very bright (L' < 0) to below 10^-psi
    (L' > 1), with factors for all lights or one per light."""
    rng = np.random.default_rng(lights)
    lp = rng.uniform(-0.3, 1.3, (200_000, 3 * lights)).astype(np.float32)
    lp[:4] = [[0.0], [1.0], [-0.25], [0.5]]
    factors = {"none": None, "rgb": np.array([1.7, 0.3, 1.0], np.float32),
               "per-light": rng.uniform(0.2, 3.0, (lights, 3)).astype(np.float32)}[scale]
    for psi in (5.0, 3.3):
        np.testing.assert_array_equal(decode_lights(lp, psi, lights, factors), _reference(lp, psi, lights, factors))


def test_decode_lights_refuses_a_mismatched_output() -> None:
    with pytest.raises(ValueError, match=r"\(N, 6\)"):
        decode_lights(np.zeros((5, 3), np.float32), 5.0, 2)
