"""The first-interaction walks' depth bounds (runtime.wavefront.depth_bounds).

- Brute force: every jittered camera ray that crosses an occupied macrocell enters the first no nearer than its
  tile's ``near`` and leaves the last no farther than its ``far``, and a tile with ``near`` = inf has no such ray;
  for cameras outside the box, close to it with a wide view, and inside it (corners behind the eye), on a sparse
  medium and a solid one whose interior macrocells are not rasterized (the eye also in its cavity and in its wall).
- Bit for bit: the fused first-interaction kernel gives the same items, weights, random states, statuses and
  transmittances with the bounds as with the walk of the whole ray, for both camera estimators, on the embedded
  scenes and from inside the volume, and the bounds do skip rays there (tiles with nothing to meet).
"""

from __future__ import annotations

import numpy as np
import pytest

from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.scene.scene import Scene, builtin_scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import Medium, build_medium
from photon_fields.runtime.wavefront import first_interaction as fim
from photon_fields.runtime.wavefront.depth_bounds import KEPT, camera_depth_bounds, depth_bounds_for

_CAMERAS = {
    "outside": Camera([1.4, 0.9, 1.7], [0.0, 0.05, 0.0], [0.0, 1.0, 0.0], 35.0, 37, 29),
    "close-wide": Camera([0.2, -0.3, 0.75], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 100.0, 33, 33),
    "inside": Camera([0.05, 0.02, -0.1], [0.6, 0.3, 0.4], [0.0, 1.0, 0.0], 70.0, 31, 27),
}


def _sparse_medium() -> Medium:
    """Isolated features and empty space at every scale (zero extinction below 0.62), a box that is not a cube."""
    rng = np.random.default_rng(11)
    raw = np.kron(rng.random((9, 7, 10)) ** 3, np.ones((4, 4, 4)))[:34, :27, :38]
    vol = make_volume(raw, spacing=(1.0, 1.3, 0.8), window=(0.0, 1.0), name="sparse")
    return build_medium(vol, TransferFunction(np.array([0.0, 0.62, 1.0]), np.full((3, 3), 0.8),
                                              np.array([0.0, 0.0, 1.0]), 30.0))


def _solid_medium() -> Medium:
    """A solid ball (most of its macrocells interior: the bounds rasterize only the boundary ones) with an empty
    cavity at the centre of the box, a bump on its side, in a box that is not a cube."""
    n = np.array([30, 26, 34])
    p = (np.stack(np.meshgrid(*[np.arange(k) + 0.5 for k in n], indexing="ij"), axis=-1) - 0.5 * n) / n.max()
    r = np.linalg.norm(p, axis=-1)
    bump = np.linalg.norm(p - np.array([0.3, 0.1, 0.0]), axis=-1)
    raw = ((r < 0.42) & (r > 0.14)) | (bump < 0.12)
    vol = make_volume(raw.astype(float), spacing=(1.0, 1.1, 0.9), window=(0.0, 1.0), name="solid")
    return build_medium(vol, TransferFunction(np.array([0.0, 0.5, 1.0]), np.full((3, 3), 0.8),
                                              np.array([0.0, 0.0, 1.0]), 30.0))


_MEDIA = {"sparse": _sparse_medium, "solid": _solid_medium}


