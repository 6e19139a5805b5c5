"""The film's accumulation: the direct add for distinct pixels equals the bincount sum bit for bit."""

from __future__ import annotations

import numpy as np

from photon_fields.runtime.wavefront.film import Film


def test_distinct_splat_equals_bincount_splat() -> None:
    rng = np.random.default_rng(3)
    a, b = Film(40, 30), Film(40, 30)
    for _ in range(5):  # several batches into the same accumulators, as frames and batches do
        pixel = rng.permutation(1200)[: rng.integers(1, 1200)]
        rgb = rng.normal(size=(3, pixel.shape[0])) * 10.0 ** rng.integers(-8, 8, size=(3, pixel.shape[0]))
        rgb[:, ::7] = -0.0  # signed zeros must not change anything either
        rgb[:, ::11] *= -1.0
        a.splat("L_d", pixel, rgb)
        b.splat("L_d", pixel, rgb, distinct=True)
    np.testing.assert_array_equal(a.acc["L_d"], b.acc["L_d"])
    assert not np.signbit(b.acc["L_d"][b.acc["L_d"] == 0]).any()
    env = np.array([0.2, 0.5, 1.0])
    pixel = np.arange(0, 1200, 3)
    a.splat("L_e", pixel, np.broadcast_to(env[:, None], (3, pixel.shape[0])))  # a read-only broadcast view
    b.splat("L_e", pixel, np.broadcast_to(env[:, None], (3, pixel.shape[0])), distinct=True)
    np.testing.assert_array_equal(a.acc["L_e"], b.acc["L_e"])


def test_weighted_splat_is_weight_times_rgb() -> None:
    rng = np.random.default_rng(4)
    pixel = rng.permutation(600)[:400]
    albedo = rng.random((3, 400))
    q = rng.random((3, 400)).astype(np.float32)  # the field's float32 radiance
    ref, a, b = Film(30, 20), Film(30, 20), Film(30, 20)
    ref.splat("L_i", pixel, albedo * q)
    a.splat("L_i", pixel, q, weight=albedo)
    b.splat("L_i", pixel, q, distinct=True, weight=albedo)
    np.testing.assert_array_equal(a.acc["L_i"], ref.acc["L_i"])
    np.testing.assert_array_equal(b.acc["L_i"], ref.acc["L_i"])


def test_layers_equal_the_numpy_means() -> None:
    """``layers()`` (one numba pass) rounds like ``(acc * scale).T.reshape(H, W, 3).astype(float32)`` and sums
    L as ``(L_e + L_d) + L_i`` in float32, overflow to inf included."""
    rng = np.random.default_rng(5)
    film = Film(7, 5)
    film.samples = 3
    for a in film.acc.values():
        a[:] = rng.normal(size=a.shape) * 10.0 ** rng.integers(-40, 40, size=a.shape)
    film.acc["L_d"][:, ::4] = 1e300
    scale = 1.0 / 3
    with np.errstate(over="ignore", invalid="ignore"):
        ref = {k: (a * scale).T.reshape(5, 7, 3).astype(np.float32) for k, a in film.acc.items()}
        ref["L"] = ref["L_e"] + ref["L_d"] + ref["L_i"]
    out = film.layers()
    assert list(out) == ["L", "L_d", "L_i", "L_e"]
    for k, v in out.items():
        assert v.dtype == np.float32 and v.shape == (5, 7, 3)
        np.testing.assert_array_equal(v, ref[k])
