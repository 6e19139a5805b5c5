"""Fitting a field that keeps the lights apart (``FieldConfig.light_channels``, issue 16): its targets, its loss and
what a fit of a two-light scene makes; the runtime side is tests/runtime/field/test_per_light.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import tiny_scene_dict

torch = pytest.importorskip("torch")

from photon_fields.runtime.scene.scene import scene_from_dict  # noqa: E402
from photon_fields.train.fit.loop import fit  # noqa: E402
from photon_fields.train.fit.loss import linear_relative_l2_loss  # noqa: E402
from photon_fields.train.fit.settings import FitSettings  # noqa: E402
from photon_fields.train.fit.targets import TargetSampler  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

LAMP = {"type": "point", "position": [0.9, 0.2, 0.9], "color": [0.6, 0.75, 1.0], "power": 2.5}


@pytest.fixture(scope="module")
def two_light_map(tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    d = tiny_scene_dict()
    d["lights"].append(dict(LAMP))
    scene = scene_from_dict(d, tmp_path_factory.mktemp("two"))
    return scene, trace_photons(scene, 60_000, seed=2, progress=False)


def test_per_light_targets_sum_to_the_targets(two_light_map) -> None:  # noqa: ANN001
    """The same draws give targets whose light blocks add up to the summed targets (same search, split by light)."""
    scene, pmap = two_light_map
    kw = {"k": 16, "psi": 5.0, "seed": 4, "sampling": "visible", "g_sampling": "window"}
    together = TargetSampler(pmap, scene.medium(), **kw).sample(512, 0.05)
    apart = TargetSampler(pmap, scene.medium(), lights=2, **kw).sample(512, 0.05)
    assert apart.q.shape == (512, 6) and apart.target.shape == (512, 6)
    np.testing.assert_array_equal(apart.pos.numpy(), together.pos.numpy())
    np.testing.assert_allclose(apart.q[:, :3] + apart.q[:, 3:], together.q, rtol=1e-12, atol=1e-300)
    assert float(apart.q[:, 3:].sum()) > 0.05 * float(apart.q.sum())  # the lamp lights a share of the targets


def test_per_light_loss_weighs_lights_by_the_sum() -> None:
    """With one light the loss is the plain relative L2; with two, each light's squared error over the sum's square:
    a prediction off by e in one light costs what a summed prediction off by e costs."""
    rng = np.random.default_rng(0)
    q = torch.from_numpy(rng.uniform(0.5, 2.0, (64, 6)).astype(np.float32))
    enc = -torch.log10(q) / 5.0
    assert float(linear_relative_l2_loss(enc, enc, 5.0, lights=2)) == 0.0
    off = q.clone()
    off[:, 3] *= 1.1  # the lamp's red 10 % high
    apart = float(linear_relative_l2_loss(-torch.log10(off) / 5.0, enc, 5.0, lights=2))
    summed_q, summed_off = q[:, :3] + q[:, 3:], off[:, :3] + off[:, 3:]
    together = float(linear_relative_l2_loss(-torch.log10(summed_off) / 5.0, -torch.log10(summed_q) / 5.0, 5.0))
    assert apart == pytest.approx(together, rel=1e-3)


def test_a_fit_of_two_lights_keeps_them_apart_unless_told(two_light_map, tmp_path: Path) -> None:  # noqa: ANN001
    scene, pmap = two_light_map
    apart = fit(scene, pmap, tmp_path / "apart", FitSettings.from_preset("tiny", steps=20), progress=False)
    assert apart.model.cfg.light_channels == 2 and apart.log["field_config"]["light_channels"] == 2
    together = fit(scene, pmap, tmp_path / "together", FitSettings.from_preset("tiny", steps=20, per_light=False),
                   progress=False)
    assert together.model.cfg.light_channels == 1 and "light_channels" not in together.log["field_config"]
    for run in (apart, together):
        assert np.isfinite(run.log["validation"][-1]["val_rel_l1"])


def test_pfn_train_fit_says_whether_the_lights_are_kept_apart(two_light_map, tmp_path: Path,  # noqa: ANN001
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """With the map's light records: "2 lights apart"; with a map traced before them: a note that the field will
    have one output (and why a light edit will need an update)."""
    import json

    from photon_fields.runtime.photons.photon_map import PhotonMap
    from photon_fields.train.cli.train import _main as train_main

    scene, pmap = two_light_map
    d = tiny_scene_dict()
    d["lights"].append(dict(LAMP))
    scene_file = tmp_path / "two.json"
    scene_file.write_text(json.dumps(d))
    pmap.save(tmp_path / "new.npz")
    PhotonMap(pmap.position, pmap.direction, pmap.power, pmap.phase, pmap.phases, pmap.scene_fingerprint,
              pmap.emitted, pmap.meta).save(tmp_path / "old.npz")
    for name in ("new", "old"):
        assert train_main(["fit", str(scene_file), "--map", str(tmp_path / f"{name}.npz"), "--preset", "tiny",
                           "--steps", "3", "--out", str(tmp_path / name), "--quiet"]) == 0
    out = capsys.readouterr()
    assert out.out.count("2 lights apart") == 1 and "does not record which light" in out.err


def test_pfn_train_fit_takes_a_map_of_the_same_lights_rescaled(two_light_map, tmp_path: Path,  # noqa: ANN001
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """A map traced before the lamp was made brighter fits the edited scene, rescaled per light (a note says so);
    a map whose lamp stood elsewhere is refused in one line."""
    import json

    from photon_fields.runtime.errors import InputError
    from photon_fields.train.cli.train import _main as train_main
    from photon_fields.train.fit.loop import load_map_for

    scene, pmap = two_light_map
    pmap.save(tmp_path / "m.npz")
    d = tiny_scene_dict()
    d["lights"].append({**LAMP, "power": 2 * LAMP["power"]})
    brighter = scene_from_dict(d, tmp_path)
    rescaled, note = load_map_for(brighter, tmp_path / "m.npz")
    assert "light 2 (2, 2, 2)" in note and rescaled.scene_fingerprint == brighter.fingerprint()
    np.testing.assert_allclose(rescaled.power, pmap.power * np.where(pmap.light == 1, 2.0, 1.0)[:, None], rtol=1e-6)
    (tmp_path / "brighter.json").write_text(json.dumps(d))
    assert train_main(["fit", str(tmp_path / "brighter.json"), "--map", str(tmp_path / "m.npz"), "--preset", "tiny",
                       "--steps", "2", "--out", str(tmp_path / "run"), "--quiet"]) == 0
    assert "light 2 (2, 2, 2)" in capsys.readouterr().err
    d["lights"][1]["position"] = [0.0, 0.9, 0.9]
    with pytest.raises(InputError, match="lights differ"):
        load_map_for(scene_from_dict(d, tmp_path), tmp_path / "m.npz")


def test_torch_and_runtime_agree_on_a_per_light_rescale(two_light_map, tmp_path: Path) -> None:  # noqa: ANN001
    """The torch field's radiance with per-light factors (the benches' estimator) is the exported bundle's query
    with the same factors (the renderers'), and the factors act on each light's part."""
    from photon_fields.models_spec.encoding import direction_input, normalize_position
    from photon_fields.runtime.field.field import PhotonField
    from photon_fields.train.export.bundle import export_bundle, write_run_domain

    scene, pmap = two_light_map
    run = tmp_path / "run"
    run.mkdir()
    write_run_domain(run, scene)
    model = fit(scene, pmap, run, FitSettings.from_preset("tiny", steps=5), progress=False).model
    field = PhotonField.load(export_bundle(run, scene=scene).path)
    m = scene.medium()
    rng = np.random.default_rng(1)
    x = m.bmin + rng.random((256, 3)) * m.bsize
    d = rng.normal(size=(256, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    scale = np.array([[1.0, 1.0, 1.0], [3.0, 0.5, 2.0]], np.float32)
    with torch.no_grad():
        args = (torch.from_numpy(normalize_position(x, m.bmin, m.bsize)), torch.from_numpy(direction_input(d)),
                torch.full((256, 1), 0.1))
        scaled = model.radiance(*args, torch.from_numpy(scale)).numpy()
        plain = model.radiance(*args).numpy()
    np.testing.assert_allclose(field.query(x, d, 0.1, scale), scaled, rtol=1e-4, atol=1e-7)
    parts = field.query_lights(x, d, 0.1)
    np.testing.assert_allclose(scaled, parts[:, 0] + parts[:, 1] * scale[1], rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(plain, parts.sum(axis=1), rtol=1e-4, atol=1e-7)
