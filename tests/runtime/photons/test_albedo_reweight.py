"""An edit of the albedo alone reweights the earlier map's paths exactly (issue 16,
``runtime/photons/albedo_reweight.py``): the path records it needs, the reweight against a fresh trace of the edited
scene, thinning, and the cases it must refuse."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from conftest import tiny_scene_dict

from photon_fields.runtime.photons.albedo_reweight import albedo_only, reweight_albedo
from photon_fields.runtime.photons.estimate import PhotonMapEstimator
from photon_fields.runtime.scene.scene import Scene, scene_from_dict
from photon_fields.runtime.transport.medium import scalar_at
from photon_fields.train.photons.tracing import trace_photons

TF = {"name": "coloured", "density_scale": 60.0,
      "points": [{"s": 0.0, "albedo": [0.9, 0.8, 0.7], "opacity": 0.0},
                 {"s": 0.3, "albedo": [0.9, 0.8, 0.7], "opacity": 0.6},
                 {"s": 1.0, "albedo": [0.5, 0.9, 0.95], "opacity": 1.0}]}


def scene_with(folder: Path, albedo: list[list[float]] | None = None, **tf_changes: object) -> Scene:
    d = tiny_scene_dict()
    tf = copy.deepcopy(TF)
    if albedo is not None:
        for p, a in zip(tf["points"], albedo, strict=True):
            p["albedo"] = a
    tf.update(tf_changes)
    d["transfer_function"] = tf
    return scene_from_dict(d, folder)


BLUER = [[0.6, 0.8, 0.95], [0.6, 0.8, 0.95], [0.3, 0.9, 0.99]]


@pytest.fixture(scope="module", params=[0.0, 0.3], ids=["real-records", "record-floor"])
def base(tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest):  # noqa: ANN201
    """The scene and its map: records at real collisions only, or with null records too (a record floor,
    ``runtime/photons/photon_path.py``), which carry the collision number and history of the collision they
    precede."""
    scene = scene_with(tmp_path_factory.mktemp("albedo"))
    return scene, trace_photons(scene, 40_000, phases=(0.0,), seed=4, progress=False, record_floor=request.param)


def test_a_paths_records_are_consecutive_and_know_the_previous_collision(base) -> None:  # noqa: ANN001
    """Records of a path follow each other with bounce 2, 3, ... (a null record repeats the number of the real
    collision after it); a record's prev_scalar is the scalar at the previous real collision: the last record
    of the number before (the first collision's is kept at the records of bounce 2)."""
    scene, pmap = base
    m = scene.medium()
    b = pmap.bounce.astype(int)
    repeats = (b[1:] == b[:-1]) & (b[1:] > 2)
    assert b.min() == 2 and np.all((b[1:] == 2) | (b[1:] == b[:-1] + 1) | repeats)
    assert np.any(repeats) == (pmap.record_floor > 0)
    same = np.flatnonzero(repeats) + 1  # a null record and the next record of its number: the same arriving power
    np.testing.assert_array_equal(pmap.power[same], pmap.power[same - 1])
    later = np.flatnonzero(b[1:] == b[:-1] + 1) + 1
    prev = np.array([scalar_at(m, *pmap.position[i - 1].astype(np.float64)) for i in later[:500]])
    np.testing.assert_allclose(pmap.prev_scalar[later[:500]], prev, rtol=1e-5, atol=1e-6)


def test_the_same_albedo_reweights_to_the_same_map(base, tmp_path: Path) -> None:  # noqa: ANN001
    scene, pmap = base
    same = reweight_albedo(pmap, scene.medium(), scene.medium(), scene)
    assert same is not None
    np.testing.assert_array_equal(same.power, pmap.power)


def test_an_albedo_edit_reweights_like_a_fresh_trace(base, tmp_path: Path) -> None:  # noqa: ANN001
    """The bluer scene: the reweighted map (whole, and thinned to half its paths) estimates what a map traced for
    it does (block z-scores over independent groups of points, per channel), and differs visibly from the
    unedited map; a null record's power changes as the collision's it precedes."""
    scene, pmap = base
    bluer = scene_with(tmp_path, BLUER)
    assert albedo_only(scene.medium(), bluer.medium())
    whole = reweight_albedo(pmap, scene.medium(), bluer.medium(), bluer)
    half = reweight_albedo(pmap, scene.medium(), bluer.medium(), bluer, keep=0.5, seed=1)
    fresh = trace_photons(bluer, 40_000, phases=(0.0,), seed=5, progress=False)
    assert whole.scene_fingerprint == bluer.fingerprint() and 0.45 < len(half) / len(pmap) < 0.55
    m = bluer.medium()
    rng = np.random.default_rng(3)
    x = (m.bmin + rng.random((4000, 3)) * m.bsize).T
    d = rng.normal(size=(3, 4000))
    d /= np.linalg.norm(d, axis=0)

    def blocks(p):  # noqa: ANN001, ANN202
        return PhotonMapEstimator(p, m, k=16)(x, d, 0.0).reshape(3, 20, -1).mean(axis=2)

    want = blocks(fresh)
    for got in (blocks(whole), blocks(half)):
        z = np.abs(got.mean(1) - want.mean(1)) / np.sqrt(got.var(1, ddof=1) / 20 + want.var(1, ddof=1) / 20)
        assert np.all(z < 4.0), z
    before = blocks(pmap).mean(1)
    assert want.mean(1)[0] < 0.9 * before[0] and want.mean(1)[2] > 1.05 * before[2]  # the edit shows
    b = pmap.bounce.astype(int)
    same = np.flatnonzero((b[1:] == b[:-1]) & (b[1:] > 2)) + 1  # a null record shares its collision's history
    np.testing.assert_allclose(whole.power[same], whole.power[same - 1], rtol=1e-6)


def test_what_cannot_be_reweighted(base, tmp_path: Path) -> None:  # noqa: ANN001
    scene, pmap = base
    denser = scene_with(tmp_path, density_scale=90.0)
    assert not albedo_only(scene.medium(), denser.medium())
    assert reweight_albedo(pmap, scene.medium(), denser.medium(), denser) is None
    no_red = scene_with(tmp_path, [[0.0, 0.8, 0.7]] * 3)
    red_again = scene_with(tmp_path, [[0.5, 0.8, 0.7]] * 3)
    traced = trace_photons(no_red, 5_000, phases=(0.0,), seed=4, progress=False)
    assert reweight_albedo(traced, no_red.medium(), red_again.medium(), red_again) is None  # red was never carried
    older = copy.copy(pmap)
    older.bounce = older.prev_scalar = None
    assert reweight_albedo(older, scene.medium(), scene_with(tmp_path, BLUER).medium(), scene) is None


@pytest.mark.parametrize(("change", "problem"), [
    ({"bounce": None}, "without the other"),
    ({"bounce": "low"}, "'bounce' below 2"),
    ({"light": "beyond"}, "indexes lights"),
])
def test_inconsistent_path_and_light_records_are_refused(base, tmp_path: Path, change: dict,  # noqa: ANN001
                                                         problem: str) -> None:
    """The optional arrays are checked at load: both path arrays or neither, collision numbers from 2, light indices
    among the recorded lights; one line naming the file."""
    from photon_fields.runtime.errors import InputError
    from photon_fields.runtime.photons.photon_map import PhotonMap

    _, pmap = base
    path = pmap.save(tmp_path / "m.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    for name, how in change.items():
        if how is None:
            del arrays[name]
        elif how == "low":
            arrays[name] = np.ones_like(arrays[name])
        else:
            arrays[name] = np.full_like(arrays[name], 7)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError, match=problem) as info:
        PhotonMap.load(tmp_path / "bad.npz")
    assert "bad.npz" in str(info.value)
