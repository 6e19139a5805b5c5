"""One light's power or colour among several (issue 16): maps that record each photon's light, estimates and fields
that keep the lights' parts apart, and the per-light rescale that follows such an edit without retraining.

Radiance is linear in each light's flux, so L_i = sum_l L_i,l and an edit that multiplies light l's flux by s_l (the
same kinds and places) gives sum_l s_l L_i,l: exact, if the parts are kept apart."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import make_model, make_run, small_field_config, tiny_scene_dict

pytest.importorskip("torch")

from photon_fields.runtime.cli.render import _main as render_main  # noqa: E402
from photon_fields.runtime.errors import InputError  # noqa: E402
from photon_fields.runtime.field.field import PhotonField  # noqa: E402
from photon_fields.runtime.photons.estimate import PhotonMapEstimator, map_for_scene  # noqa: E402
from photon_fields.runtime.photons.photon_map import PhotonMap, read_header  # noqa: E402
from photon_fields.runtime.scene.light_rescale import flux_rescale, per_light_rescale  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, scene_from_dict  # noqa: E402
from photon_fields.train.export.bundle import export_bundle  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

LAMP = {"type": "point", "position": [0.9, 0.2, 0.9], "color": [0.6, 0.75, 1.0], "power": 2.5}


def two_lights(folder: Path, **lamp_changes: object) -> Scene:
    """The tiny scene's sun and a lamp, the lamp edited by ``lamp_changes``."""
    d = tiny_scene_dict()
    d["lights"].append({**copy.deepcopy(LAMP), **lamp_changes})
    return scene_from_dict(d, folder)


def scene_dict_with_lamp(**lamp_changes: object) -> dict:
    d = tiny_scene_dict()
    d["lights"].append({**copy.deepcopy(LAMP), **lamp_changes})
    return d


def test_per_light_factors() -> None:
    sun = tiny_scene_dict()["lights"][0]
    doubled = per_light_rescale([sun, LAMP], [sun, dict(LAMP, power=5.0)])
    assert doubled == pytest.approx(np.array([[1, 1, 1], [2, 2, 2]]))
    assert per_light_rescale([sun, LAMP], [dict(sun, color=[0.5, 0.95, 1.7]), LAMP]) == pytest.approx(
        np.array([[0.5, 1, 2], [1, 1, 1]]))
    assert flux_rescale([sun, LAMP], [sun, dict(LAMP, power=5.0)]) is None  # not one common factor
    assert per_light_rescale([sun, LAMP], [sun, dict(LAMP, position=[0.0, 0.9, 0.9])]) is None  # moved
    assert per_light_rescale([sun, LAMP], [sun]) is None
    red = dict(LAMP, color=[1.0, 0.0, 0.0])
    assert per_light_rescale([sun, red], [sun, dict(red, color=[1.0, 0.2, 0.0])]) is None  # a dark channel lit


@pytest.fixture(scope="module")
def traced(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Scene]:
    folder = tmp_path_factory.mktemp("per_light")
    scene = two_lights(folder)
    return trace_photons(scene, 30_000, phases=(0.0,), seed=5, progress=False).save(folder / "m.npz"), scene


def test_a_map_records_each_photons_light(traced: tuple[Path, Scene]) -> None:
    path, scene = traced
    pmap = PhotonMap.load(path)
    assert pmap.light is not None and pmap.light_count == 2 and read_header(path).light_count == 2
    assert set(np.unique(pmap.light)) == {0, 1}
    older = PhotonMap(pmap.position, pmap.direction, pmap.power, pmap.phase, pmap.phases, pmap.scene_fingerprint,
                      pmap.emitted, pmap.meta)
    assert older.light_count == 1
    with pytest.raises(InputError, match="does not record which of 2 lights"):
        PhotonMapEstimator(older, scene.medium(), k=16, lights=2)


