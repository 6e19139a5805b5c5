"""A light's power or colour edit is a rescale of L_i, not a retrain (issue 16): the factor, its premise (the same
photon paths with their power scaled), a bundle loaded for an edited scene, and ``pfn-render`` with one.

Radiance is linear in a light's flux, so a field trained for lights F answers for lights s * F (one RGB factor s for
every light, the same kinds and geometry) with s times its L_i; anything else is still a mismatch."""

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
from photon_fields.runtime.scene.light_rescale import flux_rescale  # noqa: E402
from photon_fields.runtime.scene.scene import Scene, scene_from_dict  # noqa: E402
from photon_fields.train.export.bundle import export_bundle  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

SUN = {"type": "directional", "direction": [-0.5, -0.8, 0.3], "color": [1.0, 0.95, 0.85], "power": 3.0}
LAMP = {"type": "point", "position": [0.9, 0.2, 0.9], "color": [0.6, 0.75, 1.0], "power": 0.6}


def lit(*lights: dict, **changes: object) -> list[dict]:
    """Copies of ``lights`` with ``changes`` applied to the first."""
    out = [copy.deepcopy(light) for light in lights]
    out[0].update(changes)
    return out


@pytest.mark.parametrize(("edited", "expected"), [
    (lit(SUN), [1.0, 1.0, 1.0]),
    (lit(SUN, power=4.5), [1.5, 1.5, 1.5]),
    (lit(SUN, color=[0.5, 0.95, 1.7]), [0.5, 1.0, 2.0]),
    (lit(SUN, power=6.0, color=[0.5, 0.95, 0.85]), [1.0, 2.0, 2.0]),
])
def test_one_light_any_power_or_colour_is_a_rescale(edited: list[dict], expected: list[float]) -> None:
    assert flux_rescale([SUN], edited) == pytest.approx(expected, rel=1e-12)


def test_several_lights_rescale_only_together() -> None:
    both = [dict(SUN, power=6.0), dict(LAMP, power=1.2)]
    assert flux_rescale([SUN, LAMP], both) == pytest.approx([2.0, 2.0, 2.0])
    assert flux_rescale([SUN, LAMP], [dict(SUN, power=6.0), LAMP]) is None  # needs per-light outputs


@pytest.mark.parametrize("edited", [
    lit(SUN, direction=[0.5, -0.8, 0.3]),                                   # moved
    [dict(LAMP, color=SUN["color"], power=3.0)],                            # another kind
    [SUN, LAMP],                                                            # another light added
    [],
    lit(SUN, power=float("nan")),
    [{k: v for k, v in SUN.items() if k != "power"}],                       # not a light dict
])
def test_anything_else_is_no_rescale(edited: list[dict]) -> None:
    assert flux_rescale([SUN], edited) is None


def test_a_channel_dark_in_training_cannot_be_lit_by_a_rescale() -> None:
    red = dict(SUN, color=[1.0, 0.0, 0.0])
    assert flux_rescale([red], [dict(red, power=6.0)]) == pytest.approx([2.0, 1.0, 1.0])
    assert flux_rescale([red], [dict(red, color=[1.0, 0.1, 0.0])]) is None


def test_environment_maps_compare_their_pixels_not_their_path() -> None:
    env = {"type": "environment_map", "path": "/a/sky.exr", "color": [1.0, 1.0, 1.0], "power": 1.0,
           "rotation": [0.0, 0.0, 0.0], "sha256": "ab"}
    assert flux_rescale([env], [dict(env, path="/b/moved.exr", power=2.0)]) == pytest.approx([2.0, 2.0, 2.0])
    assert flux_rescale([env], [dict(env, sha256="cd", power=2.0)]) is None
    assert flux_rescale([env], [dict(env, rotation=[90.0, 0.0, 0.0])]) is None


def scene_with(folder: Path, **light_changes: object) -> Scene:
    d = tiny_scene_dict()
    d["lights"][0].update(light_changes)
    return scene_from_dict(d, folder)


def test_the_premise_same_paths_with_their_power_scaled(tmp_path: Path) -> None:
    """One light: a power and colour edit traces the same photon paths, each record's power times s per channel."""
    base = trace_photons(scene_with(tmp_path), 4000, seed=3, progress=False)
    edited_scene = scene_with(tmp_path, power=6.0, color=[0.5, 0.95, 1.7])
    edited = trace_photons(edited_scene, 4000, seed=3, progress=False)
    s = flux_rescale(scene_with(tmp_path).light_identities(), edited_scene.light_identities())
    assert s == pytest.approx([1.0, 2.0, 4.0])
    np.testing.assert_array_equal(edited.position, base.position)
    np.testing.assert_array_equal(edited.direction, base.direction)
    np.testing.assert_allclose(edited.power, base.power * s.astype(np.float32), rtol=1e-6)


