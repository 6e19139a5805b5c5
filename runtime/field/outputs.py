"""The MLP's output decoded (paper Eq. 7) and its lights' parts summed, in one numba pass.

:meth:`photon_fields.runtime.field.field.PhotonField.query` turns the network's L' (N, 3 C) into radiance (N, 3):
``10^(-L' psi)`` per value (:func:`photon_fields.models_spec.encoding.decode_radiance`: in float64, rounded to
float32 once), each light's part times its factor (a light edit, float32), the parts added in light order
(float32). numpy took three passes and a float64 copy of the output, and its ``power`` ~20 ns per value: ~3 ms of
a 512x512 frame of a two-light field. Here one pass, with ``pow`` compiled under the ``afn`` (approximate
functions) and ``nnan`` flags, which lets LLVM vectorize it: ~3x faster, and the same float32 values as numpy's
(tested on random outputs; the float64 results may differ in their last bits, which the rounding to float32
absorbs). The other fast-math flags stay off: contracting ``v * factor + acc`` into one fused multiply-add changed
9 % of the sums in their last bit. ``nnan``: a network with finite inputs gives finite outputs.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from photon_fields.models_spec.encoding import OUTPUT_CHANNELS, check_psi


@njit(cache=True, fastmath={"afn", "nnan"})
def _decode_kernel(lp: np.ndarray, psi: float, lights: int, factors: np.ndarray, out: np.ndarray) -> None:
    scaled = factors.shape[0] > 0
    for i in range(lp.shape[0]):
        for c in range(3):
            acc = np.float32(0.0)
            for light in range(lights):
                v = np.float32(10.0 ** (-np.float64(lp[i, 3 * light + c]) * psi))
                if scaled:
                    v = v * factors[light, c]
                acc = v if light == 0 else acc + v
            out[i, c] = acc


def decode_lights(lp: np.ndarray, psi: float, lights: int, scale: np.ndarray | None = None) -> np.ndarray:
    """Radiance float32 (N, 3) from the network's L' (N, 3 ``lights``): Eq. 7 per value, each light's part times
    ``scale`` ((3,) for all lights, (lights, 3) one factor per light, None: 1), the parts summed."""
    p = check_psi(psi)
    if lp.ndim != 2 or lp.shape[1] != OUTPUT_CHANNELS * lights:
        raise ValueError(f"L' must have shape (N, {OUTPUT_CHANNELS * lights}), got {lp.shape}")
    factors = (np.zeros((0, OUTPUT_CHANNELS), np.float32) if scale is None else
               np.ascontiguousarray(np.broadcast_to(np.asarray(scale, np.float32), (lights, OUTPUT_CHANNELS))))
    out = np.empty((lp.shape[0], OUTPUT_CHANNELS), np.float32)
    _decode_kernel(np.ascontiguousarray(lp, dtype=np.float32), p, lights, factors, out)
    return out
