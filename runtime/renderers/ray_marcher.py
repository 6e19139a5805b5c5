"""Ray marcher with global shadows: the paper's ray-marching baseline (Sec. 4.3), single scattering only, and the
product's preview (noise-free, no training; bench/README.md compares its speed with the other renderers').

Parameters
----------
step : float (default 1.0)
    Step length along camera rays in voxels (of the smallest voxel edge): the base step.
max_step : float or None (default None: ``DEFAULT_SPAN`` = 4 base steps)
    The longest camera-ray segment in voxels, a whole number of base steps: each macrocell allows as many base
    steps per segment as sigma_t's curvature and the optical depth there keep the quadrature's error small
    (:mod:`photon_fields.runtime.transport.step_grid`), so smooth or thin media and finely sampled volumes take
    fewer samples per ray; a camera segment takes the least that the macrocells it passes allow
    (:func:`photon_fields.runtime.transport.step_grid.units_along`). ``max_step <= step``, or a medium whose
    macrocells allow fewer than ``MIN_MEAN_UNITS`` base steps on average: fixed steps.
shadows : str (default "volume")
    "volume": the preview. Each delta light's transmittance is cached in a light volume
    (:mod:`photon_fields.runtime.transport.light_volume`: marched from a cell's centre the first time a sample reads
    it, interpolated trilinearly), kept on the scene object for its later frames (camera moves, progressive passes).
    "march": the paper's baseline, a shadow ray marched from every camera sample to every light.
shadow_step : float (default 1.0 for "march"; "volume": the light volume's 0.5, or half a cell where cells are larger)
    Step length along shadow rays in voxels (for "volume": the base step of the cells' rays, which span up to
    ``light_volume.SHADOW_SPAN`` of them per segment where the step grid allows). At sharp boundaries (sigma_t h ~ 1
    per voxel) exp(-tau) over the midpoint sum's errors is biased high, and a finer step shrinks that bias quickly.
light_grid_scale : float or None (default None: 1, fewer over ~320^3 voxels)
    "volume": light-volume cells per voxel along each axis (finer: sharper lit walls, more memory and marching);
    None: :func:`photon_fields.runtime.transport.light_volume.auto_cells_per_voxel`, at most 128 MiB a light.
min_transmittance : float (default ``registry.DEFAULT_MIN_TRANSMITTANCE``, 0.03)
    Early ray termination: a camera ray stops once its transmittance is below this. What lies behind can add at most
    this fraction of the brightest radiance it would have scattered (and of the environment seen through it).
level : int (default 0)
    March the volume's coarser level (:mod:`photon_fields.runtime.scene.levels`: blocks of 2^level voxels a side
    averaged, the same box): what the viewer shows while the view or the scene is being changed on a large volume.
spp, seed : int
    Jittered passes per pixel (a random start offset along each ray: no wood-grain banding); streams keyed like the
    path tracer's: same seed, same image.

For each camera ray the marcher integrates, segment by segment,

    L_d = sum_k T_k * albedo_k * (1 - exp(-sigma_k h)) * sum_lights f_g(d . l) * Le * T_shadow(x'_k -> light)

where ``T_k`` is the transmittance from the camera to the segment, sigma_k and albedo_k are taken at its midpoint
and ``T_shadow`` is the transmittance towards each delta light ("global shadows"), marched or from the light
volume. The light is evaluated at ``x'_k``, the segment's scattering centroid, not at its midpoint: with sigma_k
over the segment, scattering within it happens at mean depth ``1 / sigma - h e / (1 - e)`` (e = exp(-sigma h)),
where the light still is at the lit wall of a dense medium (the midpoint read it dark: bench/README.md). The
environment light is not marched; it only appears unscattered, as ``L_e = T * L_env``. This is the same
single-scattering integral the path tracer estimates with ``max_depth = 1``; the two agree up to the marcher's
quadrature error (and the light volume's interpolation), which the tests check. Alone it has no L_i: multiple
scattering is exactly what ray marching leaves out.

Multiple scattering from a field (``estimator``, ``pfn-render --method raymarch-field``): one segment J per ray is
drawn with probability w_J / W (w_k = T_k (1 - e_k), W = 1 - T_end), and L_i = W a_J Q(x'_J, d, g), Q a photon
field's in-scattered indirect radiance at the segment's scattering centroid: one field query per ray, unbiased for
the sum over the segments; an environment light gets its single scattering the same way (W a_J NEE_env(x'_J)). The
quick look with multiple scattering, with the preview's bias in L_d, not the image to converge (docs/rendering.md).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from photon_fields.runtime.borrowed import borrowed
from photon_fields.runtime.denoise.reprojection import DU, DV, EYE, ORIGIN, pack_view
from photon_fields.runtime.errors import check_choice
from photon_fields.runtime.progress import progress_bar
from photon_fields.runtime.renderers import preview_light
from photon_fields.runtime.renderers.preview_light import light_samples
from photon_fields.runtime.renderers.registry import DEFAULT_MIN_TRANSMITTANCE
from photon_fields.runtime.scene.levels import scene_at_level
from photon_fields.runtime.scene.lights import DIRECTIONAL
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.cell_grid import Grid
from photon_fields.runtime.transport.direct_light import direct_light_batch
from photon_fields.runtime.transport.emitters import environment_index
from photon_fields.runtime.transport.light_volume import (
    DEFAULT_SHADOW_STEP,
    SHADOW_SPAN,
    LightVolume,
    adopt_light_columns,
    auto_cells_per_voxel,
    fill_wanted,
    new_light_volume,
    prefetch_light_stencil,
)
from photon_fields.runtime.transport.marching import segment_past
from photon_fields.runtime.transport.medium import (
    Medium,
    borrowed_medium,
    extinction_albedo_at,
    prefetch_scalar_stencil,
    worth_prefetching,
)
from photon_fields.runtime.transport.phase import hg_eval
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.step_grid import own_units, step_lengths, units_along, units_from_lengths
from photon_fields.runtime.transport.tracking import empty_run_in, macrocell_of, task_items, task_stride
from photon_fields.runtime.wavefront import batches
from photon_fields.runtime.wavefront.batches import RenderResult, StageTimer, finish, scene_environment, work_batches
from photon_fields.runtime.wavefront.camera_choice import resolve_camera_estimator
from photon_fields.runtime.wavefront.depth_bounds import depth_bounds_for, unbounded
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.first_interaction import IndirectEstimator
from photon_fields.runtime.wavefront.rays import camera_ray, clip_to_box, tile_order, tiled_work

SHADOWS = ("volume", "march")
#: The longest camera-march segment by default, in base steps (runtime/transport/step_grid.py; bench/README.md,
#: ray marcher).
DEFAULT_SPAN = 4
#: Adaptive segments cost a walk over the macrocells a segment passes and two lookups a sample: below this many base
#: steps per occupied macrocell on average (the embedded scenes at 96^3) they saved fewer samples than they cost,
#: and the camera marches fixed steps (bench/README.md, ray marcher).
MIN_MEAN_UNITS = 1.5
#: Camera rays per batch (each batch marks, fills and re-marches its own light-volume cells).
MARCH_BATCH = 1 << 17
_NO_VOLUME = np.ones((2, 2, 2, 1), dtype=np.float32)  # what "march" passes for the light volume it does not read
_NO_WANTED = np.zeros((1, 1, 1), dtype=np.uint8)
_NO_GRID: Grid = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 2, 2, 2)
#: Rows of the picks :func:`march_work` returns: position 0-2, direction 3-5, weight W (PICK_W), albedo (PICK_A..+2).
PICK_W, PICK_A, PICK_ROWS = 6, 7, 10


@njit(cache=True, inline="always")
def scattering_centroid(sigma: float, seg: float, e: float) -> float:
    """Mean depth of a scattering event within a segment of length ``seg`` and extinction ``sigma`` (``e`` =
    exp(-sigma seg)), given that it happens there: 1 / sigma - seg e / (1 - e) (module docstring); where x =
    sigma seg is small, the series seg (1/2 - x/12 + x^3/720 ...) instead, before the subtraction cancels."""
    x = sigma * seg
    if x < 1e-3:
        return seg * (0.5 - x / 12.0)
    return 1.0 / sigma - seg * e / (1.0 - e)


@njit(cache=True)
def _march_items(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, view: np.ndarray,
                 width: int, n_pixels: int, work: np.ndarray, seed: int, near: np.ndarray, far: np.ndarray, tile: int,
                 h: float, h_shadow: float, skip: bool, units: np.ndarray, own: np.ndarray, adaptive: bool,
                 use_volume: bool, lv: np.ndarray, wanted: np.ndarray, grid: Grid, t_min: float, ld: np.ndarray,
                 trans: np.ndarray, missed: np.ndarray, pick: np.ndarray, pick_rng: np.ndarray, picking: bool,
                 prefetch: bool, buffer: int, lo: int, hi: int) -> None:
    """Work items ``work[lo:hi]`` of :func:`_march`, serially (``TASK_ITEMS`` in the tracking module says why):
    each one's jittered camera ray (:func:`camera_ray`), clipped to the box (:func:`clip_to_box`) and marched
    within its tile's depth bounds (``near`` / ``far``: eye distances), in segments of base steps ``h``: the
    neighbourhood's ``units`` per macrocell, or more where the macrocell's ``own`` units are more and every macrocell
    the segment passes allows them (``adaptive`` False: fixed steps). Each sample's light is looked up after the
    march, a buffer of samples at a time (:func:`photon_fields.runtime.renderers.preview_light.light_samples`). A
    ray that reads an unfilled light-volume cell is ``missed``: from there on it marks the cells its samples read
    instead of summing them, to its end (its walk does not depend on the light), so one walk finds every cell it
    needs.

    ``picking``: each ray also keeps one of its segments' scattering centroids, drawn with probability
    proportional to the segment's weight T_k (1 - e_k) (a weighted reservoir of size one, from the ray's own random
    stream after its jitter: a re-marched ray keeps the same one), and writes ``pick`` (:data:`PICK_ROWS` x n):
    its position, the ray's direction, W = sum_k T_k (1 - e_k) and the albedo there (W = 0: none), and the ray's
    random state after its march to ``pick_rng`` (for the environment's NEE there)."""
    m = borrowed_medium(m)  # no reference counting in the loops below (runtime/borrowed.py)
    kind, vec, rgb, units, own = borrowed(kind), borrowed(vec), borrowed(rgb), borrowed(units), borrowed(own)
    lv, wanted = borrowed(lv), borrowed(wanted)
    origin, du, dv = view[ORIGIN:ORIGIN + 3], view[DU:DU + 3], view[DV:DV + 3]
    ex, ey, ez = view[EYE], view[EYE + 1], view[EYE + 2]
    phases = np.empty((hi - lo, kind.shape[0]))
    dirs = np.empty((3, hi - lo))
    samples = np.empty((7, buffer))
    ray_of = np.empty(buffer, np.int64)
    count = 0
    s0 = np.uint64(seed)
    for i in range(lo, hi):
        dx, dy, dz, p, state = camera_ray(origin, du, dv, width, n_pixels, work[i], s0)
        dirs[0, i - lo], dirs[1, i - lo], dirs[2, i - lo] = dx, dy, dz
        ray_phase = phases[i - lo]
        state, jitter = next_float(state)
        ld[0, i] = ld[1, i] = ld[2, i] = 0.0
        trans[i] = 1.0
        if picking:
            pick[PICK_W, i] = 0.0
        w_sum = 0.0
        ty = (p // width) // tile
        tx = (p % width) // tile
        if not near[ty, tx] < math.inf:
            continue  # the ray meets no occupied macrocell (or misses the box)
        hit, ox, oy, oz, tmax = clip_to_box(m, ex, ey, ez, dx, dy, dz)
        if not hit:
            continue
        # Distances along the clipped ray: its segments before t_near and from t_far on have no medium.
        entry = (ox - ex) * dx + (oy - ey) * dy + (oz - ez) * dz
        t_near = near[ty, tx] - entry
        t_far = far[ty, tx] - entry
        vx = 1.0 / dx if dx != 0.0 else 0.0  # the ray's inverse direction, for units_along's walks
        vy = 1.0 / dy if dy != 0.0 else 0.0
        vz = 1.0 / dz if dz != 0.0 else 0.0
        for k in range(kind.shape[0]):  # a directional light's phase value is the same all along the ray
            if kind[k] == DIRECTIONAL:
                ray_phase[k] = hg_eval(g, -(dx * vec[k, 0] + dy * vec[k, 1] + dz * vec[k, 2]))
        T = 1.0
        # Base step s spans [t_{s-1}, t_s], t_s = (jitter + s) h, t_{-1} = 0 (the first one is partial); a
        # segment is one base step, or as many as the macrocells it passes allow (transport.step_grid).
        s = 0
        t_prev = 0.0
        empty_until = t_near  # before it the medium is empty: jump as over an empty run
        while t_prev < tmax and t_prev < t_far and t_min < T:
            t_next = min((jitter + s) * h, tmax)
            tm = 0.5 * (t_prev + t_next)
            x, y, z = ox + tm * dx, oy + tm * dy, oz + tm * dz
            mi, mj, mk = macrocell_of(m, x, y, z)  # for the empty-run test and the segment's length
            if skip and tm >= empty_until:
                run = empty_run_in(m, mi, mj, mk, x, y, z, dx, dy, dz)
                if run > 0.0:
                    empty_until = tm + run
            if tm < empty_until:  # in empty space: sigma_t is 0 up to there, the sums stay as they are
                s = segment_past(s, empty_until, h, jitter, tmax)
                t_prev = (jitter + s - 1) * h
                continue
            n = 1
            if adaptive:
                n = int(units[mi, mj, mk])
                top = int(own[mi, mj, mk])
                if top > n:
                    n = units_along(m, own, ox, oy, oz, dx, dy, dz, vx, vy, vz, t_prev, tmax, h, top, n)
            if n > 1:  # the longer segment is sampled at its own midpoint
                t_next = min((jitter + s + n - 1) * h, tmax)
                tm = 0.5 * (t_prev + t_next)
                x, y, z = ox + tm * dx, oy + tm * dy, oz + tm * dz
            seg = t_next - t_prev
            if prefetch:  # the next base step's midpoint: its loads start under this sample's work (prefetch.py)
                tn = t_next + 0.5 * h
                qx, qy, qz = ox + tn * dx, oy + tn * dy, oz + tn * dz
                prefetch_scalar_stencil(m, qx, qy, qz)
                if use_volume:
                    prefetch_light_stencil(lv, grid, qx, qy, qz)
            sigma, a0, a1, a2 = extinction_albedo_at(m, x, y, z)
            if sigma > 0.0 and seg > 0.0:
                e = math.exp(-sigma * seg)
                w = T * (1.0 - e)
                ts = t_prev + scattering_centroid(sigma, seg, e)
                x, y, z = ox + ts * dx, oy + ts * dy, oz + ts * dz
                if picking and w > 0.0:
                    w_sum += w
                    state, u = next_float(state)
                    if u * w_sum < w:
                        pick[0, i], pick[1, i], pick[2, i] = x, y, z
                        pick[PICK_A, i], pick[PICK_A + 1, i], pick[PICK_A + 2, i] = a0, a1, a2
                if count == buffer:
                    light_samples(m, kind, vec, rgb, g, h_shadow, skip, use_volume, lv, wanted, grid, ld, missed,
                                   samples, ray_of, count, dirs, phases, lo)
                    count = 0
                samples[0, count], samples[1, count], samples[2, count], samples[3, count] = x, y, z, w
                samples[4, count], samples[5, count], samples[6, count] = a0, a1, a2
                ray_of[count] = i
                count += 1
                T *= e
            s += n
            t_prev = t_next
        trans[i] = T if t_min < T else 0.0
        if picking and w_sum > 0.0:
            pick[PICK_W, i] = w_sum
            pick[3, i], pick[4, i], pick[5, i] = dx, dy, dz
            pick_rng[i] = state
    light_samples(m, kind, vec, rgb, g, h_shadow, skip, use_volume, lv, wanted, grid, ld, missed, samples, ray_of,
                   count, dirs, phases, lo)


@njit(cache=True, parallel=True)
def _march(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, view: np.ndarray, width: int,
           n_pixels: int, work: np.ndarray, seed: int, near: np.ndarray, far: np.ndarray, tile: int, h: float,
           h_shadow: float, skip: bool, units: np.ndarray, own: np.ndarray, adaptive: bool, use_volume: bool,
           lv: np.ndarray, wanted: np.ndarray, grid: Grid, t_min: float, picking: bool, prefetch: bool,
           buffer: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    n = work.shape[0]
    ld = np.empty((3, n))
    trans = np.empty(n)
    missed = np.zeros(n, dtype=np.bool_)
    pick = np.empty((PICK_ROWS, n if picking else 1))
    pick_rng = np.zeros(n if picking else 1, np.uint64)
    per_task = task_items(n)  # fewer than TASK_ITEMS for the few rays re-marched after a fill
    tasks = (n + per_task - 1) // per_task
    stride = task_stride(tasks)
    for task in prange(tasks):
        b = (task * stride) % tasks  # golden-ratio order: each thread gets dense and empty blocks alike
        _march_items(m, kind, vec, rgb, g, view, width, n_pixels, work, seed, near, far, tile, h, h_shadow, skip,
                     units, own, adaptive, use_volume, lv, wanted, grid, t_min, ld, trans, missed, pick, pick_rng,
                     picking, prefetch, buffer, b * per_task, min(n, (b + 1) * per_task))
    return ld, trans, missed, pick, pick_rng


def march_work(scene: Scene, work: np.ndarray, seed: int, h: float, hs: float, skip: bool, lv: LightVolume | None,
               t_min: float, units: np.ndarray, own: np.ndarray, cancel: Callable[[], bool] | None = None,
               picking: bool = False) -> tuple[np.ndarray, np.ndarray, Picks]:
    """(L_d (3, n), transmittance (n,), picks) of work items ``work`` (``w = sample * pixels + pixel``, the camera ray
    of random stream w under ``seed``; rays that miss the box: 0 and 1). ``skip``: empty space is jumped over and
    each ray is marched only within its tile's depth bounds (:mod:`photon_fields.runtime.wavefront.depth_bounds`);
    False marches every ray through the whole box (the same sums). With a light volume (``lv``), the rays that
    read unfilled cells mark them, the cells are marched and those rays marched once more
    (runtime/transport/light_volume.py): the sums are the ones a filled volume gives. ``units`` / ``own``: base
    steps per segment per macrocell, the neighbourhood's and each macrocell's own (:func:`scene_step_units`,
    :func:`scene_own_units`; ``own`` all ones: fixed steps). ``cancel``: asked before each chunk of the fill
    (:func:`photon_fields.runtime.transport.light_volume.fill_wanted`); True stops with
    :class:`photon_fields.runtime.wavefront.batches.RenderCancelledError`, the cells filled so far kept.
    ``picking``: picks holds one scattering point per ray for an L_i estimate (:class:`Picks`, :func:`_march_items`;
    else placeholders). Each task marches up to ``preview_light.SAMPLE_BUFFER`` samples before it looks up their
    light (the same sums whatever it is; read at each call, so that a test can make it small)."""
    m = scene.medium()
    adaptive = bool(own.max() > 1)
    cam = scene.camera
    kind, vec, rgb = scene.packed_lights()
    values, wanted, grid = (lv.values, lv.wanted, lv.grid) if lv is not None else (_NO_VOLUME, _NO_WANTED, _NO_GRID)
    bounds = depth_bounds_for(scene, m) if skip else unbounded()
    args = (pack_view(cam), cam.width, cam.width * cam.height)

    def run(items: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return _march(m, kind, vec, rgb, scene.g, *args, items, int(seed), bounds.near, bounds.far, bounds.tile, h,
                      hs, skip, units, own, adaptive, lv is not None, values, wanted, grid, t_min, picking,
                      worth_prefetching(m), int(preview_light.SAMPLE_BUFFER))

    ld, trans, missed, pick, pick_rng = run(work)
    if lv is None or not missed.any():
        return ld, trans, Picks(pick, pick_rng)
    idx = np.flatnonzero(missed)
    if not fill_wanted(m, kind, vec, lv, cancel):
        raise batches.RenderCancelledError(f"cancelled while filling the light volume for {idx.size} rays")
    ld[:, idx], trans[idx], still, again, again_rng = run(work[idx])
    if picking:
        pick[:, idx], pick_rng[idx] = again, again_rng
    if still.any():
        raise RuntimeError("ray marcher: a light-volume cell its rays read was not filled")  # cannot happen
    return ld, trans, Picks(pick, pick_rng)


class Picks(NamedTuple):
    """One scattering point per ray (:func:`march_work` with ``picking``): ``values`` (:data:`PICK_ROWS`, n) and
    each ray's random state after its march ``rng`` (n,)."""

    values: np.ndarray
    rng: np.ndarray


def add_marched_picks(film: Film, estimator: IndirectEstimator, scene: Scene, pixel: np.ndarray,
                      picks: Picks) -> None:
    """At each ray's picked point x (weight W, albedo a): L_i += W a Q(x, d, g), and, when the scene has an
    environment light, L_d += W a NEE_env(x) (one sample of the environment's single scattering, which the
    light volume of delta lights does not hold)."""
    p = picks.values
    sel = np.flatnonzero(p[PICK_W] > 0.0)
    if sel.size == 0:
        return
    x, d = np.ascontiguousarray(p[0:3, sel]), np.ascontiguousarray(p[3:6, sel])
    weight = p[PICK_A:PICK_A + 3, sel] * p[PICK_W, sel]
    film.splat("L_i", pixel[sel], estimator(x, d, scene.g), True, weight=weight)
    kind, vec, rgb = scene.packed_lights()
    e = environment_index(kind)
    if e >= 0:
        env = direct_light_batch(scene.medium(), kind[e:e + 1], vec[e:e + 1], rgb[e:e + 1],
                                 scene.packed_environment_map(), scene.g, x, d, picks.rng[sel].copy(), False)
        film.splat("L_d", pixel[sel], env, True, weight=weight)


def scene_light_volume(scene: Scene, cells_per_voxel: float, shadow_step: float) -> LightVolume:
    """The scene's light volume at this grid scale and shadow step (voxels), created unfilled on first use and kept
    in the scene's cache, which camera and g overrides share (the volume depends on neither): later frames of the
    same medium and lights find the cells they read filled. A scene that adopted another's medium (a viewer's light
    edit, :meth:`Scene.adopt_medium`) starts from that scene's cells of every light that did not move."""
    volumes = scene.shared_cache("light_volumes")
    key = (float(cells_per_voxel), float(shadow_step))
    if key not in volumes:
        kind, vec, _ = scene.packed_lights()
        volumes[key] = new_light_volume(scene.medium(), len(kind), cells_per_voxel,
                                        shadow_step * scene.volume.voxel_size,
                                        scene_step_units(scene, shadow_step, SHADOW_SPAN * shadow_step))
        before = scene.shared_cache("light_volumes_before")  # a light edit's scene: the lights that did not move
        old = before.get("volumes", {}).get(key)
        if old is not None:
            adopt_light_columns(volumes[key], kind, vec, old, before["kind"], before["vec"])
        before.clear()  # the previous scene's volumes are not kept alive any longer
    return volumes[key]


def scene_step_units(scene: Scene, step: float, max_step: float) -> np.ndarray:
    """The scene's base steps per segment per macrocell for these steps (voxels;
    :func:`photon_fields.runtime.transport.step_grid.step_units`), kept in the scene's cache (camera and g overrides
    share it: it depends on the medium only)."""
    grids = scene.shared_cache("step_units")
    key = (float(step), float(max_step))
    if key not in grids:
        grids[key] = units_from_lengths(scene.medium(), _lengths(scene, grids), step, max_step)
    return grids[key]


def scene_own_units(scene: Scene, step: float, max_step: float) -> np.ndarray:
    """The scene's own base steps per macrocell for the camera's march (:func:`photon_fields.runtime.transport.
    step_grid.own_units`, read along each segment), cached beside :func:`scene_step_units`; all ones (fixed steps)
    where the occupied macrocells allow fewer than :data:`MIN_MEAN_UNITS` on average."""
    grids = scene.shared_cache("step_units")
    key = ("own", float(step), float(max_step))
    if key not in grids:
        own = own_units(scene.medium(), _lengths(scene, grids), step, max_step)
        occupied = own[own > 0]
        grids[key] = own if occupied.size and occupied.mean() >= MIN_MEAN_UNITS else np.ones_like(own)
    return grids[key]


def _lengths(scene: Scene, grids: dict) -> np.ndarray:
    """The pass over sigma_t that the camera's and the light volume's step grids share (``step_lengths``)."""
    if "lengths" not in grids:
        grids["lengths"] = step_lengths(scene.medium(), scene.volume.voxel_size)
    return grids["lengths"]


def light_volume_settings(scene: Scene, light_grid_scale: float | None = None,
                          shadow_step: float | None = None) -> tuple[float, float]:
    """The preview's light-volume cells per voxel and shadow step in voxels, defaults resolved: the scale from
    :func:`photon_fields.runtime.transport.light_volume.auto_cells_per_voxel`, the step half a cell (half a voxel
    where cells are finer)."""
    scale = auto_cells_per_voxel(scene.volume.dims) if light_grid_scale is None else light_grid_scale
    return scale, DEFAULT_SHADOW_STEP / min(1.0, scale) if shadow_step is None else shadow_step


def camera_light_volume(scene: Scene, camera: str) -> LightVolume | None:
    """What a first-interaction renderer's ``camera`` estimator reads: for "marched"
    (:mod:`photon_fields.runtime.wavefront.marched_camera`) the light volume of the preview's default settings
    (:func:`light_volume_settings`) from the scene's cache, shared with the preview's frames; None for the others."""
    return scene_light_volume(scene, *light_volume_settings(scene)) if camera == "marched" else None


def camera_estimator_for(scene: Scene, estimator: IndirectEstimator | None, camera: str, light_sampling: str,
                         spp: int) -> tuple[str, LightVolume | None]:
    """A first-interaction renderer's ``camera`` estimator with "auto" resolved
    (:func:`photon_fields.runtime.wavefront.camera_choice.resolve_camera_estimator`, for a render of ``spp``), and
    the light volume it reads (:func:`camera_light_volume`)."""
    camera = resolve_camera_estimator(scene, estimator, camera, lambda: camera_light_volume(scene, "marched"),
                                      light_sampling, spp)
    return camera, camera_light_volume(scene, camera)


def render_ray_marched(scene: Scene, *, spp: int = 1, step: float = 1.0, shadows: str = "volume",
                       shadow_step: float | None = None, light_grid_scale: float | None = None,
                       min_transmittance: float = DEFAULT_MIN_TRANSMITTANCE, max_step: float | None = None,
                       seed: int = 0, batch_size: int = MARCH_BATCH, progress: bool = True, skip_empty: bool = True,
                       level: int = 0, cancel: Callable[[], bool] | None = None,
                       estimator: IndirectEstimator | None = None) -> RenderResult:
    """Single scattering by ray marching (module docstring for the parameters). Layers L, L_e and L_d (L_i stays
    zero). ``skip_empty``: camera and shadow rays look nothing up in empty macrocells (the same image, sooner;
    False: every sample looked up, the reference the tests and ``bench_ray_marcher.py`` compare with).
    ``cancel``: asked before each batch and during the light volume's fill (:func:`march_work`); True stops the
    render with :class:`photon_fields.runtime.wavefront.batches.RenderCancelledError` (the viewer's resting frames:
    an edit's full-level frame at 256^3 is seconds of work).

    ``estimator`` (a photon field's, ``PhotonField.estimator()``): L_i too, the estimator's Q at one scattering
    point per ray drawn along the march (module docstring, "Multiple scattering from a field")."""
    scene = scene_at_level(scene, level)
    use_volume = check_choice("--shadows", shadows, SHADOWS) == "volume"
    if use_volume:
        light_grid_scale, shadow_step = light_volume_settings(scene, light_grid_scale, shadow_step)
    elif shadow_step is None:
        shadow_step = 1.0
    env = scene_environment(scene)
    h = step * scene.volume.voxel_size
    hs = shadow_step * scene.volume.voxel_size
    lv = scene_light_volume(scene, light_grid_scale, shadow_step) if use_volume else None
    max_step = DEFAULT_SPAN * step if max_step is None else max_step
    units, own = scene_step_units(scene, step, max_step), scene_own_units(scene, step, max_step)
    cam = scene.camera
    film = Film(cam.width, cam.height)
    timer = StageTimer()
    t_start = time.perf_counter()
    n_pixels = cam.width * cam.height
    batch = min(batch_size, n_pixels)  # distinct pixels in a batch (Film.splat)
    with progress_bar(total=n_pixels * spp, desc="ray marching", unit="spl", unit_scale=True,
                      enabled=progress) as bar:
        order = tile_order(cam.width, cam.height)  # each task's rays read the same cache lines (rays.py)
        for start, count in work_batches(0, n_pixels * spp, batch):
            if cancel is not None and cancel():
                raise batches.RenderCancelledError(f"cancelled before work item {start}")
            work = tiled_work(start, count, order)
            with timer("march"):
                ld, trans, picks = march_work(scene, work, seed, h, hs, skip_empty, lv, min_transmittance, units,
                                             own, cancel, estimator is not None)
            pixel = work % n_pixels
            film.splat("L_d", pixel, ld, True)
            if estimator is not None:
                with timer("estimate_indirect"):
                    add_marched_picks(film, estimator, scene, pixel, picks)
            if env is not None:
                film.splat("L_e", pixel, trans[None, :] * env.behind_camera_rays(cam, work, seed), True)
            bar.update(count)
    return finish(film, timer, spp, t_start, {})
