"""The "auto" camera estimator (runtime.wavefront.camera_choice): the probe band is the render's own middle rows, the
choice follows the probed noise ratio against COST_RATIO, agrees with an independent measurement of that ratio on
scenes on either side of it, is made once per scene, g and estimator type, and renders the chosen estimator's image
bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import tiny_scene_dict

from photon_fields.runtime.renderers.neural import render_neural
from photon_fields.runtime.renderers.ray_marcher import camera_light_volume
from photon_fields.runtime.scene.camera import Camera, orbit_camera
from photon_fields.runtime.scene.scene import Scene, scene_from_dict
from photon_fields.runtime.wavefront import camera_choice
from photon_fields.runtime.wavefront.camera_choice import AUTO, COST_RATIO, probe_band


def _tiny(name: str, size: int) -> Scene:
    d = tiny_scene_dict(name)
    d["camera"]["width"] = d["camera"]["height"] = size
    return scene_from_dict(d)


def _pixel_directions(cam: Camera) -> np.ndarray:
    """(height, width, 3) unit directions through the pixel centres."""
    origin, du, dv = cam.image_plane()
    x, y = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    d = origin + x[..., None] * du + y[..., None] * dv
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


@pytest.mark.parametrize("fov_axis", ["x", "y"])
def test_the_probe_band_is_the_full_cameras_middle_rows(fov_axis: str) -> None:
    scene = _tiny("blobs", 32).with_overrides(
        camera=Camera([1.25, 0.75, 1.45], [0, 0, 0], [0, 1, 0], 38.0, 40, 30, fov_axis))
    band = probe_band(scene, rays=40 * 6)
    assert (band.camera.width, band.camera.height) == (40, 6)
    full, part = _pixel_directions(scene.camera), _pixel_directions(band.camera)
    np.testing.assert_allclose(part, full[12:18], atol=1e-12)
    assert probe_band(scene, rays=40 * 30) is scene and probe_band(scene, rays=10**6) is scene


@pytest.mark.parametrize(("forced", "marched", "chosen"), [(4.1 * COST_RATIO, 4.0, "marched"),
                                                           (3.9 * COST_RATIO, 4.0, "forced")])
def test_the_choice_follows_the_probed_noise_ratio(forced: float, marched: float, chosen: str,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    calls = []

    def probed(scene: Scene, estimator: object, camera: str, light_volume: object, light_sampling: str) -> float:
        calls.append((camera, scene.camera.height, scene.g))
        return {"forced": forced, "marched": marched}[camera]

    monkeypatch.setattr(camera_choice, "noise_variance", probed)
    scene = _tiny("blobs", 256)  # 8192 probe rays: a band of 32 rows

    def lv() -> object:
        return camera_light_volume(scene, "marched")

    def resolve(view: Scene, spp: int = 1) -> str:
        return camera_choice.resolve_camera_estimator(view, None, AUTO, lv, "one", spp)

    # A render of fewer samples than a probe's rays takes forced unprobed, unless the choice was made.
    small = scene.with_overrides(camera=scene.camera.with_resolution(64, 64))
    assert resolve(small) == "forced" and calls == []
    assert resolve(scene) == chosen
    assert sorted(calls) == [("forced", 32, scene.g), ("marched", 32, scene.g)]
    # Kept with the scene: a camera move asks no new probe; another g, or pixels twice the size, do.
    moved = scene.with_overrides(camera=orbit_camera(scene.camera, 40.0))
    assert resolve(moved) == chosen and len(calls) == 2
    assert resolve(scene.with_overrides(g=0.5)) == chosen and len(calls) == 4
    coarse = scene.with_overrides(camera=scene.camera.with_resolution(128, 128))
    assert resolve(coarse) == chosen
    assert len(calls) == 6 and calls[-1][1] == 64  # the band: 8192 rays in rows of 128
    assert resolve(small, spp=2) == chosen and len(calls) == 8  # 64^2 x 2 samples: worth a probe
    assert resolve(small) == chosen and len(calls) == 8  # and now the choice is made for that size
    assert camera_choice.resolve_camera_estimator(scene, None, "delta", lv, "one", 1) == "delta"


def _independent_ratio(scene: Scene) -> float:
    """forced's noise variance over marched's from four seed pairs of their own (not the probe's), whole image."""
    var = {}
    for camera in ("forced", "marched"):
        pairs = [[render_neural(scene, None, spp=1, seed=s, progress=False, camera=camera).layers["L"]
                  for s in (2 * k + 100, 2 * k + 101)] for k in range(4)]
        var[camera] = np.mean([np.sum((a.astype(np.float64) - b) ** 2) for a, b in pairs])
    return var["forced"] / var["marched"]


@pytest.mark.parametrize(("name", "size", "chosen"), [("blobs", 64, "marched"), ("vortex", 32, "forced")])
def test_auto_chooses_the_estimator_with_less_noise_per_unit_of_work(name: str, size: int, chosen: str) -> None:
    """L_d alone (no field) of two tiny scenes, one on either side of COST_RATIO: the probe's choice is the side an
    independent measurement of the noise ratio puts the scene on, and the render is the chosen estimator's, bit
    for bit, with the choice in its stats (``spp`` enough for a probe: PROBE_RAYS samples)."""
    scene = _tiny(name, size)
    ratio = _independent_ratio(scene)
    assert (ratio > 1.5 * COST_RATIO) if chosen == "marched" else (ratio < COST_RATIO / 1.5), ratio
    spp = -(-camera_choice.PROBE_RAYS // (size * size))
    auto = render_neural(scene, None, spp=spp, seed=3, progress=False)
    assert auto.stats["camera_estimator"] == chosen
    same = render_neural(scene, None, spp=spp, seed=3, progress=False, camera=chosen)
    assert np.array_equal(auto.layers["L"], same.layers["L"])


def test_the_cost_ratio_grows_with_the_volumes_resolution(monkeypatch: pytest.MonkeyPatch) -> None:
    """COST_RATIO up to 96 voxels across, (n / 96) ^ COST_EXPONENT times it beyond; the choice weighs the probe's
    noise ratio against the scene's own cost ratio."""
    coarse, fine = _tiny("blobs", 256), scene_from_dict({**tiny_scene_dict("blobs"), "volume": {
        "builtin": "blobs", "resolution": 192}, "camera": {**tiny_scene_dict("blobs")["camera"], "width": 256,
                                                           "height": 256}})
    assert camera_choice.cost_ratio(coarse) == COST_RATIO
    assert camera_choice.cost_ratio(fine) == pytest.approx(COST_RATIO * 2.0**camera_choice.COST_EXPONENT)
    between = 0.5 * (1.0 + 2.0**camera_choice.COST_EXPONENT) * COST_RATIO  # above the coarse ratio, below the fine
    noise = {"forced": between, "marched": 1.0}
    monkeypatch.setattr(camera_choice, "noise_variance", lambda scene, est, camera, lv, ls: noise[camera])
    chosen = [camera_choice.resolve_camera_estimator(s, None, AUTO, lambda: None, "one", 1) for s in (coarse, fine)]
    assert chosen == ["marched", "forced"]
