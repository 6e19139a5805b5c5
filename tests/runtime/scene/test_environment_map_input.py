"""Environment-map input: the HDR readers (runtime.io.hdr_images), the light's JSON form and its refusals.

Every bad input is one line: an InputError from the API, ``error: ...`` and exit 2 from ``pfn-render``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from conftest import tiny_scene_dict

from photon_fields.runtime.cli.render import _main
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.hdr_images import read_environment_image, read_radiance_hdr, write_radiance_hdr
from photon_fields.runtime.io.images import write_exr
from photon_fields.runtime.scene.lights import EnvironmentLight, EnvironmentMap, light_from_dict
from photon_fields.runtime.scene.scene import Scene, load_scene, scene_from_dict


def sky(h: int = 8) -> np.ndarray:
    rng = np.random.default_rng(1)
    return rng.uniform(0.0, 4.0, (h, 2 * h, 3)).astype(np.float32)


def test_radiance_hdr_round_trip_rle_and_flat(tmp_path: Path) -> None:
    img = sky(16)
    img[3, 5:20] = [2.0, 2.0, 2.0]  # runs for the encoder
    for rle in (True, False):
        p = write_radiance_hdr(tmp_path / f"s{rle}.hdr", img, rle=rle)
        back = read_radiance_hdr(p)
        assert back.shape == img.shape and back.dtype == np.float32
        # RGBE keeps 8 bits of mantissa relative to the pixel's largest component.
        np.testing.assert_allclose(back, img, atol=img.max(axis=-1, keepdims=True).max() / 128)
    flat = np.full((16, 32, 3), 0.75)  # runs: the encoded file is much smaller, and decodes exactly
    p = write_radiance_hdr(tmp_path / "flat.hdr", flat)
    assert p.stat().st_size < 16 * 32 and np.array_equal(read_radiance_hdr(p), flat.astype(np.float32))


def test_exr_maps_read_from_bare_rgb_and_layers(tmp_path: Path) -> None:
    img = sky()
    write_exr(tmp_path / "layer.exr", {"L": img})
    np.testing.assert_array_equal(read_environment_image(tmp_path / "layer.exr"), img)
    chans = {c: np.ascontiguousarray(img[..., k]) for k, c in enumerate("RGB")}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, chans).write(str(tmp_path / "bare.exr"))
    np.testing.assert_array_equal(read_environment_image(tmp_path / "bare.exr"), img)


def bad_files(tmp: Path) -> dict[str, tuple[Path, str]]:
    """name -> (file, a fragment of its one-line error)."""
    out: dict[str, tuple[Path, str]] = {}
    write_exr(tmp / "square.exr", {"L": np.ones((8, 8, 3), np.float32)})
    out["not_2_to_1"] = (tmp / "square.exr", "twice as wide as high")
    write_radiance_hdr(tmp / "tall.hdr", np.ones((8, 4, 3)))
    out["hdr_not_2_to_1"] = (tmp / "tall.hdr", "twice as wide as high")
    nan = sky()
    nan[2, 3, 1] = np.nan
    write_exr(tmp / "nan.exr", {"L": nan})
    out["nan"] = (tmp / "nan.exr", "NaN or infinite")
    neg = sky()
    neg[1, 1] = -1.0
    write_exr(tmp / "neg.exr", {"L": neg})
    out["negative"] = (tmp / "neg.exr", "negative")
    u = {c: np.ones((4, 8), np.uint32) for c in "RGB"}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, u).write(str(tmp / "uint.exr"))
    out["uint_exr"] = (tmp / "uint.exr", "not a float image")
    (tmp / "sky.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    out["png"] = (tmp / "sky.png", "not an HDR image")
    (tmp / "fake.hdr").write_bytes(b"P6\n8 4\n255\n")
    out["not_radiance"] = (tmp / "fake.hdr", "not a Radiance HDR file")
    out["missing"] = (tmp / "nope.exr", "file not found")
    return out


@pytest.mark.parametrize("case", ["not_2_to_1", "hdr_not_2_to_1", "nan", "negative", "uint_exr", "png",
                                  "not_radiance", "missing"])
def test_bad_maps_are_one_line_errors(tmp_path: Path, case: str) -> None:
    path, needle = bad_files(tmp_path)[case]
    with pytest.raises(InputError) as info:
        EnvironmentMap(str(path))
    assert needle in str(info.value) and "\n" not in str(info.value), str(info.value)


def scene_with_map(tmp_path: Path, light: dict) -> Path:
    d = tiny_scene_dict()
    d["camera"]["width"] = d["camera"]["height"] = 8
    d["lights"] = [light]
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(d))
    return p


def test_scene_file_map_path_is_relative_to_the_scene_and_round_trips(tmp_path: Path) -> None:
    (tmp_path / "maps").mkdir()
    write_exr(tmp_path / "maps" / "sky.exr", {"L": sky()})
    p = scene_with_map(tmp_path, {"type": "environment_map", "path": "maps/sky.exr", "power": 2.0,
                                  "rotation": [90, 10, 0]})
    scene = load_scene(p)
    (light,) = scene.lights
    assert isinstance(light, EnvironmentMap) and light.rotation == (90.0, 10.0, 0.0) and light.power == 2.0
    assert Path(light.path).is_absolute()
    again = scene_from_dict(scene.spec())
    assert again.fingerprint() == scene.fingerprint()
    # The fingerprint follows the pixels, not the path; a changed image is refused by a recorded spec.
    assert scene.fingerprint() != Scene(scene.volume, scene.tf, (light.rotated(0.0),), scene.camera).fingerprint()
    write_exr(tmp_path / "maps" / "sky.exr", {"L": sky() * 2})
    with pytest.raises(InputError, match="has changed"):
        scene_from_dict(scene.spec())


@pytest.mark.parametrize(("light", "needle"), [
    ({"type": "environment_map", "path": "sky.exr", "powr": 1.0}, "did you mean 'power'"),
    ({"type": "environment_map"}, "needs 'path'"),
    ({"type": "environment_map", "path": "sky.exr", "rotation": "north"}, "rotation"),
    ({"type": "environment_map", "path": "sky.exr", "rotation": [1, 2]}, "rotation"),
    ({"type": "environment_map", "path": "sky.exr", "power": -1}, "power"),
    ({"type": "environment_map", "path": "square.exr"}, "twice as wide"),
])
def test_bad_light_entries_exit_2_from_pfn_render(tmp_path: Path, light: dict, needle: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    write_exr(tmp_path / "sky.exr", {"L": sky()})
    write_exr(tmp_path / "square.exr", {"L": np.ones((8, 8, 3), np.float32)})
    p = scene_with_map(tmp_path, light)
    assert _main(["--scene", str(p), "--size", "8x8", "--spp", "1", "--quiet", "--out",
                  str(tmp_path / "out" / "r.exr")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err and "lights[0]" in err, err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_two_maps_are_refused_and_constant_environments_merge_into_the_map() -> None:
    img = sky()
    a, b = EnvironmentMap("a", image=img), EnvironmentMap("b", image=img)
    from conftest import constant_tf, small_camera

    from photon_fields.runtime.scene.volume import make_volume

    vol = make_volume(np.ones((4, 4, 4)), window=(0.0, 1.0))
    with pytest.raises(InputError, match="at most one environment_map"):
        Scene(vol, constant_tf(1.0), (a, b), small_camera(8))
    s = Scene(vol, constant_tf(1.0), (EnvironmentMap("a", [1, 1, 1], 2.0, 0.0, img),
                                       EnvironmentLight([0.1, 0.2, 0.3])), small_camera(8))
    kind, _, rgb = s.packed_lights()
    assert kind.tolist() == [3] and rgb.tolist() == [[1.0, 1.0, 1.0]]
    np.testing.assert_allclose(s.packed_environment_map().radiance, 2.0 * img + [0.1, 0.2, 0.3], rtol=1e-6)
    with pytest.raises(InputError, match="unknown light type"):
        light_from_dict({"type": "envmap", "path": "x.exr"})


def test_the_viewers_light_control_keeps_a_map_a_map() -> None:
    """The viewer edits an environment map's power like a constant environment's, without losing its image."""
    from photon_fields.runtime.viewer.light_control import LightControl

    m = EnvironmentMap("sky", [1.0, 0.5, 0.25], 2.0, [30.0, 0.0, 0.0], sky())
    control = LightControl.from_light(m)
    assert control.kind == "environment"
    control.power = 3.0
    back = control.light()
    assert isinstance(back, EnvironmentMap) and back.power == 3.0 and back.rotation == m.rotation
    assert back.sha256 == m.sha256 and back.color.tolist() == m.color.tolist()


def test_an_adjusted_map_is_the_constructed_one_without_checking_or_hashing_the_image_again(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The viewer's light edits (a yaw drag, a power slider) make a map per frame: ``adjusted`` must give what the
    constructor gives (the same fingerprint, rotation, colour and power), share the image, and refuse what the
    constructor refuses, in one line."""
    import photon_fields.runtime.scene.lights as lights_module

    base = EnvironmentMap(None, [1.0, 0.5, 0.25], 2.0, (10.0, 5.0, 0.0), sky())
    built = EnvironmentMap(None, [0.2, 0.4, 0.6], 3.5, (40.0, 5.0, 0.0), base.image)

    def no_hash(*args: object) -> None:
        raise AssertionError("the image was hashed again")

    monkeypatch.setattr(lights_module.hashlib, "sha256", no_hash)
    adjusted = base.adjusted(rotation=(40.0, 5.0, 0.0), color=[0.2, 0.4, 0.6], power=3.5)
    assert adjusted.image is base.image and adjusted.identity() == built.identity()
    assert base.adjusted(power=3.5).rotation == base.rotation and base.adjusted(power=3.5).power == 3.5
    assert base.rotation == (10.0, 5.0, 0.0) and base.power == 2.0  # the source is left as it was
    for kw in ({"power": -1.0}, {"color": [1.0, float("nan"), 0.0]}, {"rotation": (0.0, 0.0)}):
        with pytest.raises(InputError):
            base.adjusted(**kw)
