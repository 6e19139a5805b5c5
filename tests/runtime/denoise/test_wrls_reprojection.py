"""Reprojection and depth for the WRLS denoiser: the pixel <-> ray convention is the renderers', a depth map of
an analytic medium is its analytic value, and a pixel's world point lands where projecting that 3-D point puts
it (runtime/denoise/reprojection.py, runtime/denoise/depth.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import constant_tf
from numba import njit

from photon_fields.runtime.denoise.depth import DepthEstimator
from photon_fields.runtime.denoise.reprojection import pack_view, pixel_direction, project_direction, reproject_image
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.camera import Camera, orbit_camera
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import build_medium
from photon_fields.runtime.transport.rng import next_float, stream_state
from photon_fields.runtime.wavefront.rays import generate_camera_rays

SIGMA = 4.0  # extinction of the homogeneous unit box [-0.5, 0.5]^3


@pytest.fixture(scope="module")
def box():  # noqa: ANN201
    return build_medium(make_volume(np.ones((8, 8, 8)), window=(0.0, 1.0)), constant_tf(SIGMA))


def camera(width: int = 40, height: int = 30, fov_axis: str = "y") -> Camera:
    return Camera([0.4, 0.3, 2.2], [0.0, 0.05, 0.0], [0.0, 1.0, 0.0], 35.0, width, height, fov_axis)


def box_interval(eye: np.ndarray, d: np.ndarray) -> tuple[float, float]:
    """Slab test against [-0.5, 0.5]^3 in plain numpy (independent of the kernels)."""
    with np.errstate(divide="ignore"):
        ta, tb = (-0.5 - eye) / d, (0.5 - eye) / d
    return float(np.max(np.minimum(ta, tb))), float(np.min(np.maximum(ta, tb)))


def analytic_depth(eye: np.ndarray, d: np.ndarray, quantile: float = 0.5) -> float:
    """The quantile of the first-collision distance in the homogeneous box along unit direction d."""
    t0, t1 = box_interval(eye, d)
    if t0 >= t1:
        return math.inf
    opacity = 1.0 - math.exp(-SIGMA * (t1 - t0))
    return t0 - math.log(1.0 - quantile * opacity) / SIGMA


def project_solve(cam: Camera, point: np.ndarray) -> tuple[float, float]:
    """Image-plane point of ``point`` by solving eye + s (origin + x du + y dv) = point for (s, s x, s y): the
    camera's own image-plane definition, no basis algebra."""
    origin, du, dv = cam.image_plane()
    s, sx, sy = np.linalg.solve(np.stack([origin, du, dv], axis=1), point - cam.eye)
    return sx / s, sy / s


@njit
def jitter(seed: int, w: int) -> tuple[float, float]:
    """Work item w's sub-pixel offset, drawn as camera_ray draws it (compiled: the state must stay uint64)."""
    s = stream_state(np.uint64(seed), np.uint64(w))
    s, u = next_float(s)
    s, v = next_float(s)
    return u, v


@pytest.mark.parametrize("fov_axis", ["y", "x"])
def test_pixel_directions_are_the_renderers_camera_rays(fov_axis: str) -> None:
    """The renderers' jittered ray through pixel p at sub-pixel (u, v), projected back, is image-plane point
    (px + u, py + v); pixel_direction at that point is the same ray."""
    cam = camera(13, 7, fov_axis)
    view = pack_view(cam)
    work = np.arange(3 * cam.width * cam.height, dtype=np.int64)
    seed = 11
    rays = generate_camera_rays(cam, work, seed)
    for i in range(0, len(work), 17):
        p = int(rays.pixel[i])
        u, v = jitter(seed, int(work[i]))
        x_exp, y_exp = p % cam.width + u, p // cam.width + v
        x, y, front = project_direction(view, *rays.d[:, i])
        assert front
        assert x == pytest.approx(x_exp, abs=1e-9) and y == pytest.approx(y_exp, abs=1e-9)
        np.testing.assert_allclose(pixel_direction(view, x_exp, y_exp), rays.d[:, i], atol=1e-12)


