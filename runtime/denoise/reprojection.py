"""Camera reprojection for temporal denoisers: where a pixel of this frame was in the previous frame.

The WRLS denoiser (:mod:`photon_fields.runtime.denoise.wrls`) reprojects its per-pixel linear models and
temporal feature along per-pixel velocities ``v_j`` ("optical flow", Iglesias-Guitian et al. Sec. 5.3,
"Temporal Coherence of Linear Models for VPT", and Sec. 6, "Optical Flow Estimation"): ``q = pi(v_j) = j + v_j``
is the position in the previous frame of the world point pixel j sees. Sec. 6 computes the flow from the
view matrices and one world point per pixel; the point comes from a depth map
(:mod:`photon_fields.runtime.denoise.depth`), and a pixel whose depth is infinite (no medium) reprojects as a
direction (a point at infinity, only the camera's rotation moves it).

Pixel <-> ray convention: exactly :meth:`photon_fields.runtime.scene.camera.Camera.image_plane`, which the
renderers' camera rays use (:func:`photon_fields.runtime.wavefront.rays.camera_ray`): image-plane point
``(x, y)`` (pixel units, ``y`` down, pixel ``(px, py)`` covers ``[px, px + 1) x [py, py + 1)``) looks along
``origin + x du + y dv``. :func:`pixel_direction` evaluates that formula with the same arithmetic at the pixel
centre ``(px + 0.5, py + 0.5)``; :func:`project` is its exact inverse, through the camera's orthonormal basis.
``tests/runtime/denoise/test_wrls_reprojection.py`` checks both against the renderers' rays and against
projecting analytic 3-D points.

A view is packed into one float64 array (:func:`pack_view`) so that numba kernels take it as a plain argument.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from photon_fields.runtime.numba_inlining import install
from photon_fields.runtime.scene.camera import Camera

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

#: Layout of :func:`pack_view`'s array: eye, image-plane origin, du, dv (the renderers' ray arithmetic), the
#: orthonormal basis right, up, forward (for projection), the half extents of the image plane at unit distance
#: and the resolution.
EYE, ORIGIN, DU, DV, RIGHT, UP, FWD = 0, 3, 6, 9, 12, 15, 18
HALF_W, HALF_H, WIDTH, HEIGHT = 21, 22, 23, 24
VIEW_SIZE = 25


def pack_view(camera: Camera) -> np.ndarray:
    """``camera`` as the float64 (VIEW_SIZE,) array the kernels of this module read (layout above)."""
    origin, du, dv = camera.image_plane()
    right, up, fwd = camera.basis()
    aspect = camera.width / camera.height
    half = math.tan(math.radians(camera.fov) * 0.5)
    half_h, half_w = (half, half * aspect) if camera.fov_axis == "y" else (half / aspect, half)
    return np.concatenate([camera.eye, origin, du, dv, right, up, fwd,
                           [half_w, half_h, float(camera.width), float(camera.height)]]).astype(np.float64)


@njit(cache=True, inline="always")
def pixel_direction(view: np.ndarray, x: float, y: float) -> tuple[float, float, float]:
    """Unit direction through image-plane point ``(x, y)``: the arithmetic of
    :func:`photon_fields.runtime.wavefront.rays.camera_ray` (pixel centre: ``x = px + 0.5``, ``y = py + 0.5``)."""
    dx = view[ORIGIN] + x * view[DU] + y * view[DV]
    dy = view[ORIGIN + 1] + x * view[DU + 1] + y * view[DV + 1]
    dz = view[ORIGIN + 2] + x * view[DU + 2] + y * view[DV + 2]
    inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx * inv, dy * inv, dz * inv


@njit(cache=True, inline="always")
def project_direction(view: np.ndarray, vx: float, vy: float, vz: float) -> tuple[float, float, bool]:
    """Image-plane point ``(x, y)`` that looks along the (not necessarily unit) vector ``v``, and whether ``v``
    points in front of the camera; the inverse of :func:`pixel_direction`."""
    f = vx * view[FWD] + vy * view[FWD + 1] + vz * view[FWD + 2]
    if not f > 0.0:
        return 0.0, 0.0, False
    r = (vx * view[RIGHT] + vy * view[RIGHT + 1] + vz * view[RIGHT + 2]) / f
    u = (vx * view[UP] + vy * view[UP + 1] + vz * view[UP + 2]) / f
    x = (r + view[HALF_W]) * view[WIDTH] / (2.0 * view[HALF_W])
    y = (view[HALF_H] - u) * view[HEIGHT] / (2.0 * view[HALF_H])
    return x, y, True


@njit(cache=True, inline="always")
def project_point(view: np.ndarray, px: float, py: float, pz: float) -> tuple[float, float, float, bool]:
    """Image-plane point ``(x, y)`` of world point ``p``, its distance from the eye, and whether it is in
    front of the camera."""
    vx, vy, vz = px - view[EYE], py - view[EYE + 1], pz - view[EYE + 2]
    x, y, ok = project_direction(view, vx, vy, vz)
    return x, y, math.sqrt(vx * vx + vy * vy + vz * vz), ok


@njit(cache=True, inline="always")
def reproject_pixel(cur: np.ndarray, prev: np.ndarray, px: int, py: int,
                    depth: float) -> tuple[float, float, float, bool]:
    """Where the world point seen by pixel ``(px, py)`` of view ``cur`` at distance ``depth`` along its
    centre ray lies in view ``prev``: image-plane ``(x, y)``, its distance from ``prev``'s eye, and whether it
    is in front of ``prev``. This is Sec. 5.3's ``q = pi(v_j) = j + v_j`` with the flow ``v_j`` of Sec. 6.

    ``depth <= 0`` stands for a point at infinity (the background), whose distance is returned as -1: the
    denoiser's kernels are compiled with fastmath, under which infinities are not allowed."""
    dx, dy, dz = pixel_direction(cur, px + 0.5, py + 0.5)
    if depth <= 0.0:
        x, y, ok = project_direction(prev, dx, dy, dz)
        return x, y, -1.0, ok
    return project_point(prev, cur[EYE] + depth * dx, cur[EYE + 1] + depth * dy, cur[EYE + 2] + depth * dz)


@njit(cache=True)
def reproject_image(cur: np.ndarray, prev: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                    np.ndarray, np.ndarray]:
    """:func:`reproject_pixel` for every pixel of ``depth`` (H, W; inf or <= 0: background): (x, y, distance,
    in front), each (H, W), the distance inf for the background. For tests and tools; the denoiser
    reprojects inside its own kernel."""
    h, w = depth.shape
    xs = np.empty((h, w))
    ys = np.empty((h, w))
    ds = np.empty((h, w))
    ok = np.empty((h, w), dtype=np.bool_)
    for py in range(h):
        for px in range(w):
            d = depth[py, px]
            xs[py, px], ys[py, px], ds[py, px], ok[py, px] = reproject_pixel(cur, prev, px, py,
                                                                             -1.0 if math.isinf(d) else d)
            if ds[py, px] < 0.0:
                ds[py, px] = math.inf
    return xs, ys, ds, ok
