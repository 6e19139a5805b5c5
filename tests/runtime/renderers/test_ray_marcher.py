"""The ray marcher's empty-space skipping (runtime/renderers/ray_marcher.py, ``skip_empty``): camera and shadow
rays look nothing up where the majorant grid says the medium is empty, and the image is the same, bit for bit,
as the marcher that looks up every sample; on a sparse scene it does far fewer lookups.

(The marcher against the path tracer's single scattering: tests/runtime/renderers/test_path_tracer.py.)"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import small_camera

from photon_fields.runtime.renderers.ray_marcher import render_ray_marched
from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.scene.lights import DirectionalLight, EnvironmentLight, PointLight
from photon_fields.runtime.scene.scene import Scene, builtin_scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.tracking import empty_run


def _sparse_scene() -> Scene:
    """Two small dense blobs in a mostly empty box, a directional and a point light."""
    n = 40
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    field = (np.exp(-((X - 0.3) ** 2 + (Y - 0.4) ** 2 + (Z - 0.5) ** 2) / 0.004)
             + np.exp(-((X - 0.7) ** 2 + (Y - 0.6) ** 2 + (Z - 0.4) ** 2) / 0.006))
    tf = TransferFunction(np.array([0.0, 0.2, 1.0]), np.array([[0.9, 0.8, 0.7]] * 3), np.array([0.0, 0.0, 1.0]),
                          30.0, "sparse")
    lights = (DirectionalLight([-0.5, -0.8, 0.3], [1.0, 0.9, 0.8], 2.0), PointLight([0.9, 0.8, 0.9], [1.0, 1.0, 1.0],
                                                                                     0.5))
    return Scene(make_volume(np.clip(field, 0, 1), window=(0.0, 1.0), name="two_blobs"), tf, lights,
                 small_camera(32), 0.3, "sparse")


@pytest.mark.parametrize("scene", ["sparse", "vortex", "shell", "inside"])
def test_skipping_empty_space_changes_no_pixel(scene: str) -> None:
    """Skipping: jumps over empty runs and each ray marched only within its tile's depth bounds (also with the
    eye inside the volume, where macrocells behind it widen every tile's bounds)."""
    if scene == "inside":
        vortex = builtin_scene("vortex")
        m = vortex.medium()
        s = vortex.with_overrides(camera=Camera(m.bmin + 0.45 * m.bsize, m.bmin + 0.9 * m.bsize, [0.0, 1.0, 0.0],
                                                80.0, 32, 28))
    else:
        s = _sparse_scene() if scene == "sparse" else builtin_scene(scene).with_overrides(width=32, height=32)
    skipped = render_ray_marched(s, spp=2, seed=4, progress=False).layers
    every = render_ray_marched(s, spp=2, seed=4, progress=False, skip_empty=False).layers
    assert skipped["L_d"].max() > 0.0
    for layer in ("L", "L_d", "L_e"):
        np.testing.assert_array_equal(skipped[layer], every[layer], err_msg=f"{scene}: {layer}")


def test_empty_run_stays_in_empty_space_and_ends_at_the_medium() -> None:
    """Along random rays from random points: every point before the run's end has sigma_t = 0 (checked by
    lookups), and where the run is 0 the point's macrocell holds medium (its majorant is > 0)."""
    from photon_fields.runtime.transport.medium import extinction_at

    m = _sparse_scene().medium()
    rng = np.random.default_rng(1)
    runs = 0
    for _ in range(400):
        p = m.bmin + rng.random(3) * m.bsize
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        run = empty_run(m, *p, *d)
        cells = np.array(m.majorant.shape)
        cell = np.minimum(((p - m.bmin) / m.bsize * cells).astype(int), cells - 1)
        if run == 0.0:
            assert m.majorant[tuple(cell)] > 0.0
            continue
        runs += 1
        assert m.majorant[tuple(cell)] == 0.0
        for t in np.linspace(0.0, run, 50, endpoint=False):
            q = p + t * d
            if np.all((q >= m.bmin) & (q <= m.bmin + m.bsize)):
                assert extinction_at(m, *q) == 0.0
    assert runs > 100 and math.isfinite(run)