def _jittered_rays(camera: Camera, per_pixel: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(pixel x, y (2, n), unit directions (n, 3)) of ``per_pixel`` jittered rays per pixel, the corners of the
    pixel included."""
    origin, du, dv = camera.image_plane()
    w, h = camera.width, camera.height
    py, px = np.divmod(np.repeat(np.arange(w * h), per_pixel), w)
    jitter = np.random.default_rng(seed).random((2, px.size))
    jitter[:, ::per_pixel] = 0.0
    jitter[:, 1::per_pixel] = 1.0 - 1e-9
    d = origin[None, :] + (px + jitter[0])[:, None] * du[None, :] + (py + jitter[1])[:, None] * dv[None, :]
    return np.stack([px, py]), d / np.linalg.norm(d, axis=1, keepdims=True)


def _occupied_spans(m: Medium, eye: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per ray, the eye distance where it enters its first occupied macrocell and leaves its last (inf / -inf
    when it crosses none), by a slab test against every occupied macrocell's box."""
    cells = np.argwhere(m.majorant > 0.0)
    size = m.bsize / np.array(m.majorant.shape)
    lo = m.bmin + cells * size
    hi = lo + size
    first = np.full(d.shape[0], np.inf)
    last = np.full(d.shape[0], -np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        for c0 in range(0, cells.shape[0], 512):
            ta = (lo[None, c0:c0 + 512] - eye) * inv[:, None]
            tb = (hi[None, c0:c0 + 512] - eye) * inv[:, None]
            t_in = np.maximum(np.nanmax(np.minimum(ta, tb), axis=2), 0.0)
            t_out = np.nanmin(np.maximum(ta, tb), axis=2)
            hit = t_in < t_out
            first = np.minimum(first, np.where(hit, t_in, np.inf).min(axis=1))
            last = np.maximum(last, np.where(hit, t_out, -np.inf).max(axis=1))
    return first, last


@pytest.mark.parametrize("medium", list(_MEDIA))
@pytest.mark.parametrize("view", [*_CAMERAS, "cavity", "in-solid"])
def test_every_ray_meets_the_medium_within_its_tiles_bounds(view: str, medium: str) -> None:
    m = _MEDIA[medium]()
    centre = m.bmin + 0.5 * m.bsize
    if view == "cavity":  # the eye in empty space enclosed by occupied macrocells
        camera = Camera(centre + 0.02, m.bmin + 0.3 * m.bsize, [0.0, 1.0, 0.0], 90.0, 31, 27)
    elif view == "in-solid":  # the eye in the solid ball's wall (an interior macrocell of the solid medium)
        camera = Camera(centre + np.array([0.0, 0.0, 0.27]), centre + np.array([0.3, 0.1, 0.0]), [0.0, 1.0, 0.0],
                        75.0, 31, 27)
    else:
        camera = _CAMERAS[view]
    bounds = camera_depth_bounds(m, camera)
    pix, d = _jittered_rays(camera, 6, seed=len(view))
    first, last = _occupied_spans(m, camera.eye, d)
    near = bounds.near[pix[1] // bounds.tile, pix[0] // bounds.tile]
    far = bounds.far[pix[1] // bounds.tile, pix[0] // bounds.tile]
    crosses = np.isfinite(first)
    inside = view in ("inside", "cavity", "in-solid")
    assert 0.05 < crosses.mean() < 1.0 or inside, f"a poor test view: {crosses.mean():.2f} of rays cross"
    assert np.all(near[crosses] <= first[crosses]), "a ray meets an occupied macrocell before its tile's near bound"
    assert np.all(far[crosses] >= last[crosses]), "a ray leaves an occupied macrocell after its tile's far bound"
    assert np.all(np.isfinite(near[crosses])), "a tile marked empty has a ray that meets the medium"


def test_bounds_hold_for_an_eye_on_a_macrocell_plane() -> None:
    """The eye exactly on a plane between macrocells, looking along it and across it: corners at depth 0 and just
    in front of the eye (projected far outside the image) must widen the bounds, not drop the macrocell."""
    m = _sparse_medium()
    h = m.bsize / np.array(m.majorant.shape)
    eye = m.bmin + 0.5 * m.bsize
    eye[2] = m.bmin[2] + 17 * h[2]
    for target in (eye + np.array([0.0, 0.0, -1.0]), eye + np.array([1.0, 0.3, 0.0]), eye + np.array([0.4, 0.0, 1e-6])):
        camera = Camera(eye, target, [0.0, 1.0, 0.0], 80.0, 29, 23)
        bounds = camera_depth_bounds(m, camera)
        pix, d = _jittered_rays(camera, 8, seed=3)
        first, last = _occupied_spans(m, camera.eye, d)
        crosses = np.isfinite(first)
        near = bounds.near[pix[1] // bounds.tile, pix[0] // bounds.tile]
        far = bounds.far[pix[1] // bounds.tile, pix[0] // bounds.tile]
        assert crosses.any()
        assert np.all(near[crosses] <= first[crosses]) and np.all(far[crosses] >= last[crosses]), target


def _items(scene: Scene, camera: str, depth_bounds: bool) -> tuple[np.ndarray, ...]:
    """Everything the fused kernel writes for one 1-spp batch."""
    m, n = scene.medium(), scene.camera.width * scene.camera.height
    scratch, status, transmit = fim.FirstInteractions.empty(n), np.empty(n, np.uint8), np.empty(n)
    counts = fim.sample_first_interactions(scene, m, 0, n, 7, scratch, status, transmit, camera,
                                           depth_bounds=depth_bounds)
    found = fim.compact_first_interactions(scratch, counts)
    return (counts, status, transmit, found.pixel, found.x, found.d, found.albedo, found.rng, found.weight)


@pytest.mark.parametrize("name", ["vortex", "shell", "blobs", "head"])
def test_bounds_change_no_sample_on_embedded_scenes(name: str) -> None:
    scene = builtin_scene(name).with_overrides(width=48, height=40)
    bounds = depth_bounds_for(scene, scene.medium())
    assert np.isinf(bounds.near).mean() > 0.2, "the bounds skip no ray here: the comparison below shows nothing"
    for camera in ("forced", "delta"):
        with_bounds, whole = _items(scene, camera, True), _items(scene, camera, False)
        for a, b in zip(with_bounds, whole, strict=True):
            np.testing.assert_array_equal(a, b)


def test_bounds_change_no_sample_from_inside_the_volume() -> None:
    scene = builtin_scene("blobs").with_overrides(camera=_CAMERAS["inside"])
    m = scene.medium()
    assert np.all(np.abs(scene.camera.eye - (m.bmin + 0.5 * m.bsize)) < 0.5 * m.bsize), "the eye is not inside"
    for camera in ("forced", "delta"):
        for a, b in zip(_items(scene, camera, True), _items(scene, camera, False), strict=True):
            np.testing.assert_array_equal(a, b)


def test_bounds_are_kept_per_camera_with_the_medium() -> None:
    """A new scene object with the same camera (the viewer's next frame of a resting view) reuses the bounds; another
    camera, another resolution or another medium gets its own; only the last KEPT cameras are kept."""
    scene = builtin_scene("vortex").with_overrides(width=24, height=24)
    m = scene.medium()
    first = depth_bounds_for(scene, m)
    assert depth_bounds_for(scene.with_overrides(g=0.3), m) is first
    moved = scene.with_overrides(camera=_CAMERAS["outside"])
    assert depth_bounds_for(moved, m) is not first
    assert depth_bounds_for(moved, m).near.shape == (8, 10)  # 29 x 37 pixels in 4-pixel tiles
    assert depth_bounds_for(scene.with_overrides(width=28), m).near.shape == (6, 7)
    other = build_medium(scene.volume, scene.tf)
    assert depth_bounds_for(scene, other) is not first
    for w in range(30, 30 + KEPT):
        depth_bounds_for(scene.with_overrides(width=w), m)
    again = depth_bounds_for(scene, m)
    assert again is not first
    np.testing.assert_array_equal(again.near, first.near)


def test_the_occupied_cells_split_into_boundary_and_interior_as_numpy_finds_them() -> None:
    """occupied_cells (found once per grid, rasterized for every camera): every cell > 0 exactly once, interior where
    its six face neighbours are > 0 (outside the grid counts as empty), against a numpy construction."""
    from photon_fields.runtime.wavefront.depth_bounds import occupied_cells

    rng = np.random.default_rng(5)
    grid = (rng.random((9, 7, 8)) < 0.7) * rng.random((9, 7, 8))
    cells = occupied_cells(grid)
    occupied = np.pad(grid > 0.0, 1)
    inner = occupied[1:-1, 1:-1, 1:-1] & occupied[:-2, 1:-1, 1:-1] & occupied[2:, 1:-1, 1:-1] \
        & occupied[1:-1, :-2, 1:-1] & occupied[1:-1, 2:, 1:-1] & occupied[1:-1, 1:-1, :-2] & occupied[1:-1, 1:-1, 2:]
    assert cells.shape == grid.shape
    boundary, interior = cells.cells[:cells.n_boundary], cells.cells[cells.n_boundary:]
    assert {tuple(c) for c in interior} == {tuple(c) for c in np.argwhere(inner)}
    assert {tuple(c) for c in boundary} == {tuple(c) for c in np.argwhere((grid > 0.0) & ~inner)}
    assert len(interior) > 0 and len(boundary) > 0
