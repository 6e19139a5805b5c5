"""Field evaluation (train.eval.field_images): the torch field behind the renderer's estimator interface, and image
scores that tell a trained field from an untrained one and pick the right reference map for each g."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from conftest import tiny_scene_dict  # noqa: E402

from photon_fields.models_spec.encoding import FieldConfig, direction_input, normalize_position  # noqa: E402
from photon_fields.models_spec.hashgrid import HashGridConfig  # noqa: E402
from photon_fields.runtime.scene.scene import scene_from_dict  # noqa: E402
from photon_fields.train.eval.field_images import TorchFieldEstimator, evaluate_field, held_out_cameras, reference_maps  # noqa: E402
from photon_fields.train.field.network import TorchPhotonField  # noqa: E402
from photon_fields.train.fit.loop import fit  # noqa: E402
from photon_fields.train.fit.settings import FitSettings  # noqa: E402
from photon_fields.train.photons.tracing import trace_photons  # noqa: E402

PHASES = (-0.75, 0.0, 0.75)


def _random_field(seed: int = 0) -> TorchPhotonField:
    cfg = FieldConfig(HashGridConfig(3, 4, 2, 12, 4, 2.0), HashGridConfig(2, 2, 2, 8, 4, 2.0), 16, 2, 5.0, PHASES)
    model = TorchPhotonField(cfg, seed=seed)
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for t in model.table_parameters():
            t.copy_(torch.randn(t.shape, generator=gen) * 0.5)
    return model


def test_estimator_feeds_the_field_world_points_and_travel_directions(tmp_path) -> None:  # noqa: ANN001
    scene = scene_from_dict(tiny_scene_dict(), tmp_path)
    m = scene.medium()
    model = _random_field()
    rng = np.random.default_rng(1)
    n = 1000
    x = m.bmin[:, None] + rng.random((3, n)) * m.bsize[:, None]
    d = rng.standard_normal((3, n))
    d /= np.linalg.norm(d, axis=0)
    q = TorchFieldEstimator(model, m, chunk=77)(x, d, 0.35)
    with torch.no_grad():
        ref = model.radiance(torch.from_numpy(normalize_position(x.T, m.bmin, m.bsize)),
                             torch.from_numpy(direction_input(d.T)), torch.full((n, 1), 0.35)).numpy().T
    assert q.shape == (3, n)
    np.testing.assert_array_equal(q, ref)  # chunking changes nothing
    # The direction really reaches the field: reversing d changes Q for a field with random tables.
    assert not np.allclose(TorchFieldEstimator(model, m)(x, -d, 0.35), q)


def test_trained_field_scores_better_than_untrained_and_refuses_untraced_g(tmp_path) -> None:  # noqa: ANN001
    scene = scene_from_dict(tiny_scene_dict(), tmp_path)
    pmap = trace_photons(scene, 60_000, phases=PHASES, seed=3, progress=False)
    settings = FitSettings.from_preset("tiny", steps=150, batch=1024, k=64, sampling="support", schedule_kind="naive",
                                       val_points=512, checkpoint_every=1000)
    trained = fit(scene, pmap, tmp_path / "run", settings, progress=False).model
    untrained = TorchPhotonField(trained.cfg, seed=0)
    cams = held_out_cameras(scene, 24)
    assert len(cams) == 2 and not np.allclose(cams[0].eye, scene.camera.eye)
    kw = {"spp": 1, "k": 64, "radius": 0.05, "cameras": cams, "cache": {}}
    good = evaluate_field(scene, trained, [pmap], (0.0,), **kw)
    bad = evaluate_field(scene, untrained, [pmap], (0.0,), **kw)
    assert len(kw["cache"]) == 2  # the photon-map references were rendered once for both fields
    assert good["rel_l2_in_G"] < 0.6 * bad["rel_l2_in_G"]
    assert good["ssim_in_G"] > bad["ssim_in_G"]
    assert good["rel_l2_outside_G"] is None
    ref = reference_maps(scene, pmap, (0.35,))
    assert ref.phases == (0.35,) and abs(len(ref) - len(pmap) // 3) < 50  # paths finish past the quota
    out = evaluate_field(scene, trained, [pmap, ref], (0.35,), **kw)
    assert out["rel_l2_in_G"] is None and np.isfinite(out["rel_l2_outside_G"])
    with pytest.raises(ValueError, match="g = -0.35"):
        evaluate_field(scene, trained, [pmap, ref], (-0.35,), **kw)
