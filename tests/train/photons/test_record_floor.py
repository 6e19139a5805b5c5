"""Photon records with a floor (``runtime/photons/photon_path.py``): records at null collisions, weighted by
Phi / max(sigma_t, q majorant), estimate the same light as real collisions alone and bound the weights; without a
floor the tracing is delta tracking draw for draw."""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import constant_tf, small_camera
from numba import njit

from photon_fields.models_spec.photon_map import RECORD_FLOOR
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.estimate import PhotonMapEstimator
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.photons.photon_path import record_densities
from photon_fields.runtime.scene.lights import DirectionalLight
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import Medium
from photon_fields.runtime.transport.rng import stream_state
from photon_fields.runtime.transport.tracking import delta_track, record_track
from photon_fields.train.photons.tracing import trace_photons

FLOOR = 0.3


@pytest.fixture(scope="module")
def speckled() -> Scene:
    """Voxels dense (1) or nearly empty (0.02) at random: inside a macrocell sigma_t falls to a sliver of its
    majorant between voxels, where real-collision records are rare and heavy and null records are made."""
    rng = np.random.default_rng(0)
    density = np.where(rng.random((16, 16, 16)) < 0.5, 1.0, 0.02)
    vol = make_volume(density, window=(0.0, 1.0), name="speckled")
    return Scene(vol, constant_tf(40.0, 0.9), (DirectionalLight([-0.4, -1.0, -0.2], [1, 1, 1], 3.0),),
                 small_camera(16), 0.0, "speckled")


@njit(cache=True)
def _both_walks(m: Medium, o: np.ndarray, d: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Per ray, the distance of delta tracking and of record tracking without a floor, and how many of the
    streams differ afterwards."""
    n = o.shape[0]
    a, b = np.empty(n), np.empty(n)
    differ = 0
    for i in range(n):
        st = stream_state(np.uint64(seed), np.uint64(i))
        a[i], sa = delta_track(m, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2], 0.0, 10.0, st)
        b[i], real, sb = record_track(m, o[i, 0], o[i, 1], o[i, 2], d[i, 0], d[i, 1], d[i, 2], 0.0, 10.0, st, 0.0)
        if sa != sb or (np.isfinite(b[i]) and not real):
            differ += 1
    return a, b, differ


def test_without_a_floor_record_tracking_is_delta_tracking(speckled: Scene) -> None:
    """Floor 0: the same collisions from the same random numbers (so maps traced before the floor existed are
    what tracing with floor 0 gives, seed for seed)."""
    m = speckled.medium()
    rng = np.random.default_rng(1)
    o = m.bmin + rng.random((3000, 3)) * m.bsize
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a, b, differ = _both_walks(m, o, d, 5)
    assert differ == 0 and np.array_equal(a, b)
    assert 0.2 < np.isfinite(a).mean() < 0.99  # both kinds of ray: collided and escaped


def _ball_estimates(scene: Scene, floor: float, seeds: range, x: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(seeds, 3, n): the photon-map estimate at x, d of one map per seed, each query over a ball of fixed
    radius (K above any ball's count), whose mean is the same for any unbiased map."""
    out = []
    for seed in seeds:
        pmap = trace_photons(scene, 40_000, phases=(0.0,), seed=seed, progress=False, record_floor=floor)
        est = PhotonMapEstimator(pmap, scene.medium(), k=8192, radius=0.12)
        out.append(est(x, d, 0.0))
        assert max(int(f.max()) for f in est.found) < 8192  # every ball was the full radius
    return np.stack(out)


def test_records_with_a_floor_estimate_the_same_light(speckled: Scene) -> None:
    """Maps with and without the floor, over six seeds each: per block of query points the two estimates'
    means agree (z < 4.5), and so do the whole means; the floor's map holds null records (records where
    sigma_t < q majorant, more than real collisions alone put there), and its heaviest weight over the mean
    weight is several times smaller."""
    m = speckled.medium()
    rng = np.random.default_rng(2)
    x = (m.bmin + 0.15 + rng.random((400, 3)) * (m.bsize - 0.3)).T
    d = rng.normal(size=(3, 400))
    d /= np.linalg.norm(d, axis=0)
    plain = _ball_estimates(speckled, 0.0, range(6), x, d)[:, 0].reshape(6, 20, 20).mean(axis=2)
    floored = _ball_estimates(speckled, FLOOR, range(10, 16), x, d)[:, 0].reshape(6, 20, 20).mean(axis=2)
    diff = plain.mean(0) - floored.mean(0)
    se = np.sqrt(plain.var(0, ddof=1) / 6 + floored.var(0, ddof=1) / 6)
    assert np.all(np.abs(diff) / se < 4.5), np.abs(diff) / se
    whole = abs(plain.mean() - floored.mean()) / math.sqrt(plain.mean(1).var(ddof=1) / 6
                                                           + floored.mean(1).var(ddof=1) / 6)
    assert whole < 4.0, (plain.mean(), floored.mean(), whole)

    maps = {q: trace_photons(speckled, 40_000, phases=(0.0,), seed=3, progress=False, record_floor=q)
            for q in (0.0, FLOOR)}
    sliver = {q: record_densities(m, p.position.astype(np.float64).T, FLOOR)
              > record_densities(m, p.position.astype(np.float64).T, 0.0) for q, p in maps.items()}
    assert sliver[FLOOR].mean() > 1.5 * sliver[0.0].mean()
    heaviest = {q: (w := p.power[:, 0] / record_densities(m, p.position.astype(np.float64).T, q)).max() / w.mean()
                for q, p in maps.items()}
    assert heaviest[FLOOR] * 3.0 < heaviest[0.0], heaviest


def test_a_floor_map_records_it_and_bad_floors_are_refused(speckled: Scene, tmp_path: Path) -> None:
    pmap = trace_photons(speckled, 5_000, phases=(0.0,), seed=1, progress=False, record_floor=FLOOR)
    path = pmap.save(tmp_path / "m.npz")
    assert PhotonMap.load(path).record_floor == FLOOR
    assert trace_photons(speckled, 5_000, phases=(0.0,), seed=1, progress=False).record_floor == RECORD_FLOOR > 0
    assert trace_photons(speckled, 5_000, phases=(0.0,), seed=1, progress=False, record_floor=0.0).record_floor == 0
    b = pmap.bounce.astype(int)  # a null record has the number of the collision it precedes
    assert b.min() == 2 and np.all((b[1:] == 2) | (b[1:] == b[:-1]) | (b[1:] == b[:-1] + 1))
    assert np.any((b[1:] == b[:-1]) & (b[1:] > 2))
    with zipfile.ZipFile(path) as z:
        meta = json.loads(np.load(path)["meta"].tobytes())
        arrays = {n: z.read(n) for n in z.namelist() if n != "meta.npy"}
    meta["record_floor"] = 1.5
    bad = tmp_path / "bad.npz"
    with zipfile.ZipFile(bad, "w") as z:
        for n, data in arrays.items():
            z.writestr(n, data)
        with z.open("meta.npy", "w") as f:
            np.save(f, np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))
    with pytest.raises(InputError, match="record_floor"):
        PhotonMap.load(bad)
    with pytest.raises(InputError, match="record_floor"):
        trace_photons(speckled, 100, record_floor=1.0, progress=False)
