"""The ray marcher's adaptive steps (runtime/transport/step_grid.py): each macrocell's base steps per segment from
its two error bounds (sigma_t's curvature, the optical depth), checked on media whose bounds are known in closed
form; and the marcher with adaptive steps against a fine fixed-step march, and with and without skipping empty
space (tests/runtime/renderers/test_ray_marcher.py checks the rest of the marcher)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import small_camera

from photon_fields.runtime.renderers.ray_marcher import render_ray_marched, scene_step_units
from photon_fields.runtime.scene.lights import DirectionalLight
from photon_fields.runtime.scene.scene import Scene, builtin_scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import build_medium
from photon_fields.runtime.transport.step_grid import STEP_DEPTH, STEP_TOLERANCE, step_units

N = 48
GREY = np.array([[0.8, 0.8, 0.8]] * 2)


def _linear_tf(scale: float) -> TransferFunction:
    """sigma_t = scale * s: linear in the normalized scalar, so a voxel's sigma_t is its scalar times ``scale``."""
    return TransferFunction(np.array([0.0, 1.0]), GREY, np.array([0.0, 1.0]), scale, "linear")


def _medium(field: np.ndarray, tf: TransferFunction):  # noqa: ANN202
    volume = make_volume(field, window=(0.0, 1.0), name="probe")
    return build_medium(volume, tf), volume.voxel_size


def _voxel_sigma(m, s: np.ndarray) -> np.ndarray:  # noqa: ANN001
    """sigma_t of scalars ``s`` through the medium's own table (what the renderer reads)."""
    return np.interp(s, np.linspace(0.0, 1.0, len(m.ext_lut)), m.ext_lut)


def _interior(units: np.ndarray) -> np.ndarray:
    """Macrocells two away from the box (clear of the clamped voxels at its faces and of the neighbours' minimum)."""
    return units[2:-2, 2:-2, 2:-2]


@pytest.mark.parametrize("tau_per_voxel", [0.1, 0.3, 0.9])
def test_a_homogeneous_medium_is_bound_by_its_optical_depth(tau_per_voxel: float) -> None:
    """No curvature: a segment holds STEP_DEPTH optical depths of the majorant, in whole base steps, 1 to max."""
    field = np.full((N, N, N), 0.5)
    m, voxel = _medium(field, _linear_tf(1.0))
    scale = tau_per_voxel / (_voxel_sigma(m, np.array([0.5]))[0] * voxel)  # the TF's scale giving that depth
    m, voxel = _medium(field, _linear_tf(scale))
    mu = float(m.majorant.max()) * voxel
    for step, max_step in ((1.0, 4.0), (0.5, 4.0), (0.5, 1.0)):
        units = step_units(m, voxel, step, max_step)
        expected = max(1, min(int(max_step / step), int(math.floor(STEP_DEPTH / mu / step))))
        assert np.all(units == expected), (tau_per_voxel, step, max_step, np.unique(units))


def test_curvature_bounds_a_thin_medium() -> None:
    """sigma_t oscillating along x, tau = t0 (1.25 + cos(i)) per voxel: its largest second difference between
    voxels is c = 2 t0 (1 - cos 1) (at least cos(1/2) of that within any macrocell's neighbourhood), and the
    midpoint rule's bound L^3 c / 24 <= STEP_TOLERANCE gives L = (24 STEP_TOLERANCE / c)^(1/3) base steps of one
    voxel, rounded down; t0 is small enough that the depth bound allows 4."""
    i = np.arange(N)
    for length, expected, halves in ((2.3, 2, 4), (3.3, 3, 6)):  # L and L / cos(1/2)^(1/3) round down alike
        c = 24.0 * STEP_TOLERANCE / length**3
        t0 = c / (2.0 * (1.0 - math.cos(1.0)))
        s = 0.5 + 0.4 * np.cos(i)  # sigma = scale * s: t0 = 0.4 scale voxel
        field = np.broadcast_to(s[:, None, None], (N, N, N)).copy()
        voxel = make_volume(field, window=(0.0, 1.0)).voxel_size
        m, voxel = _medium(field, _linear_tf(t0 / (0.4 * voxel)))
        assert float(m.majorant.max()) * voxel * 4 < STEP_DEPTH
        units = step_units(m, voxel, 1.0, 4.0)
        assert np.all(_interior(units) == expected), (length, np.unique(_interior(units)))
        assert np.all(_interior(step_units(m, voxel, 0.5, 4.0)) == halves)  # in half-voxel steps