def test_the_parts_sum_to_the_estimate_and_each_is_its_lights(traced: tuple[Path, Scene]) -> None:
    """The per-light estimate's blocks add up to the plain estimate, and block l is the estimate from light l's
    photons alone (the other lights' powers zeroed)."""
    path, scene = traced
    pmap = PhotonMap.load(path)
    m = scene.medium()
    rng = np.random.default_rng(1)
    x = (m.bmin + rng.random((400, 3)) * m.bsize).T
    d = rng.normal(size=(3, 400))
    d /= np.linalg.norm(d, axis=0)
    together = PhotonMapEstimator(pmap, m, k=16)(x, d, 0.0)
    apart = PhotonMapEstimator(pmap, m, k=16, lights=2)(x, d, 0.0)
    assert apart.shape == (6, 400) and float(together.sum()) > 0
    np.testing.assert_allclose(apart[:3] + apart[3:], together, rtol=1e-12, atol=1e-300)
    for light in (0, 1):
        only = PhotonMap(pmap.position, pmap.direction, np.where((pmap.light == light)[:, None], pmap.power, 0.0)
                         .astype(np.float32), pmap.phase, pmap.phases, pmap.scene_fingerprint, pmap.emitted, pmap.meta)
        np.testing.assert_allclose(apart[3 * light:3 * light + 3], PhotonMapEstimator(only, m, k=16)(x, d, 0.0),
                                   rtol=1e-12, atol=1e-300)


def test_a_map_follows_one_lights_edit(traced: tuple[Path, Scene], tmp_path: Path) -> None:
    """The lamp three times as bright: the map's lamp records times 3 (the sun's unchanged), and its mean estimate
    agrees with a map traced for the edited scene (block z-score over independent groups of points)."""
    path, scene = traced
    pmap = PhotonMap.load(path)
    brighter = two_lights(tmp_path, power=7.5)
    rescaled, warning, note = map_for_scene(pmap, brighter)
    assert warning is None and "light 2 (3, 3, 3)" in note and "light 1 (1, 1, 1)" in note
    np.testing.assert_allclose(rescaled.power, pmap.power * np.where(pmap.light == 1, 3.0, 1.0)[:, None], rtol=1e-6)
    fresh = trace_photons(brighter, 30_000, phases=(0.0,), seed=6, progress=False)
    m = scene.medium()
    rng = np.random.default_rng(2)
    x = (m.bmin + rng.random((4000, 3)) * m.bsize).T
    d = rng.normal(size=(3, 4000))
    d /= np.linalg.norm(d, axis=0)
    a = PhotonMapEstimator(rescaled, m, k=16)(x, d, 0.0).sum(axis=0).reshape(20, -1).mean(axis=1)
    b = PhotonMapEstimator(fresh, m, k=16)(x, d, 0.0).sum(axis=0).reshape(20, -1).mean(axis=1)
    before = PhotonMapEstimator(pmap, m, k=16)(x, d, 0.0).sum(axis=0).reshape(20, -1).mean(axis=1)
    z = abs(a.mean() - b.mean()) / np.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
    assert z < 4.0, z
    assert b.mean() > 1.1 * before.mean()  # the edit is visible: the test can tell a rescale from none


