"""The ``auto`` transfer function (runtime/scene/auto_transfer.py): its range comes from the non-background voxels
and ignores outliers, every kind of volume shows structure (neither a solid block nor nothing), and scenes resolve
it when they are built, fingerprinting as the concrete function."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.auto_transfer import auto_transfer_function, background_level
from photon_fields.runtime.scene.scene import BUILTIN_SCENES, builtin_volume, scene_from_dict
from photon_fields.runtime.scene.transfer import TransferFunction, preset
from photon_fields.runtime.scene.volume import Volume, make_volume

N = 40


def _grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.meshgrid(*[np.linspace(-1, 1, N)] * 3, indexing="ij")


def ct_like(seed: int = 0) -> Volume:
    """Air at -1000 HU around soft tissue (~40 HU) in a shell of bone (1000 HU), and one metal voxel."""
    rng = np.random.default_rng(seed)
    x, y, z = _grid()
    r = np.sqrt(x**2 + y**2 + z**2)
    v = -1000 + rng.normal(0, 10, r.shape)
    v = np.where(r < 0.8, 40 + rng.normal(0, 10, r.shape), v)
    v = np.where((r > 0.7) & (r < 0.8), 1000, v)
    v[0, 0, 0] = 3000
    return make_volume(v, name="ct")


def mri_like(seed: int = 0) -> Volume:
    """A noise floor (20 +- 8) around patterned tissue (250 to 550) with dark ventricles (150)."""
    rng = np.random.default_rng(seed)
    x, y, z = _grid()
    r = np.sqrt(x**2 / 0.8 + y**2 + z**2 / 0.9)
    v = rng.normal(20, 8, r.shape).clip(0)
    v = np.where(r < 0.85, 400 + 150 * np.sin(6 * x) * np.cos(5 * y) + rng.normal(0, 20, r.shape), v)
    v = np.where(r < 0.3, 150, v)
    return make_volume(v, name="mri")


VOLUMES = {"ct": ct_like, "mri": mri_like,
           **{name: (lambda s=spec: builtin_volume(s["volume"], N)) for name, spec in BUILTIN_SCENES.items()}}


def transmittance(volume: Volume, tf: TransferFunction) -> np.ndarray:
    """Transmittance of the rays along z through the voxels that see something other than background."""
    _, ext = tf.evaluate(volume.data)
    T = np.exp(-ext.sum(axis=2) * volume.extent[2] / volume.dims[2])
    return T[volume.data.max(axis=2) > background_level(volume.data.ravel())]


@pytest.mark.parametrize("name", sorted(VOLUMES))
def test_every_kind_of_volume_shows_structure(name: str) -> None:
    """Across the rays through the object, transmittance spans a range: few rays are blocked outright (not a
    solid block) and a tenth of them lose most of their light (not nothing). A fixed ramp fails this on most
    of these volumes (checked below for the CT and the MRI), as a fixed density scale does."""
    volume = VOLUMES[name]()
    T = transmittance(volume, auto_transfer_function(volume))
    assert np.mean(T < 0.01) < 0.35, "a solid block"
    assert np.percentile(T, 10) < 0.3, "nearly nothing visible"
    assert np.percentile(T, 90) > 0.15, "hardly any ray gets through"


def test_a_fixed_ramp_fails_the_same_check() -> None:
    """The check above has teeth: the neutral grey_ramp preset renders the CT and the MRI as solid blocks."""
    for make in (ct_like, mri_like):
        volume = make()
        assert np.mean(transmittance(volume, preset("grey_ramp")) < 0.01) > 0.5


def test_range_comes_from_the_foreground_not_the_background() -> None:
    """A sphere of values spread evenly over [0.3, 0.9] in a volume that is 90 % empty: opacity rises over the
    sphere's values, not from 0 (where the percentiles of all voxels would put it)."""
    x, y, z = _grid()
    r = np.sqrt(x**2 + y**2 + z**2)
    inside = r < 0.5
    v = np.zeros(r.shape)
    v[inside] = np.random.default_rng(1).uniform(0.3, 0.9, inside.sum())
    v[-1, -1, -1] = 1.0  # so that the window is [0, 1]
    tf = auto_transfer_function(make_volume(v, window=(0, 1)))
    assert 0.3 <= tf.points[0] <= 0.36
    assert 0.88 <= tf.points[-1] <= 0.9
    assert tf.name == "auto"