def test_projection_of_points_matches_the_image_plane_definition() -> None:
    cam = camera()
    view = pack_view(cam)
    rng = np.random.default_rng(3)
    for _ in range(20):
        x, y = rng.uniform(-5, cam.width + 5), rng.uniform(-5, cam.height + 5)
        d = np.array(pixel_direction(view, x, y))
        point = cam.eye + rng.uniform(0.5, 4.0) * d
        assert project_solve(cam, point) == pytest.approx((x, y), abs=1e-9)
    # Behind the camera: not in front.
    assert not project_direction(view, *(-(cam.target - cam.eye)))[2]


def test_depth_of_a_homogeneous_box_is_the_analytic_median_first_collision(box) -> None:  # noqa: ANN001
    cam = camera()
    view = pack_view(cam)
    for quantile in (0.5, 0.25):
        depth = DepthEstimator(box, block=1, stride=1, quantile=quantile).depth(cam)
        expected = np.array([[analytic_depth(cam.eye, np.array(pixel_direction(view, px + 0.5, py + 0.5)), quantile)
                              for px in range(cam.width)] for py in range(cam.height)])
        assert np.isinf(expected).any() and np.isfinite(expected).any()  # the box and the background in view
        np.testing.assert_array_equal(np.isinf(depth), np.isinf(expected))
        fin = np.isfinite(expected)
        np.testing.assert_allclose(depth[fin], expected[fin], rtol=1e-5)


@pytest.mark.parametrize("name", ["vortex", "shell", "head"])
def test_depth_leaping_over_empty_cells_gives_the_cell_by_cell_depths(name: str) -> None:
    """The depth walk jumps over empty cubes of coarse cells (runtime/denoise/depth.py); the depths are those of
    the walk that steps every cell, on the embedded scenes' empty space and structure, from two views."""
    from photon_fields.runtime.scene.scene import builtin_scene

    scene = builtin_scene(name, resolution=48).with_overrides(width=40, height=32)
    medium = scene.medium()
    leaping, stepping = DepthEstimator(medium, stride=1), DepthEstimator(medium, stride=1, leap=False)
    assert leaping.leap.max() >= 2 and stepping.leap.max() == 1  # there is empty space to leap over
    assert_same_depths(leaping, stepping, scene.camera)


def assert_same_depths(est: DepthEstimator, other: DepthEstimator, camera: Camera) -> None:
    """Both estimators' depth maps from two orbit views: inf at the same pixels, the same depths elsewhere."""
    for angle in (0.0, 137.0):
        cam = orbit_camera(camera, angle)
        a, b = est.depth(cam), other.depth(cam)
        np.testing.assert_array_equal(np.isinf(a), np.isinf(b))
        assert np.isfinite(a).sum() > 50
        np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], rtol=1e-6)


@pytest.mark.parametrize("name", ["vortex", "shell", "head", "odd"])
def test_depth_walks_within_tile_bounds_give_the_whole_walks_depths(name: str) -> None:
    """Each depth ray is walked only within its tile's depth bounds over the coarse cells with medium (none in an
    empty tile): the depths of the walk through the whole box, on the embedded scenes from three views (one of them
    inside the volume) and on a volume whose coarse grid reaches past its box (odd voxel counts)."""
    from photon_fields.runtime.scene.scene import builtin_scene

    scene = builtin_scene("blobs" if name == "odd" else name, resolution=47 if name == "odd" else 48)
    scene = scene.with_overrides(width=44, height=36)
    medium = scene.medium()
    for stride in (1, 2):
        bounded, whole = DepthEstimator(medium, stride=stride), DepthEstimator(medium, stride=stride, bounds=False)
        inside = Camera(medium.bmin + 0.45 * medium.bsize, medium.bmin + 0.9 * medium.bsize, [0.0, 1.0, 0.0], 80.0,
                        44, 36)
        for cam in (orbit_camera(scene.camera, 0.0), orbit_camera(scene.camera, 137.0), inside):
            a, b = bounded.depth(cam), whole.depth(cam)
            np.testing.assert_array_equal(np.isinf(a), np.isinf(b))
            assert 20 < np.isfinite(a).sum() < a.size or cam is inside, "nothing or everything seen: a poor view"
            np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], rtol=1e-9)


