"""Counter-based random streams, identical in numba kernels and numpy code.

Every work item (a camera sample, a photon) owns a 64-bit state derived from ``(seed, stream)`` where
``stream`` is the item's global index (e.g. ``sample * n_pixels + pixel``). Results therefore depend
only on the seed and the item, never on batch size, thread count or scheduling: the same seed gives
the same image bit for bit on any machine with the same floating-point behaviour.

The generator is SplitMix64 (Steele et al. 2014): ``state += golden``; output = ``mix64(state)``.
All arithmetic is uint64 with explicit uint64 constants (mixing signed ints would promote to float in
numba and silently break the generator).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from photon_fields.runtime.numba_inlining import install

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S11, _S27, _S30, _S31 = np.uint64(11), np.uint64(27), np.uint64(30), np.uint64(31)
_INV_2_53 = 1.0 / 9007199254740992.0


@njit(cache=True, inline="always")
def mix64(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True, inline="always")
def stream_state(seed: np.uint64, stream: np.uint64) -> np.uint64:
    """Initial state of stream ``stream`` under ``seed``."""
    return mix64(mix64(np.uint64(seed) + GOLDEN) ^ np.uint64(stream))


@njit(cache=True, inline="always")
def next_float(state: np.uint64) -> tuple[np.uint64, float]:
    """Advance ``state``; return (new_state, u) with u uniform in [0, 1) at 53-bit resolution."""
    state = state + GOLDEN
    return state, float(mix64(state) >> _S11) * _INV_2_53


@njit(cache=True, parallel=False, nogil=True)
def stream_states(seed: int, first_stream: int, count: int) -> np.ndarray:
    """States of streams ``first_stream .. first_stream + count - 1``."""
    out = np.empty(count, dtype=np.uint64)
    s = np.uint64(seed)
    for i in range(count):
        out[i] = stream_state(s, np.uint64(first_stream + i))
    return out


@njit(cache=True)
def uniform_batch(states: np.ndarray, count: int) -> np.ndarray:
    """``count`` successive uniforms from each state (advancing ``states`` in place): shape (n, count)."""
    out = np.empty((states.shape[0], count))
    for i in range(states.shape[0]):
        s = states[i]
        for k in range(count):
            s, out[i, k] = next_float(s)
        states[i] = s
    return out