def test_a_noise_floor_above_the_minimum_is_background() -> None:
    """An MRI's background is a peak of noise above its minimum: it is not part of the visible range."""
    volume = mri_like()
    tf = auto_transfer_function(volume)
    noise = volume.data[0, 0, :]  # a corner column: noise floor only
    assert np.all(tf.evaluate(noise)[1] == 0)


def test_outliers_do_not_stretch_the_range() -> None:
    """One metal voxel at 3000 HU: the range ends at the bone, not at the metal."""
    volume = ct_like()
    bone = (1000 + 1000) / 4000  # normalized by the data's min/max, about -1040 to 3000
    tf = auto_transfer_function(volume)
    assert tf.points[-1] == pytest.approx(bone, abs=0.02)


def test_density_scale_override_and_constant_volume() -> None:
    volume = ct_like()
    assert auto_transfer_function(volume, density_scale=40).density_scale == 40
    flat = auto_transfer_function(make_volume(np.full((4, 4, 4), 7.0)))
    assert flat.points[-1] - flat.points[0] >= 0.02 and flat.evaluate(np.ones(1))[1][0] > 0


def _scene(tf: object, volume: dict | None = None) -> dict:
    return {"name": "s", "volume": volume or {"builtin": "blobs", "resolution": 24}, "transfer_function": tf,
            "lights": [{"type": "directional", "direction": [0, -1, 0], "color": [1, 1, 1], "power": 2}],
            "camera": {"eye": [1, 1, 1], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 40, "width": 8, "height": 8}}


def test_scene_resolves_auto_and_fingerprints_as_the_concrete_function(tmp_path: Path) -> None:
    scene = scene_from_dict(_scene({"preset": "auto"}), tmp_path)
    expected = auto_transfer_function(scene.volume)
    assert np.array_equal(scene.tf.points, expected.points) and scene.tf.density_scale == expected.density_scale
    concrete = scene_from_dict(_scene(expected.to_dict()), tmp_path)
    assert scene.fingerprint() == concrete.fingerprint()
    assert scene.fingerprint_parts() == concrete.fingerprint_parts()
    again = scene_from_dict(scene.spec(), tmp_path)  # what bundles record rebuilds the same scene
    assert again.fingerprint() == scene.fingerprint()
    other = scene_from_dict(_scene({"preset": "auto"}, {"builtin": "vortex", "resolution": 24}), tmp_path)
    assert other.tf.to_dict() != scene.tf.to_dict()
    # a file that says {"preset": "auto"} resolves against the scene's volume too
    (tmp_path / "tf.json").write_text(json.dumps({"preset": "auto", "density_scale": 33}))
    from_file = scene_from_dict(_scene("tf.json"), tmp_path)
    assert np.array_equal(from_file.tf.points, expected.points) and from_file.tf.density_scale == 33


@pytest.mark.parametrize("call", [lambda: TransferFunction.from_dict({"preset": "auto"}), lambda: preset("auto")])
def test_auto_without_a_volume_is_one_clear_line(call: object) -> None:
    with pytest.raises(InputError, match="'auto'.*needs the volume"):
        call()  # type: ignore[operator]


def test_auto_with_a_bad_density_is_refused(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="transfer_function: density_scale must be a positive number"):
        scene_from_dict(_scene({"preset": "auto", "density_scale": -1}), tmp_path)
    with pytest.raises(InputError, match="unknown key 'densty'"):
        scene_from_dict(_scene({"preset": "auto", "densty": 1}), tmp_path)