@pytest.fixture(scope="module")
def bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small random field with two light channels, exported for the two-light scene."""
    folder = tmp_path_factory.mktemp("per_light_bundle")
    scene = two_lights(folder)
    m = scene.medium()
    cfg = small_field_config()
    cfg = type(cfg)(**{**{f: getattr(cfg, f) for f in cfg.__dataclass_fields__}, "light_channels": 2})
    run = make_run(folder / "run", make_model(cfg), m.bmin.tolist(), m.bsize.tolist(), scene.fingerprint())
    return export_bundle(run, scene=scene).path


def test_a_field_sums_its_lights_parts_with_their_factors(bundle: Path, tmp_path: Path) -> None:
    manifest = json.loads((bundle / "manifest.json").read_text())
    assert manifest["field"]["light_channels"] == 2 and manifest["output"]["channels"] == 6
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.4, 0.4, (64, 3))
    d = rng.normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)

    def load(scene: Scene) -> PhotonField:
        return PhotonField.load(bundle, expected_fingerprint=scene.fingerprint(),
                                expected_parts=scene.fingerprint_parts(), expected_lights=scene.light_identities())

    trained = load(two_lights(tmp_path))
    parts = trained.query_lights(x, d, 0.2)
    assert parts.shape == (64, 2, 3) and trained.light_scale is None
    np.testing.assert_allclose(trained.query(x, d, 0.2), parts.sum(axis=1), rtol=1e-6)
    edited = load(two_lights(tmp_path, power=7.5, color=[0.6, 0.75, 0.5]))
    assert edited.light_scale == pytest.approx(np.array([[1, 1, 1], [3, 3, 1.5]])) and edited.scene_warning is None
    assert "light 2 (3, 3, 1.5)" in edited.light_note
    np.testing.assert_allclose(edited.query(x, d, 0.2), parts[:, 0] + parts[:, 1] * [3.0, 3.0, 1.5], rtol=1e-5)
    # a further edit of the loaded scene's lights (the viewer's) applies on top of the load's rescale
    np.testing.assert_allclose(edited.query(x, d, 0.2, np.array([[2, 2, 2], [1, 1, 1]])),
                               parts[:, 0] * 2.0 + parts[:, 1] * [3.0, 3.0, 1.5], rtol=1e-5)
    with pytest.raises(InputError, match="lights differ"):
        load(two_lights(tmp_path, position=[0.0, 0.9, 0.9]))


def test_pfn_render_follows_one_lights_edit(bundle: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene_file = tmp_path / "lamp.json"
    scene_file.write_text(json.dumps(scene_dict_with_lamp(power=5.0)))
    out = tmp_path / "r.exr"
    assert render_main(["--method", "field", "--bundle", str(bundle), "--scene", str(scene_file), "--size", "8x8",
                        "--spp", "1", "--out", str(out), "--quiet"]) == 0
    assert "light 2 (2, 2, 2)" in capsys.readouterr().err
    report = json.loads(out.with_suffix(".json").read_text())
    np.testing.assert_allclose(report["field"]["light_scale"], [[1, 1, 1], [2, 2, 2]], rtol=1e-6)
    assert report["warnings"] == []


def test_the_viewer_follows_one_lights_edit_with_a_field_of_light_channels(bundle: Path, tmp_path: Path) -> None:
    """The page doubles the lamp: with a field of two light channels L_i is rescaled per light (not stale), and the
    neural frame's L_i is the field's parts summed with the factors (the same samples, seed and frame)."""
    from dataclasses import replace

    from photon_fields.runtime.viewer.field_in_use import FieldInUse
    from photon_fields.runtime.viewer.light_control import LightControl

    scene = two_lights(tmp_path).with_overrides(width=12, height=12)
    field = PhotonField.load(bundle, expected_fingerprint=scene.fingerprint())
    in_use = FieldInUse(scene, estimator=field.estimator())
    controls = [LightControl.from_light(light) for light in scene.lights]
    lamp = [controls[0], replace(controls[1], power=controls[1].power * 2.0)]
    assert in_use.kept_apart() == 2 and not in_use.stale(scene.tf, lamp)
    np.testing.assert_allclose(in_use.indirect_scale(lamp), [[1, 1, 1], [2, 2, 2]], rtol=1e-12)
    plain = in_use.render(scene, "neural", seed=3, n=0, lights=controls)["L_i"]
    doubled = in_use.render(scene, "neural", seed=3, n=0, lights=lamp)["L_i"]
    expected = FieldInUse(scene, estimator=field.estimator(np.array([[1, 1, 1], [2, 2, 2]], np.float32)))
    np.testing.assert_allclose(doubled, expected.render(scene, "neural", seed=3, n=0, lights=controls)["L_i"],
                               rtol=1e-5)
    assert float(doubled.sum()) > float(plain.sum()) > 0.0
    of_the_sum = FieldInUse(scene, estimator=lambda x, d, g: field.estimator()(x, d, g))  # no light channels
    assert of_the_sum.kept_apart() == 1 and of_the_sum.stale(scene.tf, lamp)