# --- the preview: camera quadrature and light volume (runtime/transport/light_volume.py) ---------------------------

def _slab_scene(optical_depth_per_voxel: float = 1.5) -> Scene:
    """A homogeneous medium filling a 16^3 box, seen face-on from far away (fov 0.5 degrees) with a directional
    light from behind the camera: single scattering is albedo / (4 pi) / 2 per unit irradiance (g = 0)."""
    from photon_fields.runtime.scene.camera import Camera

    vol = make_volume(np.ones((16, 16, 16)), window=(0.0, 1.0), name="slab")
    tf = TransferFunction(np.array([0.0, 1.0]), np.array([[0.8, 0.8, 0.8]] * 2), np.array([1.0, 1.0]),
                          optical_depth_per_voxel / vol.voxel_size, "slab")
    c = vol.bbox_min + 0.5 * vol.extent
    cam = Camera(c + np.array([0.0, 0.0, 40.0]), c, [0, 1, 0], 0.5, 8, 8)
    return Scene(vol, tf, (DirectionalLight([0, 0, -1], [1, 1, 1], 1.0),), cam, 0.0, "slab")


def test_scattering_centroid_is_the_mean_depth_of_scattering_in_a_segment() -> None:
    from photon_fields.runtime.renderers.ray_marcher import scattering_centroid

    for sigma, seg in ((1e-6, 0.3), (0.5, 0.2), (3.0, 1.0), (40.0, 0.1), (1e-3, 0.9)):
        t = np.linspace(0.0, seg, 200001)
        pdf = sigma * np.exp(-sigma * t)
        mean = np.trapezoid(t * pdf, t) / np.trapezoid(pdf, t)
        assert scattering_centroid(sigma, seg, math.exp(-sigma * seg)) == pytest.approx(mean, rel=1e-5, abs=1e-9)


def test_a_coarse_step_reads_the_light_at_the_lit_wall() -> None:
    """1.5 optical depths per camera step: scattering happens near the start of each segment, where the light
    still is. Evaluated at the segment's scattering centroid the marcher is within 6 % of the analytic value;
    at the midpoint (half a step deep, after the wall absorbed the light) it read 23 % dark."""
    scene = _slab_scene()
    exact = 0.8 / (4 * math.pi) / 2
    fine = render_ray_marched(scene, spp=4, step=0.02, shadows="march", shadow_step=0.02, min_transmittance=1e-6,
                              progress=False).layers["L_d"]
    assert fine.mean() == pytest.approx(exact, rel=1e-3)
    coarse = render_ray_marched(scene, spp=16, shadows="march", shadow_step=0.02, progress=False).layers["L_d"]
    assert abs(coarse.mean() / exact - 1.0) < 0.06
    preview = render_ray_marched(scene, spp=16, progress=False).layers["L_d"]
    assert abs(preview.mean() / exact - 1.0) < 0.15  # the lit face interpolates towards the ring outside the box


@pytest.mark.parametrize("tau", [0.25, 0.5])
def test_long_segments_stay_within_one_optical_depth_in_a_lit_slab(tau: float) -> None:
    """A dense medium lit from the camera's side: the light falls off within a segment, which is read at one point.
    The step grid's depth bound keeps a segment within one optical depth (at 0.25 per voxel: 3-voxel segments), and
    the marcher within 2.5 % of the analytic single scattering of the 16-voxel slab; 3 optical depths a segment read
    it 6-10 % dark."""
    from photon_fields.runtime.renderers.ray_marcher import scene_step_units

    scene = _slab_scene(tau)
    exact = 0.8 / (4 * math.pi) * (1.0 - math.exp(-2.0 * 16 * tau)) / 2
    units = scene_step_units(scene, 1.0, 4.0)
    assert units.max() == (3 if tau == 0.25 else 1)
    marched = render_ray_marched(scene, spp=16, shadows="march", shadow_step=0.02, progress=False).layers["L_d"]
    assert abs(marched.mean() / exact - 1.0) < 0.025