@pytest.fixture(scope="module")
def bundle(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small random field exported as the bundle of the tiny scene (its manifest records the scene's lights)."""
    folder = tmp_path_factory.mktemp("rescale")
    scene = scene_with(folder)
    m = scene.medium()
    run = make_run(folder / "run", make_model(small_field_config()), m.bmin.tolist(), m.bsize.tolist(),
                   scene.fingerprint())
    return export_bundle(run, scene=scene).path


def load_for(bundle: Path, scene: Scene) -> PhotonField:
    return PhotonField.load(bundle, expected_fingerprint=scene.fingerprint(), expected_parts=scene.fingerprint_parts(),
                            expected_lights=scene.light_identities())


def test_a_bundle_answers_for_its_lights_rescaled(bundle: Path, tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.4, 0.4, (64, 3))
    d = rng.normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    trained = load_for(bundle, scene_with(tmp_path))
    assert trained.light_scale is None and trained.light_note is None
    edited = load_for(bundle, scene_with(tmp_path, power=4.5, color=[0.5, 0.95, 1.7]))
    assert edited.light_scale == pytest.approx([0.75, 1.5, 3.0])
    assert "rescaled by (0.75, 1.5, 3)" in edited.light_note and edited.scene_warning is None
    np.testing.assert_allclose(edited.query(x, d, 0.2), trained.query(x, d, 0.2) * edited.light_scale, rtol=1e-6)
    np.testing.assert_array_equal(edited.query_encoded(x, d, 0.2), trained.query_encoded(x, d, 0.2))
    assert edited.describe()["light_scale"] == pytest.approx([0.75, 1.5, 3.0])


def test_a_moved_light_is_still_refused(bundle: Path, tmp_path: Path) -> None:
    with pytest.raises(InputError, match="lights differ"):
        load_for(bundle, scene_with(tmp_path, direction=[0.5, -0.8, 0.3]))


def test_pfn_render_says_it_rescaled(bundle: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = tiny_scene_dict()
    d["lights"][0]["power"] = 9.0
    scene_file = tmp_path / "brighter.json"
    scene_file.write_text(json.dumps(d))
    out = tmp_path / "r.exr"
    assert render_main(["--method", "field", "--bundle", str(bundle), "--scene", str(scene_file), "--size", "8x8",
                        "--spp", "1", "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "note: the lights differ from the field's only in power or colour" in err and "(3, 3, 3)" in err
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["field"]["light_scale"] == pytest.approx([3.0, 3.0, 3.0]) and report["warnings"] == []


def test_a_photon_map_answers_for_its_lights_rescaled(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A map records the lights it was traced with; rendering a scene whose lights are those rescaled uses the map
    with its powers rescaled (what tracing that scene gives), a moved light or a map without them is refused."""
    from photon_fields.runtime.photons.estimate import map_for_scene
    from photon_fields.runtime.photons.photon_map import PhotonMap

    scene = scene_with(tmp_path)
    path = trace_photons(scene, 3000, phases=(0.0,), seed=3, progress=False).save(tmp_path / "m.npz")
    pmap = PhotonMap.load(path)
    assert pmap.lights == scene.light_identities()
    brighter = scene_with(tmp_path, power=6.0, color=[0.5, 0.95, 1.7])
    same, warning, note = map_for_scene(pmap, scene)
    assert same is pmap and warning is None and note is None
    rescaled, warning, note = map_for_scene(pmap, brighter)
    traced = trace_photons(brighter, 3000, phases=(0.0,), seed=3, progress=False)
    np.testing.assert_allclose(rescaled.power, traced.power, rtol=1e-6)
    assert rescaled.scene_fingerprint == brighter.fingerprint() and warning is None and "(1, 2, 4)" in note
    with pytest.raises(InputError, match="lights differ"):
        map_for_scene(pmap, scene_with(tmp_path, direction=[0.5, -0.8, 0.3]))
    older = PhotonMap(pmap.position, pmap.direction, pmap.power, pmap.phase, pmap.phases, pmap.scene_fingerprint,
                      pmap.emitted, {k: v for k, v in pmap.meta.items() if k != "lights"})
    with pytest.raises(InputError, match="lights differ"):
        map_for_scene(older, brighter)
    d = tiny_scene_dict()
    d["lights"][0]["power"] = 9.0
    scene_file = tmp_path / "brighter.json"
    scene_file.write_text(json.dumps(d))
    capsys.readouterr()
    assert render_main(["--method", "photonmap", "--map", str(path), "--scene", str(scene_file), "--g", "0",
                        "--size", "8x8", "--spp", "1", "--out", str(tmp_path / "pm.exr"), "--quiet"]) == 0
    assert "note: the lights differ from the photon map's only in power or colour" in capsys.readouterr().err
