"""Label volumes at the scene level: integer identity through loading, the categorical transfer function's JSON
form (round trip, refusals), the ``labels_transfer`` helper and the scene/fingerprint wiring."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.labels import LabelTransfer, labels_transfer, palette, volume_labels
from photon_fields.runtime.scene.scene import Scene, scene_from_dict
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import Volume, make_volume
from photon_fields.runtime.scene.volume_io import load_volume, save_volume_raw

RED, BLUE = [0.9, 0.1, 0.1], [0.1, 0.2, 0.9]
TWO = {"labels": {"3": {"albedo": RED, "opacity": 1.0}, "7": {"albedo": BLUE, "opacity": 0.4}},
       "density_scale": 30.0, "name": "two"}


def label_array(shape: tuple[int, int, int] = (9, 7, 5), labels: tuple[int, ...] = (0, 3, 7, 12),
                seed: int = 0, dtype: type = np.uint16) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a = np.asarray(labels, dtype=dtype)[rng.integers(0, len(labels), size=shape)]
    a.flat[: len(labels)] = labels  # every label present
    return a


def one_line(err: pytest.ExceptionInfo[InputError]) -> str:
    text = str(err.value)
    assert "\n" not in text
    return text


# --- integer identity -------------------------------------------------------------------------------


@pytest.mark.parametrize("labels", [(0, 3, 7, 12), (-5, 0, 2), (100, 101, 65000), (42,)])
def test_labels_are_recovered_exactly(labels: tuple[int, ...]) -> None:
    """Whatever the raw range, each voxel's dense index names its own raw label (the normalization to [0, 1]
    loses nothing), and values/counts are the distinct labels present."""
    a = label_array(labels=labels, dtype=np.int32)
    grid = volume_labels(make_volume(a))
    np.testing.assert_array_equal(grid.values, sorted(set(labels)))
    np.testing.assert_array_equal(grid.values[grid.index.astype(np.int64)], a)
    np.testing.assert_array_equal(grid.counts, [(a == v).sum() for v in grid.values])


@pytest.mark.parametrize("suffix", [".npy", ".raw"])
def test_a_label_file_keeps_its_labels(tmp_path: Path, suffix: str) -> None:
    """Through the readers (which normalize with the data's min/max or the sidecar window) labels survive."""
    a = label_array(labels=(0, 5, 1000, 4095))
    path = tmp_path / f"seg{suffix}"
    if suffix == ".npy":
        np.save(path, a)
    else:
        save_volume_raw(path, a)
    grid = volume_labels(load_volume(path))
    np.testing.assert_array_equal(grid.values[grid.index.astype(np.int64)], a)


def test_float_volume_with_integer_values_is_a_label_volume() -> None:
    """NIfTI label maps are often stored as floats: integral values are labels whatever the dtype."""
    a = label_array().astype(np.float32)
    np.testing.assert_array_equal(volume_labels(make_volume(a)).values, [0, 3, 7, 12])


def test_non_integer_volume_is_refused_in_one_line() -> None:
    a = label_array().astype(np.float64)
    a[2, 3, 4] = 3.4
    with pytest.raises(InputError, match=r"not a label volume: voxel \(2, 3, 4\) has the value 3\.4") as err:
        TransferFunction.from_dict(TWO, "tf.json", volume=make_volume(a, name="ct"))
    assert one_line(err).startswith("tf.json")


def test_a_clipping_window_is_refused() -> None:
    with pytest.raises(InputError, match=r"window \[0, 10\] clips the raw values \(range \[0, 12\]\)"):
        volume_labels(make_volume(label_array(), window=(0, 10)))


def test_a_volume_without_raw_values_is_refused() -> None:
    vol = Volume(np.zeros((2, 2, 2), np.float32))
    with pytest.raises(InputError, match="records no raw values"):
        volume_labels(vol)


# --- the categorical transfer function ----------------------------------------------------------------


def test_json_round_trip(tmp_path: Path) -> None:
    vol = make_volume(label_array())
    tf = TransferFunction.from_dict(TWO, volume=vol)
    assert isinstance(tf, LabelTransfer)
    path = tmp_path / "labels.json"
    tf.save(path)
    again = TransferFunction.load(path, volume=vol)
    assert isinstance(again, LabelTransfer) and again.to_dict() == tf.to_dict() == json.loads(path.read_text())
    np.testing.assert_array_equal(again.labels, [3, 7])
    np.testing.assert_array_equal(again.albedo, [RED, BLUE])
    assert again.density_scale == 30.0 and again.name == "two"
    with pytest.raises(InputError, match="exists; pass force=True"):
        tf.save(path)
    labels_transfer(vol).save(path, force=True)
    assert set(LabelTransfer.load(path).to_dict()["labels"]) == {"0", "3", "7", "12"}


@pytest.mark.parametrize(("change", "needle"), [
    ({"densty_scale": 3}, r"unknown key 'densty_scale' \(did you mean 'density_scale'\?\)"),
    ({"labels": {"3": {"albedo": RED, "opacity": 1, "colour": RED}}}, r"labels\['3'\]: unknown key 'colour'"),
    ({"labels": {"3": {"albedo": RED}}}, r"labels\['3'\]: missing 'opacity'"),
    ({"labels": {"3.5": {"albedo": RED, "opacity": 1}}}, "a label must be an integer, got '3.5'"),
    ({"labels": {"3": {"albedo": RED, "opacity": 1}, "03": {"albedo": RED, "opacity": 1}}}, "label 3 is given twice"),
    ({"labels": {"3": {"albedo": [1, 0], "opacity": 1}}}, "albedo must have three components"),
    ({"labels": {"3": {"albedo": RED, "opacity": 2}}}, r"opacity values must be finite and lie in \[0, 1\]"),
    ({"labels": {}}, "'labels' must be a non-empty object"),
    ({"points": []}, "give one of 'preset', 'points' or 'labels', not 'points' and 'labels'"),
    ({"labels": {"3": {"albedo": RED, "opacity": 1}, "5": {"albedo": RED, "opacity": 1},
                 "99": {"albedo": RED, "opacity": 1}}},
     r"labels 5, 99 not in volume 'seg' \(its labels: 0, 3, 7, 12\)"),
])
def test_bad_label_functions_are_one_line(change: dict, needle: str) -> None:
    with pytest.raises(InputError, match=needle) as err:
        TransferFunction.from_dict({**TWO, **change}, "tf.json", volume=make_volume(label_array(), name="seg"))
    assert one_line(err).startswith("tf.json")


def test_unnamed_labels_are_transparent() -> None:
    """Labels the function does not name get extinction 0; named ones opacity * density_scale, in the order of
    the labels present (the dense indices)."""
    vol = make_volume(label_array())
    index, ext, alb = TransferFunction.from_dict(TWO, volume=vol).tables(vol)
    np.testing.assert_array_equal(ext, [0.0, 30.0, 12.0, 0.0])  # labels 0, 3, 7, 12
    np.testing.assert_array_equal(alb[1:3], [RED, BLUE])
    assert index.dtype == np.float32


# --- the helper ---------------------------------------------------------------------------------------


def test_helper_gives_distinct_colours_and_transparent_background() -> None:
    vol = make_volume(label_array(labels=(0, 1, 2, 5, 9, 30)))
    tf = labels_transfer(vol)
    np.testing.assert_array_equal(tf.labels, [0, 1, 2, 5, 9, 30])
    np.testing.assert_array_equal(tf.opacity, [0, 1, 1, 1, 1, 1])
    colours = tf.albedo[1:]
    dist = np.linalg.norm(colours[:, None] - colours[None], axis=-1)
    assert dist[np.triu_indices(len(colours), 1)].min() > 0.2  # well separated, not merely unequal


def test_palette_stays_distinct_beyond_its_table() -> None:
    p = palette(200)
    assert np.all((p >= 0.1 - 1e-12) & (p <= 1.0))  # no black absorbers
    dist = np.linalg.norm(p[:, None] - p[None], axis=-1)
    assert dist[np.triu_indices(200, 1)].min() > 1e-3
    assert dist[np.triu_indices(20, 1)].min() > 0.2


def test_helper_shows_only_the_chosen_labels() -> None:
    vol = make_volume(label_array(labels=(0, 1, 2, 5, 9)))
    tf = labels_transfer(vol, [2, 9])
    assert dict(zip(tf.labels.tolist(), tf.opacity.tolist(), strict=True)) == {0: 0, 1: 0, 2: 1, 5: 0, 9: 1}
    from_json = TransferFunction.from_dict({"preset": "labels", "visible": [2, 9], "density_scale": 7}, volume=vol)
    np.testing.assert_array_equal(from_json.opacity, tf.opacity)
    assert from_json.density_scale == 7
    with pytest.raises(InputError, match=r"visible: label 4 not in volume"):
        labels_transfer(vol, [2, 4])
    with pytest.raises(InputError, match="labels must be integers"):
        labels_transfer(vol, ["liver"])


def test_labels_preset_needs_the_volume() -> None:
    with pytest.raises(InputError, match="preset 'labels' is built from the labels present in a volume"):
        TransferFunction.from_dict({"preset": "labels"})
    with pytest.raises(InputError, match="unknown key 'visibel'"):
        TransferFunction.from_dict({"preset": "labels", "visibel": [1]}, volume=make_volume(label_array()))


# --- scenes -------------------------------------------------------------------------------------------


def _scene_dict(volume: dict, tf: object) -> dict:
    return {"name": "seg", "volume": volume, "transfer_function": tf,
            "lights": [{"type": "directional", "direction": [-1, -1, -0.5], "power": 3}],
            "camera": {"eye": [1.2, 0.7, 1.5], "target": [0, 0, 0], "fov": 40, "width": 8, "height": 8}}


def test_scene_file_with_labels(tmp_path: Path) -> None:
    np.save(tmp_path / "seg.npy", label_array())
    scene = scene_from_dict(_scene_dict({"path": "seg.npy"}, TWO), tmp_path, "seg.json")
    assert isinstance(scene.tf, LabelTransfer) and scene.medium().categorical
    again = scene_from_dict(scene.spec(), tmp_path, "again.json")
    assert again.fingerprint() == scene.fingerprint()


def test_labels_on_a_scalar_volume_are_refused_by_the_scene() -> None:
    with pytest.raises(InputError, match=r"^seg\.json transfer_function: volume 'vortex' is not a label volume"):
        scene_from_dict(_scene_dict({"builtin": "vortex", "resolution": 8}, TWO), what="seg.json")
    # The Python API's Scene refuses it too, before any medium is built.
    vol = make_volume(np.linspace(0, 1, 27).reshape(3, 3, 3))
    scene = scene_from_dict(_scene_dict({"builtin": "vortex", "resolution": 8}, {"preset": "grey_ramp"}))
    tf = LabelTransfer(np.array([1]), np.array([RED]), np.array([1.0]))
    with pytest.raises(InputError, match="scene 'x' transfer_function: volume 'volume' is not a label volume"):
        Scene(vol, tf, scene.lights, scene.camera, name="x")


def test_fingerprint_tells_label_volumes_with_the_same_normalized_grid_apart() -> None:
    """Labels {0, 1, 2} and {0, 2, 4} normalize to the same grid; under {"0", "2"} they are different media
    (label 2 is the middle value in one, the top in the other), so their scenes must not share a fingerprint.
    A scalar scene's fingerprint stays the volume's own (no existing bundle or photon map is invalidated)."""
    a = label_array(labels=(0, 1, 2))
    v1, v2 = make_volume(a), make_volume(a * 2)
    assert v1.fingerprint() == v2.fingerprint()
    base = scene_from_dict(_scene_dict({"builtin": "vortex", "resolution": 8}, {"preset": "grey_ramp"}))
    tf = {"labels": {"0": {"albedo": RED, "opacity": 0}, "2": {"albedo": BLUE, "opacity": 1}}}
    s1, s2 = (Scene(v, TransferFunction.from_dict(tf, volume=v), base.lights, base.camera) for v in (v1, v2))
    assert s1.fingerprint() != s2.fingerprint()
    assert s1.medium().ext_lut.tolist() != s2.medium().ext_lut.tolist()
    grey = TransferFunction.from_dict({"preset": "grey_ramp"})
    assert (Scene(v1, grey, base.lights, base.camera).fingerprint_parts()["volume"]
            == Scene(v2, grey, base.lights, base.camera).fingerprint_parts()["volume"])