def test_early_termination_loses_what_scatters_behind_the_stopping_point() -> None:
    """Lit from behind the camera, the slab scatters towards the camera at depth t in proportion to exp(-2 sigma t):
    camera and light transmittance alike. A ray stopped where its transmittance T_s falls below the threshold
    loses exactly the fraction T_s^2 of what it would scatter (the slab is 4 optical depths, exp(-8) beyond it),
    and T_s lies between the threshold times one segment's transmittance (3 voxels of 0.25) and the threshold."""
    scene = _slab_scene(0.25)
    full = render_ray_marched(scene, spp=16, shadows="march", shadow_step=0.02, min_transmittance=1e-9,
                              progress=False).layers["L_d"].mean()
    for threshold in (0.03, 0.1):
        stopped = render_ray_marched(scene, spp=16, shadows="march", shadow_step=0.02, min_transmittance=threshold,
                                     progress=False).layers["L_d"].mean()
        lost = 1.0 - stopped / full
        assert (threshold * math.exp(-0.75)) ** 2 * 0.9 < lost < threshold ** 2 * 1.1, (threshold, lost)


def test_light_volume_cells_are_shadow_rays_from_their_centres_and_only_read_cells_are_marched() -> None:
    from photon_fields.runtime.renderers.ray_marcher import scene_light_volume
    from photon_fields.runtime.transport.cell_grid import cell_centre
    from photon_fields.runtime.transport.emitters import delta_light_direction
    from photon_fields.runtime.transport.light_volume import TAU_MAX, UNFILLED
    from photon_fields.runtime.transport.marching import march_transmittance_in_segments

    scene = _sparse_scene()
    render_ray_marched(scene, spp=1, progress=False)
    lv = scene_light_volume(scene, 1.0, 0.5)
    filled = lv.values != UNFILLED
    assert 0.001 < filled.mean() < 0.5  # the cells that samples read, not the grid
    m = scene.medium()
    kind, vec, _ = scene.packed_lights()
    rng = np.random.default_rng(0)
    cells = np.argwhere(filled)
    for i, j, k, light in cells[rng.choice(len(cells), 60, replace=False)]:
        p = cell_centre(lv.grid, i, j, k)
        lx, ly, lz, _, tend = delta_light_direction(kind[light], vec[light], *p)
        t = march_transmittance_in_segments(m, lv.units, *p, lx, ly, lz, tend, lv.shadow_step, TAU_MAX)
        assert lv.values[i, j, k, light] == np.float32(t)