def test_depth_stride_gives_each_block_its_centre_ray_depth(box) -> None:  # noqa: ANN001
    cam = camera(41, 29)  # odd sizes: partial blocks at the right and bottom
    view = pack_view(cam)
    coarse = DepthEstimator(box, block=1, stride=2).depth(cam)
    assert coarse.shape == (cam.height, cam.width)
    for py, px in ((0, 0), (13, 21), (28, 40), (28, 7)):
        cy = 0.5 * (2 * (py // 2) + min(2 * (py // 2 + 1), cam.height))
        cx = 0.5 * (2 * (px // 2) + min(2 * (px // 2 + 1), cam.width))
        expected = analytic_depth(cam.eye, np.array(pixel_direction(view, cx, cy)))
        assert coarse[py, px] == pytest.approx(expected, rel=1e-5) if math.isfinite(expected) else np.isinf(
            coarse[py, px])


def test_history_reprojects_onto_the_projection_of_the_3d_point(box) -> None:  # noqa: ANN001
    """Under a known orbit step, pixel j's median-depth point (analytic) projects where reproject_image says;
    a pixel at infinity moves with the rotation only."""
    cur, prev = orbit_camera(camera(), 4.0), camera()
    depth = DepthEstimator(box, block=1, stride=1).depth(cur)
    xs, ys, dist, front = reproject_image(pack_view(cur), pack_view(prev), depth.astype(np.float64))
    view = pack_view(cur)
    checked = 0
    for py in range(0, cur.height, 3):
        for px in range(0, cur.width, 3):
            d = np.array(pixel_direction(view, px + 0.5, py + 0.5))
            t = analytic_depth(cur.eye, d)
            if math.isinf(t):
                assert np.isinf(dist[py, px])
                # A direction: the previous camera sees it at the image-plane point of eye + d.
                expected = project_solve(prev, prev.eye + d)
            else:
                point = cur.eye + t * d
                expected = project_solve(prev, point)
                assert dist[py, px] == pytest.approx(np.linalg.norm(point - prev.eye), rel=1e-5)
                checked += 1
            assert front[py, px]
            assert (xs[py, px], ys[py, px]) == pytest.approx(expected, abs=2e-4)
    assert checked > 20
    # The orbit moved the picture: the check above is not the identity.
    assert np.abs(xs - (np.arange(cur.width) + 0.5)[None]).max() > 1.0


def test_depth_estimator_refuses_bad_parameters_in_one_line(box) -> None:  # noqa: ANN001
    for kw in ({"stride": 0}, {"block": 2.5}, {"quantile": 1.0}, {"min_opacity": -0.1}):
        with pytest.raises(InputError) as err:
            DepthEstimator(box, **kw)
        assert "\n" not in str(err.value) and str(err.value).startswith("depth ")


def test_the_depth_grid_keeps_to_its_cells_per_side_on_large_volumes() -> None:
    """The automatic block is 2 up to 256 voxels a side and grows beyond, so that the coarse grid (and its leap
    tables, rebuilt at every transfer-function edit) stays within ``MAX_CELLS_SIDE`` cells a side."""
    from photon_fields.runtime.denoise.depth import DEFAULT_BLOCK, MAX_CELLS_SIDE, auto_block

    assert auto_block((96, 96, 96)) == auto_block((256, 200, 10)) == DEFAULT_BLOCK == 2
    assert auto_block((257, 10, 10)) == 3 and auto_block((512, 512, 300)) == 4
    rng = np.random.default_rng(3)
    medium = build_medium(make_volume(rng.random((300, 12, 9))), constant_tf(0.5))
    est = DepthEstimator(medium)
    assert est.grid.shape == (100, 4, 3) and max(est.grid.shape) <= MAX_CELLS_SIDE


@pytest.mark.parametrize(("size", "shared"), [(48, True), (47, False)])
def test_the_depth_walk_leaps_with_the_mediums_table_where_the_cells_are_its_macrocells(size: int,
                                                                                        shared: bool) -> None:
    """On sides the block divides, the depth grid's cells are the medium's macrocells and its leap table is the
    medium's (no second set of sweeps); the depths are the cell-by-cell walk's either way."""
    from photon_fields.runtime.scene.scene import builtin_scene

    scene = builtin_scene("vortex", resolution=size).with_overrides(width=40, height=32)
    medium = scene.medium()
    est, stepping = DepthEstimator(medium, stride=1), DepthEstimator(medium, stride=1, leap=False)
    assert (est.leap is medium.leap) == shared and est.leap.max() >= 2
    assert_same_depths(est, stepping, scene.camera)
