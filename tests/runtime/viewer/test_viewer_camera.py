"""The viewer's orbit camera (runtime/viewer/camera.py): it starts as the scene's camera, every frame shape
contains the scene camera's view (a tall, narrow window must not cut the volume off at the sides), and a pan
of one view height moves the target by the height the frame shows."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.viewer.camera import OrbitView


def _scene_camera(width: int, height: int, fov: float = 40.0, axis: str = "y") -> Camera:
    return Camera([1.2, 0.7, 1.9], [0.05, -0.02, 0.0], [0.0, 1.0, 0.0], fov, width, height, axis)


def _half_extents(cam: Camera) -> tuple[float, float]:
    """(half width, half height) of the image plane at unit distance."""
    _, du, dv = cam.image_plane()
    return float(np.linalg.norm(du)) * cam.width / 2.0, float(np.linalg.norm(dv)) * cam.height / 2.0


@pytest.mark.parametrize(("size", "axis"), [((64, 64), "y"), ((96, 54), "y"), ((54, 96), "x"), ((96, 54), "x")])
def test_the_view_starts_as_the_scene_camera(size: tuple[int, int], axis: str) -> None:
    cam = _scene_camera(*size, axis=axis)
    again = OrbitView.from_camera(cam).camera(*size)
    np.testing.assert_allclose(again.eye, cam.eye, atol=1e-12)
    np.testing.assert_allclose(again.target, cam.target, atol=1e-12)
    assert (again.fov, again.fov_axis) == (cam.fov, cam.fov_axis)


@settings(max_examples=200, deadline=None)
@given(base=st.tuples(st.integers(16, 400), st.integers(16, 400)), frame=st.tuples(st.integers(16, 2000),
       st.integers(16, 2000)), fov=st.floats(10.0, 120.0), axis=st.sampled_from(["x", "y"]))
def test_every_frame_contains_the_scene_cameras_view_tightly(base: tuple[int, int], frame: tuple[int, int],
                                                             fov: float, axis: str) -> None:
    cam = _scene_camera(*base, fov=fov, axis=axis)
    w0, h0 = _half_extents(cam)
    w, h = _half_extents(OrbitView.from_camera(cam).camera(*frame))
    assert w >= w0 * (1 - 1e-9) and h >= h0 * (1 - 1e-9)
    assert min(w / w0, h / h0) == pytest.approx(1.0, rel=1e-9)  # no larger than needed


def test_a_tall_window_widens_the_view_and_a_wide_one_keeps_it() -> None:
    view = OrbitView.from_camera(_scene_camera(64, 64))
    wide = view.camera(200, 100)
    assert (wide.fov, wide.fov_axis) == (40.0, "y")
    tall = view.camera(100, 200)
    w, h = _half_extents(tall)
    assert w == pytest.approx(math.tan(math.radians(20.0)), rel=1e-12) and h == pytest.approx(2 * w, rel=1e-12)


@pytest.mark.parametrize("frame", [(64, 64), (200, 100), (100, 200)])
def test_a_pan_of_one_view_height_moves_the_target_by_the_height_shown(frame: tuple[int, int]) -> None:
    view = OrbitView.from_camera(_scene_camera(64, 64))
    moved = view.pan(0.0, 1.0, frame[0] / frame[1])
    _, half_h = _half_extents(view.camera(*frame))
    shown = 2.0 * half_h * view.distance
    assert float(np.linalg.norm(moved.target - view.target)) == pytest.approx(shown, rel=1e-9)