def test_marked_cells_are_filled_brick_by_brick_and_no_others() -> None:
    """want_stencil flags the brick of every corner it marks (a stencil straddling bricks, the partial bricks at
    the grid's far end) and fill_wanted marches exactly the marked cells, then clears the flags."""
    from photon_fields.runtime.transport.light_volume import (
        BRICK,
        UNFILLED,
        fill_wanted,
        new_light_volume,
        want_stencil,
    )

    scene = _sparse_scene()
    m = scene.medium()
    kind, vec, _ = scene.packed_lights()
    assert len(kind) == 2  # the lights the marks below name
    lv = new_light_volume(m, len(kind), 1.0, 0.01)
    g = np.asarray(lv.values.shape[:3])
    assert (g % BRICK != 0).any()  # a partial brick to reach
    marked = set()
    for base, light in (((0, 0, 0), 0), ((BRICK - 1, BRICK - 1, BRICK - 1), 1), (tuple(g - 2), 0),
                        ((BRICK - 1, 2 * BRICK - 1, 3), 0)):
        want_stencil(lv.values, lv.wanted, light, *base)
        marked |= {(base[0] + (c & 1), base[1] + ((c >> 1) & 1), base[2] + ((c >> 2) & 1), light) for c in range(8)}
    assert {tuple(b) for b in np.argwhere(lv.wanted)} == {(i // BRICK, j // BRICK, k // BRICK) for i, j, k, _ in marked}
    fill_wanted(m, kind, vec, lv)
    assert {tuple(c) for c in np.argwhere(lv.values != UNFILLED)} == marked
    assert (lv.values[lv.values != UNFILLED] >= 0.0).all() and not lv.wanted.any()


def test_a_fill_over_a_medium_of_another_macrocell_grid_is_refused() -> None:
    """The cells' shadow rays read the volume's step units per macrocell: a medium of another grid (here 1-voxel
    macrocells for a volume made over 2-voxel ones) would index past them, so the fill refuses it."""
    from photon_fields.runtime.transport.light_volume import fill_wanted, new_light_volume
    from photon_fields.runtime.transport.medium import build_medium

    scene = builtin_scene("blobs", 16)
    m = scene.medium()
    kind, vec, _ = scene.packed_lights()
    lv = new_light_volume(m, len(kind), 1.0, 0.5 * scene.volume.voxel_size)
    assert fill_wanted(m, kind, vec, lv)
    finer = build_medium(scene.volume, scene.tf, macrocell=1)
    with pytest.raises(ValueError, match="per macrocell"):
        fill_wanted(finer, kind, vec, lv)


def test_a_cancelled_fill_keeps_its_cells_and_the_next_frame_completes_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """A render cancelled while its light volume fills (a chunk of one brick at a time here) raises, keeps the
    cells it filled and the flags of the bricks it did not; the next frame fills those, and its image is a cold
    render's bit for bit. Cancelled before its first batch, a render fills nothing."""
    from photon_fields.runtime.renderers.ray_marcher import light_volume_settings, scene_light_volume
    from photon_fields.runtime.transport import light_volume
    from photon_fields.runtime.wavefront.batches import RenderCancelledError

    monkeypatch.setattr(light_volume, "FILL_CHUNK", 1)
    scene = _sparse_scene()
    lv = scene_light_volume(scene, *light_volume_settings(scene))
    with pytest.raises(RenderCancelledError):
        render_ray_marched(scene, spp=1, seed=4, progress=False, cancel=lambda: True)
    assert (lv.values == light_volume.UNFILLED).all() and not lv.wanted.any()
    asked = []

    def cancel_in_the_fill() -> bool:
        asked.append(1)
        return len(asked) >= 4  # before the batch and the fill's first two chunks: go on; then stop

    with pytest.raises(RenderCancelledError):
        render_ray_marched(scene, spp=1, seed=4, progress=False, cancel=cancel_in_the_fill)
    assert len(asked) == 4 and lv.wanted.sum() > 0 and (lv.values >= 0.0).sum() > 0
    warm = render_ray_marched(scene, spp=1, seed=4, progress=False).layers["L_d"]
    assert not lv.wanted.any() and not (lv.values == light_volume.WANTED).any()
    np.testing.assert_array_equal(warm, render_ray_marched(_sparse_scene(), spp=1, seed=4,
                                                           progress=False).layers["L_d"])


def _dilated(filled: np.ndarray) -> np.ndarray:
    """Each light's filled cells (gx, gy, gz, lights) grown by the 26 cells around each (clipped at the grid)."""
    out = filled.copy()
    g = filled.shape[:3]
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            for dk in (-1, 0, 1):
                src = tuple(slice(max(0, -d), n - max(0, d)) for d, n in zip((di, dj, dk), g, strict=True))
                dst = tuple(slice(max(0, d), n - max(0, -d)) for d, n in zip((di, dj, dk), g, strict=True))
                out[dst] |= filled[src]
    return out


def test_a_margin_fills_the_cells_beside_those_frames_filled_once_and_changes_no_image() -> None:
    """fill_margin marches exactly the unfilled cells among the 26 around every filled cell (each from its centre,
    as a wanted cell), once: a second call finds nothing to do; the frames after it are the cold render's."""
    from photon_fields.runtime.renderers.ray_marcher import light_volume_settings, scene_light_volume
    from photon_fields.runtime.transport.cell_grid import cell_centre
    from photon_fields.runtime.transport.emitters import delta_light_direction
    from photon_fields.runtime.transport.light_volume import TAU_MAX, fill_margin
    from photon_fields.runtime.transport.marching import march_transmittance_in_segments

    scene = _sparse_scene()
    first = render_ray_marched(scene, spp=1, seed=3, progress=False).layers["L_d"]
    lv = scene_light_volume(scene, *light_volume_settings(scene))
    m = scene.medium()
    kind, vec, _ = scene.packed_lights()
    before = lv.values >= 0.0
    assert lv.margin.any() and 0.001 < before.mean() < 0.3
    assert fill_margin(m, kind, vec, lv)
    after = lv.values >= 0.0
    np.testing.assert_array_equal(after, _dilated(before))
    assert not lv.margin.any() and not lv.wanted.any() and (lv.values[after] >= 0.0).all()
    new = np.argwhere(after & ~before)
    for i, j, k, light in new[np.random.default_rng(1).choice(len(new), 40, replace=False)]:
        p = cell_centre(lv.grid, i, j, k)
        lx, ly, lz, _, tend = delta_light_direction(kind[light], vec[light], *p)
        assert lv.values[i, j, k, light] == np.float32(march_transmittance_in_segments(m, lv.units, *p, lx, ly, lz,
                                                                                        tend, lv.shadow_step, TAU_MAX))
    once = lv.values.copy()
    assert fill_margin(m, kind, vec, lv)  # the cells it filled are not a margin's seeds: nothing more
    np.testing.assert_array_equal(lv.values, once)
    np.testing.assert_array_equal(render_ray_marched(scene, spp=1, seed=3, progress=False).layers["L_d"], first)
    later = render_ray_marched(scene, spp=1, seed=4, progress=False).layers["L_d"]
    np.testing.assert_array_equal(later, render_ray_marched(_sparse_scene(), spp=1, seed=4,
                                                            progress=False).layers["L_d"])


def test_a_cancelled_margin_is_completed_by_the_next_fill() -> None:
    """A margin fill stopped before its first chunk leaves its marks (and their bricks flagged); the next frame's
    fill marches them with its own cells, and its image is a cold render's."""
    from photon_fields.runtime.renderers.ray_marcher import light_volume_settings, scene_light_volume
    from photon_fields.runtime.transport.light_volume import NEIGHBOUR, fill_margin

    scene = _sparse_scene()
    render_ray_marched(scene, spp=1, seed=3, progress=False)
    lv = scene_light_volume(scene, *light_volume_settings(scene))
    kind, vec, _ = scene.packed_lights()
    assert not fill_margin(scene.medium(), kind, vec, lv, cancel=lambda: True)
    assert (lv.values == NEIGHBOUR).sum() > 0 and lv.wanted.any() and not lv.margin.any()
    image = render_ray_marched(scene, spp=1, seed=8, progress=False).layers["L_d"]
    assert not (lv.values == NEIGHBOUR).any() and not lv.wanted.any()
    np.testing.assert_array_equal(image, render_ray_marched(_sparse_scene(), spp=1, seed=8,
                                                            progress=False).layers["L_d"])


def test_light_volume_gives_the_same_image_cold_or_warm_and_with_any_threads() -> None:
    import numba

    a = render_ray_marched(_sparse_scene(), spp=2, seed=3, progress=False).layers
    scene = _sparse_scene()
    render_ray_marched(scene.with_overrides(camera=small_camera(16)), spp=1, seed=9, progress=False)  # fills some
    warm = render_ray_marched(scene, spp=2, seed=3, progress=False).layers
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        one = render_ray_marched(_sparse_scene(), spp=2, seed=3, progress=False).layers
    finally:
        numba.set_num_threads(old)
    assert a["L_d"].max() > 0.0
    for layer in ("L", "L_d", "L_e"):
        np.testing.assert_array_equal(a[layer], warm[layer])
        np.testing.assert_array_equal(a[layer], one[layer])


def test_a_light_edit_keeps_the_cells_of_the_lights_that_did_not_move() -> None:
    """A scene that adopts another's medium (the viewer's light edit) starts its light volume from the other's
    cells of each light with the same kind and position or direction (a colour or power change keeps them), not of
    a moved light; the image is the one a cold render of the edited scene gives, and the other scene's volumes are
    let go once copied."""
    from photon_fields.runtime.renderers.ray_marcher import scene_light_volume
    from photon_fields.runtime.transport.light_volume import UNFILLED

    scene = _sparse_scene()
    render_ray_marched(scene, spp=1, seed=2, progress=False)
    before = scene_light_volume(scene, 1.0, 0.5).values.copy()
    sun, lamp = scene.lights
    lights = (DirectionalLight(sun.direction, [0.2, 0.4, 1.0], 5.0), PointLight([0.1, 0.8, 0.9], lamp.color, 0.5))

    def edited() -> Scene:
        return replace(scene, lights=lights, _cache={})

    warm = edited()
    warm.adopt_medium(scene)
    lv = scene_light_volume(warm, 1.0, 0.5)
    assert not warm.shared_cache("light_volumes_before")
    filled = before[..., 0] >= 0.0
    assert filled.mean() > 0.001
    np.testing.assert_array_equal(lv.values[..., 0][filled], before[..., 0][filled])
    assert (lv.values[..., 1] == UNFILLED).all()
    a = render_ray_marched(warm, spp=2, seed=5, progress=False).layers
    b = render_ray_marched(edited(), spp=2, seed=5, progress=False).layers
    assert a["L_d"].max() > 0.0
    for layer in ("L", "L_d"):
        np.testing.assert_array_equal(a[layer], b[layer])


def test_light_volume_is_kept_across_camera_moves_not_across_scenes() -> None:
    from photon_fields.runtime.renderers.ray_marcher import scene_light_volume

    scene = _sparse_scene()
    moved = scene.with_overrides(camera=small_camera(16), g=-0.2)
    assert scene_light_volume(moved, 1.0, 0.5) is scene_light_volume(scene, 1.0, 0.5)
    assert scene_light_volume(scene, 2.0, 0.5) is not scene_light_volume(scene, 1.0, 0.5)
    assert scene_light_volume(_sparse_scene(), 1.0, 0.5) is not scene_light_volume(scene, 1.0, 0.5)


def test_a_light_volume_too_large_is_refused_in_one_line() -> None:
    from photon_fields.runtime.errors import InputError
    from photon_fields.runtime.transport.light_volume import new_light_volume

    m = _sparse_scene().medium()._replace(density=np.broadcast_to(np.float32(0.0), (512, 512, 512)))
    with pytest.raises(InputError, match="--light-grid-scale.*MiB"):
        new_light_volume(m, 2, 2.0, 0.01)


def test_the_default_light_volume_stays_within_its_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    """One cell per voxel for the embedded scenes; for a 512^3 scan with two lights (1 GiB at one cell per voxel, over
    the limit) fewer cells, within AUTO_CELLS a light, so that the preview renders it by default; and a render takes
    the default scale (a budget smaller than the sparse scene's grid gives it a coarser light volume)."""
    import math

    from photon_fields.runtime.errors import InputError
    from photon_fields.runtime.renderers.ray_marcher import light_volume_settings, scene_light_volume
    from photon_fields.runtime.transport import light_volume
    from photon_fields.runtime.transport.light_volume import (
        AUTO_CELLS,
        DEFAULT_SHADOW_STEP,
        auto_cells_per_voxel,
        light_volume_shape,
        new_light_volume,
    )

    assert auto_cells_per_voxel((96, 96, 96)) == 1.0 and auto_cells_per_voxel((256, 256, 256)) == 1.0
    big = (512, 512, 512)
    scale = auto_cells_per_voxel(big)
    assert 0.5 < scale < 1.0 and math.prod(light_volume_shape(big, scale)) <= AUTO_CELLS
    m = _sparse_scene().medium()._replace(density=np.broadcast_to(np.float32(0.0), big))
    with pytest.raises(InputError, match="--light-grid-scale.*MiB"):
        new_light_volume(m, 2, 1.0, 0.01)
    assert new_light_volume(m, 2, scale, 0.01).values.shape == (*light_volume_shape(big, scale), 2)

    scene = _sparse_scene()
    fine = render_ray_marched(scene, spp=2, seed=1, progress=False).layers["L_d"]
    monkeypatch.setattr(light_volume, "AUTO_CELLS", 20**3)
    coarse_scale = auto_cells_per_voxel(scene.volume.dims)
    assert coarse_scale < 0.5
    coarse = render_ray_marched(scene, spp=2, seed=1, progress=False).layers["L_d"]
    # its shadow rays step half a cell, not half a voxel; explicit settings are kept
    assert light_volume_settings(scene) == (coarse_scale, DEFAULT_SHADOW_STEP / coarse_scale)
    assert light_volume_settings(scene, 2.0, 0.3) == (2.0, 0.3) and light_volume_settings(scene, 2.0)[1] == 0.5
    lv = scene_light_volume(scene, *light_volume_settings(scene))
    assert math.prod(lv.values.shape[:3]) <= 20**3 and (lv.values >= 0).any()  # the one the render filled
    assert coarse.mean() == pytest.approx(fine.mean(), rel=0.1)


def test_an_unknown_shadow_mode_is_refused() -> None:
    from photon_fields.runtime.errors import InputError

    with pytest.raises(InputError, match="--shadows"):
        render_ray_marched(_sparse_scene(), shadows="soft", progress=False)


def test_taking_rays_a_tile_at_a_time_changes_no_pixel(monkeypatch: pytest.MonkeyPatch) -> None:
    """The marcher takes its rays in 16 x 16 tiles (rays.tile_order); in row order (the order before) the image is
    the same bit for bit, with batches that end inside a sample and samples that end inside a batch."""
    from photon_fields.runtime.renderers import ray_marcher

    vortex = builtin_scene("vortex")
    s = replace(vortex, lights=(*vortex.lights, EnvironmentLight([0.2, 0.3, 0.5])), _cache={}).with_overrides(
        width=40, height=36)  # and a sky, seen through the medium: L_e per work item too
    tiled = render_ray_marched(s, spp=3, seed=2, progress=False, batch_size=500).layers
    monkeypatch.setattr(ray_marcher, "tile_order", lambda w, h: np.arange(w * h, dtype=np.int64))
    rows = render_ray_marched(s, spp=3, seed=2, progress=False, batch_size=500).layers
    assert tiled["L_d"].max() > 0.0 and np.ptp(tiled["L_e"]) > 0.0
    for layer in ("L", "L_d", "L_e"):
        np.testing.assert_array_equal(tiled[layer], rows[layer], err_msg=layer)


@pytest.mark.parametrize("shadows", ["volume", "march"])
def test_the_light_of_buffered_samples_is_the_same_whatever_the_buffer(monkeypatch: pytest.MonkeyPatch,
                                                                       shadows: str) -> None:
    """The march buffers its samples and looks up their light a buffer at a time (preview_light.py): buffers of one
    sample, of a few (full many times within a ray, and rays that end with samples still buffered) and the default
    give the same image bit for bit, with a cold light volume (rays that miss cells, marked and marched again) and
    with shadow rays."""
    from photon_fields.runtime.renderers import preview_light

    images = []
    for size in (preview_light.SAMPLE_BUFFER, 1, 5):
        monkeypatch.setattr(preview_light, "SAMPLE_BUFFER", size)
        images.append(render_ray_marched(_sparse_scene(), spp=2, seed=6, shadows=shadows, progress=False).layers)
    assert images[0]["L_d"].max() > 0.0
    for other in images[1:]:
        for layer in ("L", "L_d", "L_e"):
            np.testing.assert_array_equal(images[0][layer], other[layer], err_msg=layer)
