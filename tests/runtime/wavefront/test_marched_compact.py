"""marched_camera.compact_marched: the interacting items' picks, pick-major, with their salted random streams."""

from __future__ import annotations

import numpy as np

from photon_fields.runtime.wavefront.marched_camera import _INTERACTED, _PICK_SALT, MarchedItems, compact_marched


def _reference(items: MarchedItems, start: int, n_pixels: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The same copies written with numpy's takes and tiles."""
    idx = np.flatnonzero(items.status == _INTERACTED)
    kept = MarchedItems(*(a[..., idx] for a in (items.x, items.d, items.albedo, items.weight, items.rng, items.cached,
                                                items.cached_at_pick, items.status, items.transmit)))
    picks = kept.x.shape[0]
    rng = np.concatenate([kept.rng ^ np.uint64(_PICK_SALT * q % 2**64) for q in range(picks)])
    flat = [np.tile((start + idx) % n_pixels, picks), kept.x.transpose(1, 0, 2).reshape(3, -1),
            np.tile(kept.d, (1, picks)), kept.albedo.transpose(1, 0, 2).reshape(3, -1), rng, kept.weight.reshape(-1)]
    return flat, [kept.cached, kept.cached_at_pick.transpose(1, 0, 2).reshape(3, -1)]


def test_compact_marched_copies_every_pick_of_every_interacting_item() -> None:
    rng = np.random.default_rng(4)
    n, picks, start, n_pixels = 3000, 3, 5000, 4096
    items = MarchedItems.empty(n, picks)
    for name in ("x", "d", "albedo", "weight", "cached", "cached_at_pick", "transmit"):
        getattr(items, name)[...] = rng.normal(size=getattr(items, name).shape)
    items.rng[:] = rng.integers(0, 2**63, n, dtype=np.uint64) * np.uint64(2) + np.uint64(1)
    items.status[:] = rng.integers(0, 3, n)
    flat, cached = compact_marched(items, start, n_pixels)
    want, want_cached = _reference(items, start, n_pixels)
    k = int(np.count_nonzero(items.status == _INTERACTED))
    assert flat.rays == k and flat.pixel.shape == (picks * k,)
    for got, expected in zip((flat.pixel, flat.x, flat.d, flat.albedo, flat.rng, flat.weight), want, strict=True):
        assert got.dtype == expected.dtype and np.array_equal(got, expected)
    assert np.array_equal(cached.strata, want_cached[0]) and np.array_equal(cached.at_pick, want_cached[1])
    assert np.array_equal(flat.rng[:k], items.rng[items.status == _INTERACTED])  # the first pick keeps the walk's state
    assert len(set(flat.rng[::k].tolist())) == picks  # the others get their own streams
