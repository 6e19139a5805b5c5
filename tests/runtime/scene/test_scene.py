"""Tests for the scene model (transfer functions, lights, camera) and JSON scene files.

Every bad input must surface as one :class:`photon_fields.runtime.errors.InputError` whose message is a single line
naming the offending input; these tests check the message, not just the exception type.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.camera import Camera, orbit_camera
from photon_fields.runtime.scene.lights import (
    DIRECTIONAL,
    ENVIRONMENT,
    POINT,
    DirectionalLight,
    EnvironmentLight,
    PointLight,
    light_from_dict,
    pack_lights,
)
from photon_fields.runtime.scene.scene import BUILTIN_SCENES, Scene, builtin_scene, load_scene, scene_from_dict
from photon_fields.runtime.scene.transfer import LUT_SIZE, PRESETS, TransferFunction, preset


def assert_one_line(err: InputError, *needles: str) -> str:
    """The message is one non-empty line containing every needle (case-insensitive)."""
    msg = str(err)
    assert msg.strip() and "\n" not in msg and "\r" not in msg, msg
    for needle in needles:
        assert needle.lower() in msg.lower(), f"{needle!r} not in {msg!r}"
    return msg


# ----------------------------------------------------------------------------------------------------------
# Transfer functions


def three_point_tf() -> TransferFunction:
    return TransferFunction(
        np.array([0.0, 0.5, 1.0]),
        np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [0.0, 1.0, 1.0]]),
        np.array([0.0, 1.0, 0.5]),
        10.0,
        "three",
    )


def test_tf_exact_at_control_points() -> None:
    tf = three_point_tf()
    alb, ext = tf.evaluate(tf.points)
    np.testing.assert_array_equal(alb, tf.albedo)
    np.testing.assert_array_equal(ext, tf.opacity * 10.0)


@pytest.mark.parametrize(
    ("s", "albedo", "ext"),
    [
        (0.25, [0.5, 0.25, 0.0], 5.0),
        (0.75, [0.5, 0.75, 0.5], 7.5),
        (0.1, [0.2, 0.1, 0.0], 2.0),
        (0.9, [0.2, 0.9, 0.8], 6.0),
    ],
)
def test_tf_linear_between_control_points(s: float, albedo: list[float], ext: float) -> None:
    alb, e = three_point_tf().evaluate(np.array([s]))
    np.testing.assert_allclose(alb[0], albedo, atol=1e-12)
    assert e[0] == pytest.approx(ext, abs=1e-12)


def test_tf_evaluate_shapes() -> None:
    tf = three_point_tf()
    alb, ext = tf.evaluate(np.zeros((4, 5)))
    assert alb.shape == (4, 5, 3) and ext.shape == (4, 5)
    alb, ext = tf.evaluate(0.5)
    assert alb.shape == (3,) and ext.shape == ()


def test_tf_constant_beyond_the_ends() -> None:
    tf = TransferFunction(
        np.array([0.2, 0.8]), np.array([[0.1, 0.2, 0.3], [0.9, 0.8, 0.7]]), np.array([0.25, 0.75]), 4.0
    )
    alb, ext = tf.evaluate(np.array([0.0, 0.1, 0.2, 0.8, 0.9, 1.0]))
    np.testing.assert_allclose(alb[:3], [[0.1, 0.2, 0.3]] * 3)
    np.testing.assert_allclose(alb[3:], [[0.9, 0.8, 0.7]] * 3)
    np.testing.assert_allclose(ext, [1.0, 1.0, 1.0, 3.0, 3.0, 3.0])


def test_tf_single_point_is_constant() -> None:
    tf = TransferFunction(np.array([0.5]), np.array([[0.3, 0.4, 0.5]]), np.array([0.6]), 2.0)
    alb, ext = tf.evaluate(np.linspace(0, 1, 7))
    np.testing.assert_allclose(alb, [[0.3, 0.4, 0.5]] * 7)
    np.testing.assert_allclose(ext, 1.2)


@pytest.mark.parametrize("size", [LUT_SIZE, 17, 2])
def test_tf_lut_matches_exact_evaluation_at_nodes(size: int) -> None:
    tf = PRESETS["vortex"]
    alb, ext = tf.lut(size)
    assert alb.shape == (size, 3) and ext.shape == (size,)
    s = np.arange(size) / (size - 1)
    alb_exact, ext_exact = tf.evaluate(s)
    np.testing.assert_allclose(alb, alb_exact, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ext, ext_exact, rtol=0, atol=1e-9)
    assert ext[0] == tf.opacity[0] * tf.density_scale and ext[-1] == tf.opacity[-1] * tf.density_scale


def test_tf_default_lut_size() -> None:
    alb, ext = PRESETS["grey_ramp"].lut()
    assert alb.shape == (LUT_SIZE, 3) and ext.shape == (LUT_SIZE,)


def _same_tf(a: TransferFunction, b: TransferFunction) -> None:
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.albedo, b.albedo)
    np.testing.assert_array_equal(a.opacity, b.opacity)
    assert a.density_scale == b.density_scale and a.name == b.name


def test_tf_dict_round_trip() -> None:
    tf = three_point_tf()
    d = tf.to_dict()
    d2 = json.loads(json.dumps(d))  # JSON-able, and survives text
    _same_tf(TransferFunction.from_dict(d2), tf)


def test_tf_file_round_trip(tmp_path: Path) -> None:
    tf = PRESETS["shell"]
    path = tmp_path / "tf.json"
    tf.save(path)
    assert json.loads(path.read_text())["name"] == "shell"
    _same_tf(TransferFunction.load(path), tf)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tf.json"]  # no temp file left over


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_load(name: str) -> None:
    tf = preset(name)
    assert tf is PRESETS[name] and tf.name == name
    _same_tf(TransferFunction.from_dict({"preset": name}), tf)
    scaled = TransferFunction.from_dict({"preset": name, "density_scale": 7})
    assert scaled.density_scale == 7.0 and scaled.name == name
    np.testing.assert_array_equal(scaled.opacity, tf.opacity)
    # albedo stays high: multiple scattering is the point of the product
    assert np.all((tf.albedo >= 0.3) & (tf.albedo <= 1.0))


_ALB2 = np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.5]])


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"points": np.array([]), "albedo": np.zeros((0, 3)), "opacity": np.array([])}, "control point"),
        ({"points": np.array([0.5, 0.2])}, "increasing"),
        ({"points": np.array([0.5, 0.5])}, "increasing"),
        ({"points": np.array([-0.1, 0.5])}, "[0, 1]"),
        ({"points": np.array([0.5, 1.5])}, "[0, 1]"),
        ({"albedo": np.array([[0.5, 0.5, 0.5], [0.5, 1.2, 0.5]])}, "albedo"),
        ({"albedo": np.array([[0.5, 0.5, 0.5], [0.5, -0.1, 0.5]])}, "albedo"),
        ({"albedo": np.array([[0.5, 0.5], [0.5, 0.5]])}, "albedo must have shape (2, 3)"),
        ({"albedo": np.array([0.5, 0.5])}, "albedo must have shape"),
        ({"opacity": np.array([0.0, 1.5])}, "opacity"),
        ({"opacity": np.array([0.0])}, "opacity must have shape"),
        ({"points": np.array([0.0, np.nan])}, "points contain non-finite"),
        ({"albedo": np.array([[0.5, 0.5, 0.5], [0.5, np.inf, 0.5]])}, "albedo contain non-finite"),
        ({"opacity": np.array([0.0, np.nan])}, "opacity contain non-finite"),
        ({"density_scale": 0.0}, "density_scale"),
        ({"density_scale": -3.0}, "density_scale"),
        ({"density_scale": float("inf")}, "density_scale"),
        ({"density_scale": float("nan")}, "density_scale"),
    ],
)
def test_tf_rejects_bad_input(kwargs: dict[str, Any], needle: str) -> None:
    args = {
        "points": np.array([0.0, 1.0]),
        "albedo": _ALB2,
        "opacity": np.array([0.0, 1.0]),
        "density_scale": 5.0,
        "name": "bad",
    }
    args.update(kwargs)
    with pytest.raises(InputError) as info:
        TransferFunction(**args)
    assert_one_line(info.value, "transfer function", needle)


def _pt(s: Any = 0.0, albedo: Any = (0.5, 0.5, 0.5), opacity: Any = 0.5) -> dict[str, Any]:
    return {"s": s, "albedo": list(albedo) if isinstance(albedo, tuple) else albedo, "opacity": opacity}


@pytest.mark.parametrize(
    ("d", "needle"),
    [
        ([], "JSON object"),
        ({"points": []}, "points"),
        ({}, "points"),
        ({"points": [_pt(0.6), _pt(0.3)]}, "increasing"),
        ({"points": [_pt(0.0, (0.5, 1.5, 0.5))]}, "albedo"),
        ({"points": [_pt(0.0, (0.5, 0.5))]}, "three components"),
        ({"points": [_pt(0.0, 0.5)]}, "albedo"),
        ({"points": [_pt("x")]}, "numeric"),
        ({"points": [{"s": 0.0, "opacity": 0.5}]}, "albedo"),
        ({"points": [_pt(float("nan"))]}, "non-finite"),
        ({"points": [_pt()], "density_scale": 0}, "density_scale"),
        ({"points": [_pt()], "density_scale": "lots"}, "density_scale"),
        ({"preset": "cloud", "density_scale": -1}, "density_scale"),
        ({"preset": "nope"}, "unknown preset 'nope'"),
    ],
)
def test_tf_from_dict_rejects_bad_input(d: Any, needle: str) -> None:
    with pytest.raises(InputError) as info:
        TransferFunction.from_dict(d, what="my_tf.json")
    assert_one_line(info.value, "my_tf.json", needle)


def test_unknown_preset_lists_available() -> None:
    with pytest.raises(InputError) as info:
        preset("fog")
    assert_one_line(info.value, "fog", *PRESETS)


def test_tf_load_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError) as info:
        TransferFunction.load(tmp_path / "absent.json")
    assert_one_line(info.value, "absent.json", "not found")
    bad = tmp_path / "bad.json"
    bad.write_text('{"points": [')
    with pytest.raises(InputError) as info:
        TransferFunction.load(bad)
    assert_one_line(info.value, "bad.json", "JSON")
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"points": [_pt(0.0, (2.0, 0.0, 0.0))]}))
    with pytest.raises(InputError) as info:
        TransferFunction.load(wrong)
    assert_one_line(info.value, "wrong.json", "albedo")


# ----------------------------------------------------------------------------------------------------------
# Lights


def test_pack_lights_layout() -> None:
    lights = [
        PointLight([1.0, 2.0, 3.0], [1.0, 0.5, 0.25], 2.0),
        DirectionalLight([0.0, -2.0, 0.0], [0.2, 0.4, 0.6], 5.0),
        EnvironmentLight([0.1, 0.2, 0.3], 10.0),
    ]
    kind, vec, rgb = pack_lights(lights)
    assert kind.dtype == np.int64 and vec.dtype == np.float64 and rgb.dtype == np.float64
    assert kind.shape == (3,) and vec.shape == (3, 3) and rgb.shape == (3, 3)
    np.testing.assert_array_equal(kind, [POINT, DIRECTIONAL, ENVIRONMENT])
    np.testing.assert_allclose(vec, [[1, 2, 3], [0, -1, 0], [0, 0, 0]])  # directions are normalized
    np.testing.assert_allclose(rgb, [[2.0, 1.0, 0.5], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    kind, vec, rgb = pack_lights([])
    assert kind.shape == (0,) and vec.shape == (0, 3) and rgb.shape == (0, 3)


def test_light_dict_round_trip() -> None:
    for light in (
        PointLight([1, 2, 3], [1, 1, 1], 2.0),
        DirectionalLight([1, 1, 0], [0.5, 0.5, 1], 3.0),
        EnvironmentLight([0.2, 0.3, 0.4], 1.5),
    ):
        d = json.loads(json.dumps(light.to_dict()))
        back = light_from_dict(d)
        assert type(back) is type(light)
        for a, b in zip(pack_lights([light]), pack_lights([back]), strict=True):
            np.testing.assert_allclose(a, b)


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda: PointLight([0, 0, 0], [1, 1, 1], -1.0), "power"),
        (lambda: DirectionalLight([0, -1, 0], [1, 1, 1], float("nan")), "power"),
        (lambda: EnvironmentLight([1, 1, 1], "bright"), "power"),
        (lambda: EnvironmentLight([1, 1, 1], None), "power"),
        (lambda: PointLight([0, 0, 0], [1, -0.5, 1], 1.0), "color"),
        (lambda: PointLight([0, 0, 0], [1, 1], 1.0), "color"),
        (lambda: PointLight([0, 0, 0], "white", 1.0), "color"),
        (lambda: DirectionalLight([0, 0, 0], [1, 1, 1], 1.0), "zero vector"),
        (lambda: DirectionalLight([1e-15, 0, 0], [1, 1, 1], 1.0), "zero vector"),
        (lambda: DirectionalLight(["a", 0, 0], [1, 1, 1], 1.0), "direction"),
        (lambda: PointLight("here", [1, 1, 1], 1.0), "position"),
        (lambda: PointLight([0, np.inf, 0], [1, 1, 1], 1.0), "position"),
    ],
)
def test_light_rejects_bad_input(make: Any, needle: str) -> None:
    with pytest.raises(InputError) as info:
        make()
    assert_one_line(info.value, needle)


@pytest.mark.parametrize(
    ("d", "needle"),
    [
        ({"type": "spot", "position": [0, 0, 0]}, "unknown light type 'spot'"),
        ({"position": [0, 0, 0]}, "unknown light type"),
        ("point", "JSON object"),
        ({"type": "point"}, "position"),
        ({"type": "directional"}, "direction"),
        ({"type": "point", "position": [0, 0, 0], "power": -2}, "power"),
        ({"type": "point", "position": [0, 0, 0], "color": [1, -1, 1]}, "color"),
        ({"type": "directional", "direction": [0, 0, 0]}, "direction"),
        ({"type": "environment", "power": "x"}, "power"),
        ({"type": "environment", "pwr": 3}, "pwr"),  # a misspelt key is not silently ignored
    ],
)
def test_light_from_dict_rejects_bad_input(d: Any, needle: str) -> None:
    with pytest.raises(InputError) as info:
        light_from_dict(d, "scene.json lights[3]")
    assert_one_line(info.value, "scene.json lights[3]", needle)


# ----------------------------------------------------------------------------------------------------------
# Camera


def _ray(cam: Camera, x: float, y: float) -> np.ndarray:
    origin, du, dv = cam.image_plane()
    d = origin + x * du + y * dv
    return d / np.linalg.norm(d)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))))


CAM_ARGS = {"eye": [0.4, 0.7, 2.2], "target": [0.1, -0.1, 0.05], "up": [0.0, 1.0, 0.0]}


@pytest.mark.parametrize("fov_axis", ["y", "x"])
@pytest.mark.parametrize(("w", "h"), [(64, 48), (30, 90), (17, 17)])
def test_camera_centre_ray_points_at_target(fov_axis: str, w: int, h: int) -> None:
    cam = Camera(**CAM_ARGS, fov=50.0, width=w, height=h, fov_axis=fov_axis)
    fwd = (cam.target - cam.eye) / np.linalg.norm(cam.target - cam.eye)
    np.testing.assert_allclose(_ray(cam, w / 2, h / 2), fwd, atol=1e-12)


@pytest.mark.parametrize("fov", [10.0, 45.0, 90.0, 150.0])
@pytest.mark.parametrize(("w", "h"), [(64, 48), (30, 90)])
def test_camera_fov_y_is_vertical(fov: float, w: int, h: int) -> None:
    cam = Camera(**CAM_ARGS, fov=fov, width=w, height=h, fov_axis="y")
    assert _angle_deg(_ray(cam, w / 2, 0), _ray(cam, w / 2, h)) == pytest.approx(fov, abs=1e-9)
    # the horizontal extent follows from the aspect ratio
    horiz = 2 * math.degrees(math.atan(math.tan(math.radians(fov) / 2) * w / h))
    assert _angle_deg(_ray(cam, 0, h / 2), _ray(cam, w, h / 2)) == pytest.approx(horiz, abs=1e-9)


@pytest.mark.parametrize("fov", [10.0, 45.0, 90.0, 150.0])
@pytest.mark.parametrize(("w", "h"), [(64, 48), (30, 90)])
def test_camera_fov_x_is_horizontal(fov: float, w: int, h: int) -> None:
    cam = Camera(**CAM_ARGS, fov=fov, width=w, height=h, fov_axis="x")
    assert _angle_deg(_ray(cam, 0, h / 2), _ray(cam, w, h / 2)) == pytest.approx(fov, abs=1e-9)
    vert = 2 * math.degrees(math.atan(math.tan(math.radians(fov) / 2) * h / w))
    assert _angle_deg(_ray(cam, w / 2, 0), _ray(cam, w / 2, h)) == pytest.approx(vert, abs=1e-9)


def test_camera_orientation_y_down_x_right() -> None:
    # Looking down -z from +z with up +y: image x grows towards +x (right), image y grows towards -y (down).
    cam = Camera([0.0, 0.0, 3.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 40.0, 32, 32)
    right, up, fwd = cam.basis()
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(up, [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(fwd, [0, 0, -1], atol=1e-12)
    top, bottom = _ray(cam, 16, 0), _ray(cam, 16, 32)
    assert top[1] > 0 > bottom[1]
    left, rightmost = _ray(cam, 0, 16), _ray(cam, 32, 16)
    assert left[0] < 0 < rightmost[0]
    # pixel rows step by dv = -up * (pixel height): moving one pixel down lowers the ray
    _, du, dv = cam.image_plane()
    assert dv[1] < 0 and du[0] > 0 and abs(dv[0]) < 1e-15 and abs(du[1]) < 1e-15


def test_camera_basis_is_orthonormal_for_tilted_up() -> None:
    cam = Camera([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], [0.3, 1.0, -0.2], 35.0, 20, 10)
    r, u, f = cam.basis()
    m = np.stack([r, u, f])
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.dot(u, cam.up) > 0  # true up on the same side as the requested up


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        ({"fov": 0.0}, "fov"),
        ({"fov": 180.0}, "fov"),
        ({"fov": -10.0}, "fov"),
        ({"fov": float("nan")}, "fov"),
        ({"fov": "wide"}, "fov"),
        ({"width": 0}, "width"),
        ({"height": 0}, "height"),
        ({"width": -5}, "width"),
        ({"width": 12.5}, "width"),
        ({"height": True}, "height"),
        ({"width": 20000}, "width"),
        ({"up": [0.0, 0.0, 1.0], "eye": [0.0, 0.0, 2.0], "target": [0.0, 0.0, 0.0]}, "parallel"),
        ({"up": [0.0, -3.0, 0.0], "eye": [0.0, 2.0, 0.0], "target": [0.0, 0.0, 0.0]}, "parallel"),
        ({"up": [0.0, 0.0, 0.0]}, "zero vector"),
        ({"eye": [1.0, 1.0, 1.0], "target": [1.0, 1.0, 1.0]}, "same point"),
        ({"eye": [np.nan, 0.0, 1.0]}, "eye"),
        ({"target": [0.0, 1.0]}, "target"),
        ({"fov_axis": "z"}, "fov_axis"),
    ],
)
def test_camera_rejects_degenerate(overrides: dict[str, Any], needle: str) -> None:
    args: dict[str, Any] = {**CAM_ARGS, "fov": 40.0, "width": 32, "height": 32, "fov_axis": "y"}
    args.update(overrides)
    with pytest.raises(InputError) as info:
        Camera(**args)
    assert_one_line(info.value, "camera", needle)
    with pytest.raises(InputError) as info:  # same through a scene file's camera entry
        Camera.from_dict(args, what="scene.json camera")
    assert_one_line(info.value, "scene.json camera", needle)


def test_camera_from_dict_defaults_and_errors() -> None:
    cam = Camera.from_dict({"eye": [0, 0, 2], "target": [0, 0, 0]})
    assert (cam.fov, cam.width, cam.height, cam.fov_axis) == (40.0, 256, 256, "y")
    np.testing.assert_array_equal(cam.up, [0, 1, 0])
    back = Camera.from_dict(json.loads(json.dumps(cam.to_dict())))
    np.testing.assert_array_equal(back.eye, cam.eye)
    for d, needle in (
        ({"target": [0, 0, 0]}, "eye"),
        ({"eye": [0, 0, 1]}, "target"),
        ({"eye": [0, 0, 1], "target": [0, 0, 0], "zoom": 2}, "zoom"),
        ([1, 2], "object"),
    ):
        with pytest.raises(InputError) as info:
            Camera.from_dict(d, what="s.json camera")
        assert_one_line(info.value, "s.json camera", needle)


@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0, 180.0, -45.0, 360.0, 1234.5])
def test_orbit_camera_keeps_distance_and_height(angle: float) -> None:
    base = Camera([1.2, 0.6, 1.4], [0.1, 0.2, -0.1], [0.0, 1.0, 0.0], 38.0, 24, 16, "x")
    cam = orbit_camera(base, angle)
    assert np.linalg.norm(cam.eye - cam.target) == pytest.approx(np.linalg.norm(base.eye - base.target), rel=1e-12)
    np.testing.assert_array_equal(cam.target, base.target)
    assert cam.eye[1] == pytest.approx(base.eye[1], abs=1e-12)  # rotation about the vertical axis
    assert (cam.fov, cam.width, cam.height, cam.fov_axis) == (base.fov, base.width, base.height, base.fov_axis)
    # the horizontal offset turned by the requested angle, right-handed about +y: in (z, x) coordinates
    v0 = (base.eye - base.target)[[2, 0]]
    v1 = (cam.eye - cam.target)[[2, 0]]
    turned = math.degrees(math.atan2(v0[0] * v1[1] - v0[1] * v1[0], float(np.dot(v0, v1))))
    assert math.cos(math.radians(turned - angle)) == pytest.approx(1.0, abs=1e-12)


def test_orbit_camera_full_turn_is_identity() -> None:
    base = Camera([1.2, 0.6, 1.4], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    np.testing.assert_allclose(orbit_camera(base, 360.0).eye, base.eye, atol=1e-12)
    np.testing.assert_allclose(orbit_camera(orbit_camera(base, 100.0), -100.0).eye, base.eye, atol=1e-12)


# ----------------------------------------------------------------------------------------------------------
# Scene files

CAMERA = {"eye": [1.2, 0.7, 1.5], "target": [0, 0, 0], "up": [0, 1, 0], "fov": 40, "width": 24, "height": 16}
INLINE_TF = {
    "name": "inline",
    "density_scale": 30,
    "points": [
        {"s": 0.0, "albedo": [0.9, 0.9, 0.9], "opacity": 0.0},
        {"s": 1.0, "albedo": [0.8, 0.7, 0.6], "opacity": 1.0},
    ],
}
SUN = {"type": "directional", "direction": [-1, -1, -0.5], "color": [1, 1, 1], "power": 3}


def _field(n: int = 16) -> np.ndarray:
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    return np.exp(-((X - 0.5) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2) / 0.05).astype(np.float32)


@pytest.fixture
def scene_dir(tmp_path: Path) -> Path:
    """A folder with a 16^3 .npy volume, a TF file and a scene file using both (by relative paths)."""
    d = tmp_path / "scenes"
    (d / "data").mkdir(parents=True)
    np.save(d / "data" / "vol.npy", _field())
    TransferFunction.from_dict(INLINE_TF).save(d / "tf.json")
    return d


def write_scene(folder: Path, filename: str = "scene.json", **entries: Any) -> Path:
    spec: dict[str, Any] = {
        "name": "test",
        "volume": {"path": "data/vol.npy"},
        "transfer_function": INLINE_TF,
        "lights": [SUN],
        "camera": CAMERA,
        "phase": {"g": 0.25},
    }
    spec.update(entries)
    spec = {k: v for k, v in spec.items() if v is not None}
    path = folder / filename
    path.write_text(json.dumps(spec))
    return path


def test_load_scene_inline_tf(scene_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # relative paths must resolve against the scene file, not the cwd
    scene = load_scene(write_scene(scene_dir))
    assert isinstance(scene, Scene) and scene.name == "test"
    assert scene.volume.dims == (16, 16, 16) and scene.volume.name == "vol"
    assert float(scene.volume.data.min()) == 0.0 and float(scene.volume.data.max()) == 1.0
    assert scene.tf.name == "inline" and scene.tf.density_scale == 30.0
    assert scene.g == 0.25
    assert len(scene.lights) == 1 and isinstance(scene.lights[0], DirectionalLight)
    assert (scene.camera.width, scene.camera.height) == (24, 16)
    json.dumps(scene.to_dict())


def test_load_scene_preset_and_tf_file(scene_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(scene_dir.parent)
    s1 = load_scene(write_scene(scene_dir, "a.json", transfer_function={"preset": "cloud", "density_scale": 12}))
    assert s1.tf.name == "cloud" and s1.tf.density_scale == 12.0
    s2 = load_scene(write_scene(scene_dir, "b.json", transfer_function="tf.json"))
    _same_tf(s2.tf, TransferFunction.from_dict(INLINE_TF))
    # an absolute TF path and an absolute volume path work too
    s3 = load_scene(
        write_scene(
            scene_dir,
            "c.json",
            transfer_function=str(scene_dir / "tf.json"),
            volume={"path": str(scene_dir / "data" / "vol.npy")},
        )
    )
    assert s3.volume.fingerprint() == s2.volume.fingerprint()
    # the scene name defaults to the file's stem
    s4 = load_scene(write_scene(scene_dir, "my_scene.json", name=None, phase=None))
    assert s4.name == "my_scene" and s4.g == 0.0
    # a bare name that is no file is a preset, as in the Python API ("auto" resolved from the histogram)
    s5 = load_scene(write_scene(scene_dir, "d.json", transfer_function="cloud"))
    assert s5.tf.name == "cloud"
    s6 = load_scene(write_scene(scene_dir, "e.json", transfer_function="auto"))
    _same_tf(s6.tf, TransferFunction.from_dict({"preset": "auto"}, volume=s6.volume))


def test_load_scene_builtin_volume(tmp_path: Path) -> None:
    scene = load_scene(write_scene(tmp_path, volume={"builtin": "blobs", "resolution": 32}))
    assert scene.volume.dims == (32, 32, 32) and scene.volume.name == "blobs"


def test_load_scene_volume_options(scene_dir: Path) -> None:
    raw = _field()
    raw[0, 1, 2] = 2.0
    np.save(scene_dir / "data" / "peak.npy", raw)
    scene = load_scene(
        write_scene(
            scene_dir, volume={"path": "data/peak.npy", "spacing": [1, 1, 2], "window": [0.0, 4.0], "axes": "zyx"}
        )
    )
    assert scene.volume.spacing == (1.0, 1.0, 2.0)
    assert float(scene.volume.data[2, 1, 0]) == pytest.approx(0.5, abs=1e-6)  # transposed and windowed
    assert float(scene.volume.data.max()) == pytest.approx(0.5, abs=1e-6)


def test_scene_medium_and_packed_lights(tmp_path: Path) -> None:
    scene = load_scene(
        write_scene(
            tmp_path,
            volume={"builtin": "blobs", "resolution": 32},
            lights=[
                SUN,
                {"type": "environment", "power": 0.5},
                {"type": "environment", "color": [1, 0, 0], "power": 1.0},
            ],
        )
    )
    kind, vec, rgb = scene.packed_lights()
    np.testing.assert_array_equal(kind, [DIRECTIONAL, ENVIRONMENT])  # environments merged into one
    np.testing.assert_allclose(rgb[1], [1.5, 0.5, 0.5])
    assert scene.medium() is scene.medium()


def _load_error(path: Path | str) -> str:
    with pytest.raises(InputError) as info:
        load_scene(path)
    return assert_one_line(info.value)


def test_scene_error_missing_file(tmp_path: Path) -> None:
    msg = _load_error(tmp_path / "absent.json")
    assert "absent.json" in msg and "not found" in msg


def test_scene_error_directory(tmp_path: Path) -> None:
    d = tmp_path / "a_folder.json"
    d.mkdir()
    assert "a_folder.json" in _load_error(d)


def test_scene_error_invalid_json(tmp_path: Path) -> None:
    p = tmp_path / "broken.json"
    p.write_text('{"volume": {"builtin": "blobs"},\n "lights": [')
    msg = _load_error(p)
    assert "broken.json" in msg and "JSON" in msg
    p.write_bytes(b"\xff\xfe\x00garbage")
    assert "broken.json" in _load_error(p)


@pytest.mark.parametrize(
    ("entries", "needles"),
    [
        ({"colour": "red"}, ["unknown key", "colour"]),
        ({"camera": None}, ["missing 'camera'"]),
        ({"lights": []}, ["lights", "at least one light"]),
        ({"lights": [{**SUN, "power": 0}, {"type": "environment", "color": [0, 0, 0]}]}, ["lights", "zero power"]),
        ({"lights": {"type": "environment"}}, ["lights", "list"]),
        ({"phase": {"g": 1.5}}, ["phase g", "1.5"]),
        ({"phase": {"g": "forward"}}, ["phase g"]),
        ({"phase": 0.3}, ["phase"]),
        ({"phase": {"gee": 0.3}}, ["phase", "gee"]),
        ({"lights": [SUN, {"type": "point", "position": [1, 1, 1], "power": -2}]}, ["lights[1]", "power", "-2"]),
        ({"lights": [{"type": "laser"}]}, ["lights[0]", "laser"]),
        ({"camera": {**CAMERA, "fov": 0}}, ["camera fov"]),
        ({"camera": {**CAMERA, "up": [0, 0, 1], "eye": [0, 0, 2]}}, ["camera up", "parallel"]),
        ({"camera": {**CAMERA, "width": 0}}, ["camera width"]),
        ({"transfer_function": {**INLINE_TF, "density_scale": -1}}, ["transfer_function", "density_scale"]),
        ({"transfer_function": {"preset": "smoke"}}, ["transfer_function", "smoke"]),
        ({"transfer_function": "no_such_tf.json"}, ["no_such_tf.json", "not found"]),
        ({"transfer_function": "smoke"}, ["transfer_function", "unknown preset 'smoke'"]),
        ({"volume": {"path": "data/missing.npy"}}, ["missing.npy", "not found"]),
        ({"volume": {"path": "data/vol.npy", "dims": [1, 2, 3]}}, ["vol.npy", "dims"]),
        ({"volume": {"path": "data/vol.npy", "scale": 2}}, ["volume", "scale"]),
        ({"volume": {}}, ["volume", "path"]),
        ({"volume": "data/vol.npy"}, ["volume"]),
        ({"volume": {"builtin": "teapot"}}, ["volume", "teapot", "blobs"]),
        ({"volume": {"builtin": "blobs", "resolution": 4}}, ["volume", "resolution"]),
        ({"volume": {"builtin": "blobs", "resolution": [32]}}, ["volume", "resolution"]),
        ({"volume": {"builtin": "blobs", "resolution": 32.0}}, ["volume", "resolution"]),
        ({"volume": {"builtin": "blobs", "size": 32}}, ["volume", "size"]),
    ],
)
def test_scene_file_errors(scene_dir: Path, entries: dict[str, Any], needles: list[str]) -> None:
    path = write_scene(scene_dir, "bad_scene.json", **entries)
    msg = _load_error(path)
    referenced = [n for n in needles if n.endswith((".npy", ".json"))]
    # the scene file is named, or, for a bad referenced file, that file (by its full resolved path) ...
    if referenced:
        assert str(scene_dir / "data" / referenced[0]) in msg or str(scene_dir / referenced[0]) in msg, msg
    else:
        assert "bad_scene.json" in msg, msg
    for needle in needles:  # ... and so is the offending entry
        assert needle in msg, f"{needle!r} not in {msg!r}"


def test_scene_error_not_an_object(tmp_path: Path) -> None:
    p = tmp_path / "list.json"
    p.write_text("[1, 2, 3]")
    msg = _load_error(p)
    assert "list.json" in msg and "object" in msg


def test_scene_error_nan_volume(scene_dir: Path) -> None:
    data = _field()
    data[3, 4, 5] = np.nan
    np.save(scene_dir / "data" / "nan.npy", data)
    msg = _load_error(write_scene(scene_dir, volume={"path": "data/nan.npy"}))
    assert "nan.npy" in msg and "non-finite" in msg and "(3, 4, 5)" in msg


def test_scene_error_wrong_shape_and_dtype(scene_dir: Path) -> None:
    np.save(scene_dir / "data" / "flat.npy", np.zeros((16, 16)))
    msg = _load_error(write_scene(scene_dir, volume={"path": "data/flat.npy"}))
    assert "flat.npy" in msg and "3-D" in msg
    np.save(scene_dir / "data" / "cplx.npy", np.zeros((4, 4, 4), dtype=np.complex64))
    msg = _load_error(write_scene(scene_dir, volume={"path": "data/cplx.npy"}))
    assert "cplx.npy" in msg and "dtype" in msg


def test_scene_error_corrupt_volume(scene_dir: Path) -> None:
    good = (scene_dir / "data" / "vol.npy").read_bytes()
    (scene_dir / "data" / "cut.npy").write_bytes(good[: len(good) // 2])
    msg = _load_error(write_scene(scene_dir, volume={"path": "data/cut.npy"}))
    assert "cut.npy" in msg and "truncated" in msg


def test_scene_from_dict_in_python() -> None:
    d = {
        "volume": {"builtin": "shell", "resolution": 32},
        "transfer_function": {"preset": "shell"},
        "lights": [SUN],
        "camera": CAMERA,
    }
    scene = scene_from_dict(d)
    assert scene.g == 0.0 and scene.tf.name == "shell"
    with pytest.raises(InputError) as info:
        scene_from_dict({**d, "lights": []}, what="inline scene")
    assert_one_line(info.value, "inline scene", "light")


def test_scene_with_overrides() -> None:
    scene = builtin_scene("blobs", resolution=32)
    medium = scene.medium()
    small = scene.with_overrides(g=-0.5, width=8, height=6)
    assert small.g == -0.5 and (small.camera.width, small.camera.height) == (8, 6)
    assert small.medium() is medium  # shares the heavy part
    assert scene.g == 0.3 and scene.camera.width == 256  # the original is untouched
    assert scene.with_overrides(width=10).camera.height == 256
    for kwargs, needle in (
        ({"g": 1.01}, "g"),
        ({"g": float("nan")}, "g"),
        ({"width": 0}, "width"),
        ({"height": 0}, "height"),
    ):
        with pytest.raises(InputError) as info:
            scene.with_overrides(**kwargs)
        assert_one_line(info.value, needle)


def test_scene_constructor_validation() -> None:
    base = builtin_scene("shell", resolution=32)
    with pytest.raises(InputError) as info:
        Scene(base.volume, base.tf, (), base.camera, 0.0, "empty")
    assert_one_line(info.value, "empty", "at least one light")
    with pytest.raises(InputError) as info:
        Scene(base.volume, base.tf, (PointLight([1, 1, 1], [1, 1, 1], 0.0),), base.camera, 0.0, "dark")
    assert_one_line(info.value, "dark", "zero power")
    with pytest.raises(InputError) as info:
        Scene(base.volume, base.tf, base.lights, base.camera, -1.5, "neg")
    assert_one_line(info.value, "neg", "g")
    assert Scene(base.volume, base.tf, base.lights, base.camera, 1.0).g == 1.0  # the boundary is allowed


# ----------------------------------------------------------------------------------------------------------
# Builtin scenes


@pytest.mark.parametrize("name", sorted(BUILTIN_SCENES))
def test_builtin_scene_builds(name: str) -> None:
    scene = builtin_scene(name, resolution=32)
    assert scene.name == name and scene.volume.dims == (32, 32, 32)
    assert scene.volume.data.dtype == np.float32
    assert float(scene.volume.data.min()) >= 0.0 and float(scene.volume.data.max()) <= 1.0
    assert float(scene.volume.data.max()) > 0.0  # not empty
    assert -1.0 <= scene.g <= 1.0
    text = json.dumps(scene.to_dict())
    d = json.loads(text)
    assert set(d) == {"name", "volume", "transfer_function", "lights", "camera", "phase"}
    assert d["volume"]["fingerprint"] == scene.volume.fingerprint()
    # the description's parts load back
    _same_tf(TransferFunction.from_dict(d["transfer_function"]), scene.tf)
    assert len([light_from_dict(x) for x in d["lights"]]) == len(scene.lights)
    Camera.from_dict(d["camera"])


def test_builtin_scene_by_name_through_load_scene() -> None:
    scene = load_scene("shell")
    assert scene.name == "shell" and scene.volume.dims == (96, 96, 96)


def test_unknown_builtin_scene_lists_available(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(InputError) as info:
        builtin_scene("teapot")
    assert_one_line(info.value, "teapot", *BUILTIN_SCENES)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError) as info:
        load_scene("teapot")
    assert_one_line(info.value, "teapot", *BUILTIN_SCENES)


# ----------------------------------------------------------------------------------------------------------
# Issue 11: every JSON entry refuses unknown keys, naming the file, the entry and the key


def test_tf_file_typo_is_refused_not_defaulted(tmp_path: Path) -> None:
    """``"densty_scale": 80`` used to render with the default 50 and exit 0."""
    path = tmp_path / "my_tf.json"
    path.write_text(json.dumps({**INLINE_TF, "densty_scale": 80}))
    with pytest.raises(InputError) as info:
        TransferFunction.load(path)
    msg = assert_one_line(info.value, str(path), "unknown key 'densty_scale'", "did you mean 'density_scale'")
    assert msg.startswith(f"{path}: ") and "'points'" in msg  # the allowed keys are listed
    path.write_text(json.dumps({"preset": "cloud", "densty_scale": 80}))
    with pytest.raises(InputError) as info:
        TransferFunction.load(path)
    assert_one_line(info.value, str(path), "densty_scale")
    path.write_text(json.dumps({"preset": "cloud", "points": INLINE_TF["points"]}))
    with pytest.raises(InputError) as info:
        TransferFunction.load(path)
    assert_one_line(info.value, str(path), "give one of 'preset', 'points' or 'labels', not 'preset' and 'points'")


@pytest.mark.parametrize(("point", "needles"), [
    ({"s": 1.0, "albedo": [1, 1, 1], "opacty": 1.0}, ["points[1]: unknown key 'opacty'", "did you mean 'opacity'"]),
    ({"s": 1.0, "albedo": [1, 1, 1]}, ["points[1]: missing 'opacity'"]),
    ({"albedo": [1, 1, 1], "opacity": 1.0}, ["points[1]: missing 's'"]),
    ({"s": 1.0, "albedo": [1, 1], "opacity": 1.0}, ["points[1]: albedo must have three components"]),
    ({"s": "one", "albedo": [1, 1, 1], "opacity": 1.0}, ["points[1]: needs numeric"]),
    (0.5, ["points[1]: must be an object"]),
])
def test_tf_point_errors_name_the_point(tmp_path: Path, point: Any, needles: list[str]) -> None:
    """An ``"opacty"`` typo used to error without naming the point."""
    path = tmp_path / "tf.json"
    path.write_text(json.dumps({"points": [INLINE_TF["points"][0], point]}))
    with pytest.raises(InputError) as info:
        TransferFunction.load(path)
    assert_one_line(info.value, f"{path} points[1]", *needles)


@pytest.mark.parametrize(("entries", "entry", "key"), [
    ({"volum": {"path": "data/vol.npy"}}, "scene.json", "volum"),
    ({"volume": {"path": "data/vol.npy", "spacng": [1, 1, 2]}}, "scene.json volume", "spacng"),
    ({"volume": {"builtin": "blobs", "resolution": 16, "res": 8}}, "scene.json volume", "res"),
    ({"transfer_function": {"preset": "cloud", "densty_scale": 80}}, "scene.json transfer_function", "densty_scale"),
    ({"transfer_function": {**INLINE_TF, "densty_scale": 80}}, "scene.json transfer_function", "densty_scale"),
    ({"transfer_function": {"points": [{**INLINE_TF["points"][0], "opacty": 0.5}]}},
     "scene.json transfer_function points[0]", "opacty"),
    ({"lights": [SUN, {**SUN, "powr": 9}]}, "scene.json lights[1]", "powr"),
    ({"camera": {**CAMERA, "fow": 20}}, "scene.json camera", "fow"),
    ({"phase": {"g": 0.1, "gg": 0.5}}, "scene.json phase", "gg"),
])
def test_every_scene_entry_refuses_unknown_keys(scene_dir: Path, entries: dict, entry: str, key: str) -> None:
    """Each nested entry of a scene file names the file, the entry and the key, and lists what is allowed."""
    if "volum" in entries:
        spec = json.loads(write_scene(scene_dir).read_text())
        spec["volum"] = spec.pop("volume")
        (scene_dir / "scene.json").write_text(json.dumps(spec))
        path = scene_dir / "scene.json"
    else:
        path = write_scene(scene_dir, **entries)
    msg = _load_error(path)
    assert msg.startswith(f"{scene_dir / entry}: ") or msg.startswith(f"{scene_dir / entry} "), msg
    assert f"'{key}'" in msg and "allowed: " in msg, msg


# ----------------------------------------------------------------------------------------------------------
# Scene.spec: the scene file that rebuilds a scene (recorded in bundles, issue 11)


@pytest.mark.parametrize("name", sorted(BUILTIN_SCENES))
def test_builtin_scene_spec_rebuilds_the_same_scene(name: str) -> None:
    scene = builtin_scene(name, resolution=16).with_overrides(g=0.4, width=20, height=10)
    spec = json.loads(json.dumps(scene.spec()))  # survives JSON
    back = scene_from_dict(spec, what="recorded")
    assert back.fingerprint() == scene.fingerprint() and back.fingerprint_parts() == scene.fingerprint_parts()
    assert back.name == name and back.g == 0.4 and back.camera.to_dict() == scene.camera.to_dict()
    assert spec["volume"] == {"builtin": BUILTIN_SCENES[name]["volume"], "resolution": 16}


def test_file_scene_spec_uses_absolute_paths(scene_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    write_scene(scene_dir, transfer_function="tf.json")
    monkeypatch.chdir(scene_dir)
    scene = load_scene("scene.json")  # relative paths all the way
    spec = scene.spec()
    assert spec is not None and spec["volume"] == {"path": str(scene_dir / "data" / "vol.npy")}
    assert isinstance(spec["transfer_function"], dict)  # embedded: the TF file is not needed to rebuild
    monkeypatch.chdir(tmp_path)  # rebuilt from anywhere
    back = scene_from_dict(json.loads(json.dumps(spec)), what="recorded")
    assert back.fingerprint() == scene.fingerprint() and back.g == scene.g and back.name == "test"


def test_scene_from_arrays_has_no_spec() -> None:
    scene = builtin_scene("blobs", resolution=16)
    assert Scene(scene.volume, scene.tf, scene.lights, scene.camera).spec() is None


def test_an_unknown_light_kind_is_refused_not_taken_for_an_environment() -> None:
    """The kernels branch on point / directional / environment; packing is the one gate where a new light
    class without kernel support must fail loudly instead of rendering as a sky."""
    from dataclasses import dataclass

    from photon_fields.runtime.scene.lights import EnvironmentLight, pack_lights

    @dataclass(frozen=True)
    class SpotLight:
        color: np.ndarray
        power: float

    kind, _, _ = pack_lights([EnvironmentLight([1.0, 1.0, 1.0], 2.0)])
    assert kind.tolist() == [2]
    with pytest.raises(TypeError, match="SpotLight"):
        pack_lights([EnvironmentLight([1.0, 1.0, 1.0], 2.0), SpotLight(np.ones(3), 1.0)])