def test_empty_macrocells_fixed_steps_and_a_peak_between_voxel_values() -> None:
    """Empty macrocells hold 1 (the skipping and the stepping march meet the medium at the same segment); max_step
    at or below step gives fixed steps; a transfer function that peaks between two voxels' values keeps them 1."""
    x = (np.arange(N) + 0.5) / N
    ramp = np.broadcast_to((0.40 + 0.2 * x)[:, None, None], (N, N, N)).copy()  # voxels pass s = 0.5 between two
    ramp[:, :, : N // 4] = 0.0  # and an empty quarter
    thin = TransferFunction(np.array([0.0, 0.3, 1.0]), np.array([[0.8, 0.8, 0.8]] * 3), np.array([0.0, 0.01, 0.01]),
                            1.0, "thin")
    m, voxel = _medium(ramp, thin)
    smooth = step_units(m, voxel, 1.0, 4.0)
    assert np.all(m.majorant[:, :, : N // 8 - 1] == 0.0) and np.all(smooth[:, :, : N // 8 - 1] == 1)  # empty
    assert np.all(_interior(smooth)[:, :, N // 8:] == 4)  # thin and constant: the longest segments
    assert np.all(step_units(m, voxel, 1.0, 1.0) == 1) and np.all(step_units(m, voxel, 2.0, 3.0) == 1)
    pts = np.array([0.0, 0.3, 0.4985, 0.5, 0.5015, 1.0])  # a spike between the voxel values 0.4979 and 0.5021
    spike = TransferFunction(pts, np.array([[0.8, 0.8, 0.8]] * 6), np.array([0.0, 0.01, 0.01, 1.0, 0.01, 0.01]),
                             100.0, "spike")
    m, voxel = _medium(ramp, spike)
    assert float(m.majorant.max()) * voxel > 1.0  # the spike's optical depth per voxel, far above the voxels'
    units = step_units(m, voxel, 1.0, 4.0)
    crossing = int(np.argmin(np.abs(0.40 + 0.2 * x - 0.5))) // 2  # the macrocell whose voxels straddle s = 0.5
    assert np.all(units[crossing, 2:-2, N // 8 + 1:-2] == 1)
    assert np.all(units[2, 2:-2, N // 8 + 3:-3] == 4)  # far from it (and from the empty quarter)


@pytest.mark.parametrize("max_step", [4.0, 8.0])
def test_a_sharp_step_limits_every_macrocell_a_segment_could_reach_it_from(max_step: float) -> None:
    """A thin medium whose extinction jumps between voxels N/2 - 1 and N/2 (second differences at both): the two
    macrocells whose stencils hold them allow fewer steps, and so does every macrocell from which a segment of
    max_step voxels could reach them (max_step / 2 macrocells of 2 voxels on either side); the ones beyond allow the
    longest segments."""
    field = np.full((N, N, N), 0.1)
    field[N // 2:] = 0.9
    voxel = make_volume(field, window=(0.0, 1.0)).voxel_size
    m, voxel = _medium(field, _linear_tf(0.12 / (0.9 * voxel)))  # 0.12 optical depths per voxel on the dense side
    assert float(m.majorant.max()) * voxel * max_step < STEP_DEPTH  # thin: only the jump limits the segments
    units = step_units(m, voxel, 1.0, max_step)[:, N // 4, N // 4]
    limited = np.flatnonzero(units < int(max_step))
    reach = int(max_step) // 2
    assert limited.min() == N // 4 - 1 - reach and limited.max() == N // 4 + reach, (limited, units)
    assert units.min() == 2  # (24 STEP_TOLERANCE / 0.8 x 0.12 / 0.9)^(1/3) = 2.2 voxels


def _segments_along(m, own: np.ndarray, cube: np.ndarray, rays: int, seed: int) -> list[tuple[int, int, set[int]]]:  # noqa: ANN001
    """For random segment starts in occupied macrocells and random directions: (units_along's base steps of a
    voxel, the neighbourhood grid's at the start, the own units of the macrocells the segment passes, sampled every
    1/100 voxel)."""
    from photon_fields.runtime.transport.step_grid import units_along

    rng = np.random.default_rng(seed)
    voxel = float(m.bsize[0] / m.density.shape[0])
    shape = np.asarray(own.shape)
    out = []
    while len(out) < rays:
        p = m.bmin + rng.random(3) * m.bsize
        cell = tuple(np.minimum((p - m.bmin) / m.bsize * shape, shape - 1).astype(int))
        if own[cell] == 0:
            continue
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        inv = 1.0 / d
        n = units_along(m, own, *p, *d, *inv, 0.0, np.inf, voxel, int(own[cell]), int(cube[cell]))
        pts = p + np.arange(0.0, n * voxel, voxel / 100)[:, None] * d
        pts = pts[np.all((pts >= m.bmin) & (pts < m.bmin + m.bsize), axis=1)]
        idx = np.minimum(((pts - m.bmin) / m.bsize * shape).astype(int), shape - 1)
        out.append((n, int(cube[cell]), {int(v) for v in own[idx[:, 0], idx[:, 1], idx[:, 2]]}))
    return out


@pytest.mark.parametrize("case", ["step", "blobs"])
def test_a_camera_segment_spans_what_every_macrocell_it_passes_allows(case: str) -> None:
    """units_along walks the macrocells a segment passes: it never spans more base steps than an occupied one it
    enters allows (empty ones, 0, bound nothing), never fewer than the neighbourhood grid guarantees in any
    direction, and where a segment leads away from a wall it spans more than that grid does (the point of it)."""
    from photon_fields.runtime.transport.step_grid import own_units, step_lengths, units_from_lengths

    if case == "step":  # a thin medium whose extinction jumps between voxels N/2 - 1 and N/2
        field = np.full((N, N, N), 0.1)
        field[N // 2:] = 0.9
        voxel = make_volume(field, window=(0.0, 1.0)).voxel_size
        m, voxel = _medium(field, _linear_tf(0.12 / (0.9 * voxel)))
    else:
        scene = builtin_scene("blobs", 160)
        m, voxel = scene.medium(), scene.volume.voxel_size
    lengths = step_lengths(m, voxel)
    own, cube = own_units(m, lengths, 1.0, 4.0), units_from_lengths(m, lengths, 1.0, 4.0)
    assert np.array_equal(own == 0, m.majorant <= 0.0)
    results = _segments_along(m, own, cube, 300, 5)
    for n, least, passed in results:
        assert n >= least and all(v == 0 or v >= n for v in passed), (n, least, passed)
    assert sum(n > least for n, least, _ in results) > 0.1 * len(results)


def _smooth_scene(n: int) -> Scene:
    """A soft Gaussian cloud at resolution n, lit from the side: smooth and thin enough for long segments."""
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    field = np.exp(-((X - 0.5) ** 2 + (Y - 0.5) ** 2 + (Z - 0.5) ** 2) / 0.05)
    tf = TransferFunction(np.array([0.0, 1.0]), GREY, np.array([0.0, 1.0]), 12.0, "cloud")
    return Scene(make_volume(field, window=(0.0, 1.0), name="cloud"), tf,
                 (DirectionalLight([-0.6, -0.7, -0.4], [1.0, 0.95, 0.85], 3.0),), small_camera(32), 0.3, "cloud")


def test_adaptive_steps_keep_the_image_of_a_fine_march() -> None:
    """On a smooth cloud most segments span several steps, and the image stays within 1 % of a fixed-step march at
    an eighth of a voxel, block by block, as the fixed 1-voxel march does (same jitter streams)."""
    scene = _smooth_scene(64)
    units = scene_step_units(scene, 1.0, 4.0)
    assert np.mean(units[scene.medium().majorant > 0] > 1) > 0.5
    fine = render_ray_marched(scene, spp=8, step=0.125, max_step=0.125, progress=False).layers["L_d"]
    fixed = render_ray_marched(scene, spp=8, max_step=1.0, progress=False).layers["L_d"]
    adaptive = render_ray_marched(scene, spp=8, progress=False).layers["L_d"]

    def blocks(img: np.ndarray) -> np.ndarray:
        return img.reshape(8, 4, 8, 4, 3).mean(axis=(1, 3))

    lit = blocks(fine) > 0.05 * blocks(fine).max()
    for name, img in (("fixed", fixed), ("adaptive", adaptive)):
        assert abs(img.mean() / fine.mean() - 1) < 0.01, name
        assert np.all(np.abs(blocks(img) / blocks(fine) - 1)[lit] < 0.03), name


def test_skipping_empty_space_changes_no_pixel_with_long_segments() -> None:
    """The adaptive march jumps over empty space and meets the medium at the segment the stepping march meets it
    at, so the two images agree bit for bit (blobs at 160^3, where most occupied macrocells allow long segments)."""
    scene = builtin_scene("blobs", 160).with_overrides(width=32, height=32)
    assert np.mean(scene_step_units(scene, 1.0, 4.0)[scene.medium().majorant > 0] > 1) > 0.5
    skipped = render_ray_marched(scene, spp=2, seed=4, progress=False).layers
    every = render_ray_marched(scene, spp=2, seed=4, progress=False, skip_empty=False).layers
    assert skipped["L_d"].max() > 0.0
    for layer in ("L", "L_d", "L_e"):
        np.testing.assert_array_equal(skipped[layer], every[layer], err_msg=layer)


def _shadow_rays(scene: Scene, count: int, seed: int) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(point, direction to the light, distance) of ``count`` shadow rays from random points with medium towards
    the scene's directional light (to the box)."""
    from photon_fields.runtime.transport.emitters import delta_light_direction

    m = scene.medium()
    kind, vec, _ = scene.packed_lights()
    rng = np.random.default_rng(seed)
    rays = []
    while len(rays) < count:
        p = m.bmin + rng.random(3) * m.bsize
        i, j, k = (np.floor((p - m.bmin) / m.bsize * m.majorant.shape)).astype(int)
        if m.majorant[i, j, k] > 0.0:
            lx, ly, lz, _, tend = delta_light_direction(kind[0], vec[0], *p)
            rays.append((p, np.array([lx, ly, lz]), tend))
    return rays


def _two_boxes() -> tuple[Scene, list[tuple[np.ndarray, np.ndarray, float]]]:
    """Two boxes of a smooth medium with hard faces in an empty 64^3 volume, and shadow rays from the first that
    cross the empty gap into the second: a sample skipped past the gap's end would miss sigma_t > 0."""
    n = 64
    x = (np.arange(n) + 0.5) / n
    X, Y, Z = np.meshgrid(x, x, x, indexing="ij")
    field = 0.5 + 0.3 * np.sin(7 * X) * np.cos(5 * Y)
    box_a = (abs(X - 0.3) < 0.12) & (abs(Y - 0.5) < 0.2) & (abs(Z - 0.5) < 0.2)
    box_b = (abs(X - 0.75) < 0.1) & (abs(Y - 0.5) < 0.2) & (abs(Z - 0.5) < 0.2)
    field = np.where(box_a | box_b, field, 0.0)
    scene = Scene(make_volume(field, window=(0.0, 1.0), name="boxes"), _linear_tf(4.0),
                  (DirectionalLight([-1.0, 0.1, 0.05], [1.0, 1.0, 1.0], 1.0),), small_camera(16), 0.0, "boxes")
    m = scene.medium()
    rng = np.random.default_rng(3)
    d = np.array([1.0, -0.1, -0.05]) / np.linalg.norm([1.0, -0.1, -0.05])
    starts = m.bmin + m.bsize * (np.array([0.3, 0.5, 0.5]) + rng.uniform(-0.1, 0.1, (40, 3)) * [1.0, 1.2, 1.2])
    return scene, [(p, d, math.inf) for p in starts]


@pytest.mark.parametrize("case", ["boxes", "blobs"])
def test_segmented_shadow_rays_sum_what_stepping_through_every_segment_sums(case: str) -> None:
    """The light volume's shadow rays (``march_transmittance_in_segments``) skip empty runs; summing sigma_t at every
    segment's midpoint instead, empty ones included, on the same lattice of base steps and the same segments
    (computed here in Python), gives the same transmittance (two boxes with an empty gap between them; blobs at
    160^3: long segments and empty runs)."""
    from photon_fields.runtime.transport.marching import march_transmittance_in_segments
    from photon_fields.runtime.transport.medium import extinction_at, intersect_box
    from photon_fields.runtime.transport.tracking import macrocell_of

    scene, rays = _two_boxes() if case == "boxes" else (builtin_scene("blobs", 160), None)
    rays = rays or _shadow_rays(scene, 40, 1)
    m, h = scene.medium(), 0.5 * scene.volume.voxel_size
    units = scene_step_units(scene, 0.5, 2.0)
    assert np.mean(units[m.majorant > 0] > 1) > 0.3
    spans = []
    for p, d, tend in rays:
        t0, t1 = intersect_box(m, *p, *d)
        t1 = min(t1, tend)
        tau, t = 0.0, t0
        while t < t1:
            mid = 0.5 * (t + min(t + h, t1))
            n = int(units[macrocell_of(m, *(p + mid * d))])
            tb = min(t + n * h, t1)
            tau += extinction_at(m, *(p + 0.5 * (t + tb) * d)) * (tb - t)
            spans.append(n)
            t += n * h
        got = march_transmittance_in_segments(m, units, *p, *d, tend, h, 1e9)
        assert got == pytest.approx(math.exp(-tau), rel=1e-12, abs=1e-300)
    assert max(spans) > 1


def test_segmented_shadow_rays_agree_with_a_fine_march() -> None:
    """On a smooth cloud the segmented shadow rays (up to 4 half-voxel steps, as the light volume's) take far fewer
    samples and their optical depth stays within 2 % of a march at a sixteenth of a voxel (measured: 1.6 % at worst
    over these rays, half-voxel steps 0.24 %; the step grid bounds each segment's error by 0.05 absolute)."""
    from photon_fields.runtime.transport.marching import march_transmittance, march_transmittance_in_segments

    scene = _smooth_scene(64)
    m, h = scene.medium(), 0.5 * scene.volume.voxel_size
    units = scene_step_units(scene, 0.5, 2.0)
    assert np.mean(units[m.majorant > 0] == 4) > 0.5
    for p, d, tend in _shadow_rays(scene, 30, 2):
        fine = march_transmittance(m, *p, *d, tend, h / 8, True, 1e9)
        got = march_transmittance_in_segments(m, units, *p, *d, tend, h, 1e9)
        assert -math.log(got) == pytest.approx(-math.log(fine), rel=0.02, abs=1e-3)


def test_the_camera_and_light_volume_grids_come_from_one_pass_over_sigma() -> None:
    """A preview frame keeps one pass of allowed lengths (``step_lengths``) and derives the camera's grid (1-voxel
    base) and its light volume's (half-voxel base) from it, each equal to its own ``step_units``."""
    scene = builtin_scene("blobs").with_overrides(width=16, height=16)
    render_ray_marched(scene, spp=1, progress=False)
    grids = scene.shared_cache("step_units")
    m, voxel = scene.medium(), scene.volume.voxel_size
    assert "lengths" in grids and {(1.0, 4.0), (0.5, 2.0), ("own", 1.0, 4.0)} <= set(grids)
    for step, max_step in ((1.0, 4.0), (0.5, 2.0)):
        np.testing.assert_array_equal(grids[(step, max_step)], step_units(m, voxel, step, max_step))
    assert grids[(0.5, 2.0)].max() > 1


@pytest.mark.parametrize(("res", "adaptive"), [(96, False), (160, True)])
def test_the_camera_walks_its_own_units_where_they_pay(res: int, adaptive: bool) -> None:
    """The camera's grid is each macrocell's own units (0 where empty) from the same pass; where the occupied
    macrocells allow fewer than MIN_MEAN_UNITS base steps on average (blobs at 96^3) it is all ones instead (fixed
    steps: the walks would cost more than they save)."""
    from photon_fields.runtime.renderers.ray_marcher import MIN_MEAN_UNITS, scene_own_units
    from photon_fields.runtime.transport.step_grid import own_units, step_lengths

    scene = builtin_scene("blobs", res)
    m = scene.medium()
    own = own_units(m, step_lengths(m, scene.volume.voxel_size), 1.0, 4.0)
    assert (own[m.majorant > 0].mean() >= MIN_MEAN_UNITS) == adaptive
    np.testing.assert_array_equal(scene_own_units(scene, 1.0, 4.0), own if adaptive else np.ones_like(own))
