"""The PVRT renderer (paper Sec. 7): relighting from a precomputed transfer (``pfn-train pvrt``).

Per frame (after a light or camera change): project the lighting into the basis (Sec. 7.1,
``runtime/pvrt/lighting.py``), evaluate the view-dependent radiance volume with early evaluation in CPCA space
(Sec. 7.2, ``runtime/pvrt/radiance.py``), march each directional light's light volume (its direct term by NEE,
the fall-back for a delta the basis cannot represent), weigh the quadrature directions of the basis lighting's
direct term (Sec. 6.2, ``runtime/pvrt/direct.py``), then ray-march the camera rays (Sec. 7.3):

    L_d = sum_s T_s (1 - exp(-sigma_s dt)) albedo_s [sum_q W_q f_g(w_o, w_q) exp(-tau_q(x_s))
                                                     + sum_lights f_g(w_o, l) E T_light(x_s)]
    L_i = sum_s T_s (1 - exp(-sigma_s dt)) albedo_s R_ms(x_s)
    L_e = T_exit * sky(w)

with ``tau_q`` the optical-depth volume towards quadrature direction w_q (trilinear before the exponential,
computed once per transfer), ``W_q`` the lighting on it, ``R_ms`` the radiance volume of multiple scattering
(trilinear, cell-centred, each cell weighted by s_v: ``runtime/pvrt/radiance.py``), sigma and
albedo from the full-resolution medium, the same segment quadrature and jittered start as
``runtime/renderers/ray_marcher.py`` and its empty-space skipping (``tracking.empty_run``). Layers L, L_d, L_i, L_e
as the other renderers.

Relighting (the paper's use: the view stays, a light or the environment turns): the samples x_s and their weights
T_s (1 - exp(-sigma_s dt)) albedo_s do not depend on the lighting. :class:`Relighting` marches the camera rays once
and keeps them; each frame then only projects the lighting, evaluates the radiance volume, marches the light volumes
at the cells the kept samples read, and sums the samples: the same sums without the walk through the medium.

Parameters: ``transfer`` (a :class:`photon_fields.runtime.pvrt.transfer.Transfer`, checked against the scene),
``step`` (camera step in voxels), ``direct`` ("nee": directional lights' direct term from light volumes, "transfer":
from the basis), ``light_grid`` (light-volume cells along the longest side), ``sky`` (a callable sky, Python API),
``rotation`` (3x3: turns the whole lighting), ``skip_empty`` (see :func:`render_pvrt`).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np
from numba import njit, prange

from photon_fields.runtime.pvrt.constants import DEFAULT_LIGHT_GRID, DIRECT_STEP
from photon_fields.runtime.pvrt.direct import (
    NO_BASIS_DIRECT,
    BasisDirect,
    basis_direct,
    direct_volumes,
    direct_weights,
    kept_direct,
    nee,
    phases,
    quadrature,
    sample_transmittances,
)
from photon_fields.runtime.pvrt.lighting import scene_lighting
from photon_fields.runtime.pvrt.precompute import grid_shape
from photon_fields.runtime.pvrt.radiance import CHANNELS, interpolation_weights, light_volumes, radiance_volume
from photon_fields.runtime.pvrt.transfer import Transfer
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.cell_grid import Grid, grid_of, stencil, trilinear
from photon_fields.runtime.transport.marching import segment_past
from photon_fields.runtime.transport.medium import Medium, borrowed_medium, extinction_albedo_at
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import TASK_ITEMS, empty_run, task_stride
from photon_fields.runtime.wavefront.batches import RenderResult, StageTimer, finish
from photon_fields.runtime.wavefront.film import Film
from photon_fields.runtime.wavefront.rays import clip_rays_to_volume, generate_camera_rays

_T_MIN = 1e-4  # as the ray marcher: stop once the camera ray is this opaque


@njit(cache=True, inline="always")
def _radiance_sums(rad: np.ndarray, grid: Grid, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """The trilinear interpolations at x of the radiance volume's multiple-scattering radiance times s_v (RGB) and of
    the cells' weights s_v (radiance.CHANNELS); the radiance is their quotient. A corner's 4 channels are
    16 adjacent bytes and all share the stencil's weight: summed in float32 (the volume's precision) as 4 scalars,
    which fit one vector register, not in an array the kernel would have to allocate or be handed."""
    i, j, k, fx, fy, fz = stencil(grid, x, y, z)
    r0 = r1 = r2 = r3 = np.float32(0.0)
    for corner in range(8):
        a, b, e = corner & 1, (corner >> 1) & 1, corner >> 2
        w = np.float32((fx if a else 1.0 - fx) * (fy if b else 1.0 - fy) * (fz if e else 1.0 - fz))
        v = rad[i + a, j + b, k + e]
        r0 += w * v[0]
        r1 += w * v[1]
        r2 += w * v[2]
        r3 += w * v[3]
    return r0, r1, r2, r3


#: What :func:`_march_items` does with a sample: sum its light, count it, or keep its position and weight.
_EVALUATE, _COUNT, _RECORD = 0, 1, 2


@njit(cache=True)
def _march_items(m: Medium, rad: np.ndarray, lights: np.ndarray, travel: np.ndarray, rgb: np.ndarray,
                 basis: BasisDirect, g: float, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, states: np.ndarray,
                 h: float, skip: bool, mode: int, out: np.ndarray, trans: np.ndarray, first: np.ndarray,
                 pos: np.ndarray, weight: np.ndarray, lo: int, hi: int) -> None:
    """Camera rays lo..hi-1 of :func:`_march`, serially (``TASK_ITEMS`` in the tracking module says why). Per
    sample with sigma_t > 0 (its weight w = T_s (1 - exp(-sigma_s dt)) albedo_s, RGB), by ``mode``: _EVALUATE adds
    w times what it sends towards the camera per unit albedo (the basis lighting's direct term, ``basis_direct``,
    plus the lights' NEE, ``nee``, to out[0:3] (L_d); the radiance volume's s_v-weighted interpolation,
    :func:`_radiance_sums`, to out[3:6] (L_i)); _COUNT counts
    the ray's samples into ``first[ray]``; _RECORD writes their positions and weights to ``pos`` and ``weight[0:3]``
    from index ``first[ray]`` on. Every mode writes the transmittance into ``trans``.

    Segment s of a ray spans [t_{s-1}, t_s] with t_s = (jitter + s) h (t_{-1} = 0), sampled at its midpoint; over
    an empty run (:func:`empty_run`) the walk jumps to the first segment whose midpoint is past it (the midpoints
    it passes have sigma_t = 0 and add nothing), so empty space costs one step per run, not one per segment
    (``skip`` False: every midpoint looked up, the same sums). (The rays are not a kernel of their own: an inlined
    call per ray took and released a reference to each of its 13 arrays.)"""
    m = borrowed_medium(m)  # no reference counting in the loops below (runtime/borrowed.py)
    depth, active, b_travel, b_rgb = basis
    ph = np.empty(travel.shape[0])  # each light's phase along the ray
    b_ph = np.empty(b_travel.shape[0])  # each active quadrature direction's
    b_tau = np.empty(depth.shape[3])  # the optical depths at a sample
    rg = grid_of(m, rad.shape[0], rad.shape[1], rad.shape[2])
    lg = grid_of(m, lights.shape[1], lights.shape[2], lights.shape[3])
    bg = grid_of(m, depth.shape[0], depth.shape[1], depth.shape[2])
    for ray in range(lo, hi):
        states[ray], jitter = next_float(states[ray])
        ox, oy, oz, dx, dy, dz = o[0, ray], o[1, ray], o[2, ray], d[0, ray], d[1, ray], d[2, ray]
        phased = False  # the phases are computed at the ray's first sample in the medium (most rays have none)
        t_end = tmax[ray]
        T = 1.0
        s = 0
        t_prev = 0.0
        empty_until = -math.inf
        q = first[ray] if mode == _RECORD else 0
        l0 = l1 = l2 = l3 = l4 = l5 = 0.0
        while t_prev < t_end and T > _T_MIN:
            t_next = min((jitter + s) * h, t_end)
            seg = t_next - t_prev
            tm = 0.5 * (t_prev + t_next)
            x, y, z = ox + tm * dx, oy + tm * dy, oz + tm * dz
            if skip and tm >= empty_until:
                run = empty_run(m, x, y, z, dx, dy, dz)
                if run > 0.0:
                    empty_until = tm + run
            if tm < empty_until:
                s = segment_past(s, empty_until, h, jitter, t_end)
                t_prev = (jitter + s - 1) * h
                continue
            sigma, a0, a1, a2 = extinction_albedo_at(m, x, y, z)
            if sigma > 0.0 and seg > 0.0:
                e = math.exp(-sigma * seg)
                w = T * (1.0 - e)
                if mode == _EVALUATE:
                    if not phased:
                        phases(g, travel, dx, dy, dz, ph)
                        phases(g, b_travel, dx, dy, dz, b_ph)
                        phased = True
                    r0, r1, r2, dv = _radiance_sums(rad, rg, x, y, z)
                    inv = 1.0 / dv if dv > 0.0 else 0.0  # no medium in reach: no transfer
                    n0, n1, n2 = nee(lights, lg, ph, rgb, x, y, z)
                    b0, b1, b2 = basis_direct(depth, bg, active, b_ph, b_rgb, b_tau, x, y, z)
                    l0 += w * a0 * (n0 + b0)
                    l1 += w * a1 * (n1 + b1)
                    l2 += w * a2 * (n2 + b2)
                    l3 += w * a0 * (r0 * inv)
                    l4 += w * a1 * (r1 * inv)
                    l5 += w * a2 * (r2 * inv)
                elif mode == _RECORD and q < pos.shape[1]:  # the same walk as _COUNT's: never false
                    pos[0, q], pos[1, q], pos[2, q] = x, y, z
                    weight[0, q], weight[1, q], weight[2, q] = w * a0, w * a1, w * a2
                q += 1
                T *= e
            s += 1
            t_prev = t_next
        if mode == _EVALUATE:
            out[0, ray], out[1, ray], out[2, ray], out[3, ray], out[4, ray], out[5, ray] = l0, l1, l2, l3, l4, l5
        elif mode == _COUNT:
            first[ray] = q
        trans[ray] = T if T > _T_MIN else 0.0


@njit(cache=True, parallel=True)
def _march(m: Medium, rad: np.ndarray, lights: np.ndarray, travel: np.ndarray, rgb: np.ndarray, basis: BasisDirect,
           g: float, o: np.ndarray, d: np.ndarray, tmax: np.ndarray, states: np.ndarray, h: float, skip: bool,
           mode: int, first: np.ndarray, pos: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All camera rays (:func:`_march_items`): (out (6, n) (zeros unless _EVALUATE), transmittance (n,))."""
    n = o.shape[1]
    out = np.zeros((6, n))
    trans = np.ones(n)
    tasks = (n + TASK_ITEMS - 1) // TASK_ITEMS
    stride = task_stride(tasks)
    for task in prange(tasks):
        b = (task * stride) % tasks  # blocks spread over the image (task_stride)
        _march_items(m, rad, lights, travel, rgb, basis, g, o, d, tmax, states, h, skip, mode, out, trans, first,
                     pos, weight, b * TASK_ITEMS, min(n, (b + 1) * TASK_ITEMS))
    return out, trans


@njit(cache=True)
def _sum_items(m: Medium, rad: np.ndarray, lights: np.ndarray, travel: np.ndarray, rgb: np.ndarray,
               basis: BasisDirect, g: float, d: np.ndarray, first: np.ndarray, pos: np.ndarray, weight: np.ndarray,
               kept_tr: np.ndarray, out: np.ndarray, lo: int, hi: int) -> None:
    """Rays lo..hi-1 of :func:`_sum_kept`: out[0:6, ray] = the sum over the ray's kept samples (from first[ray] to
    first[ray + 1]) of what :func:`_march_items` adds for them, with their s_v's reciprocal kept in weight[3] and,
    when ``kept_tr`` has a row per sample, their transmittances towards the quadrature directions."""
    m = borrowed_medium(m)  # no reference counting in the loops below (runtime/borrowed.py)
    depth, active, b_travel, b_rgb = basis
    ph = np.empty(travel.shape[0])
    b_ph = np.empty(b_travel.shape[0])
    b_tau = np.empty(depth.shape[3])
    rg = grid_of(m, rad.shape[0], rad.shape[1], rad.shape[2])
    lg = grid_of(m, lights.shape[1], lights.shape[2], lights.shape[3])
    bg = grid_of(m, depth.shape[0], depth.shape[1], depth.shape[2])
    for ray in range(lo, hi):
        if first[ray + 1] > first[ray]:  # most rays keep no sample
            phases(g, travel, d[0, ray], d[1, ray], d[2, ray], ph)
            phases(g, b_travel, d[0, ray], d[1, ray], d[2, ray], b_ph)
        l0 = l1 = l2 = l3 = l4 = l5 = 0.0
        for q in range(first[ray], first[ray + 1]):
            x, y, z = pos[0, q], pos[1, q], pos[2, q]
            r0, r1, r2, _ = _radiance_sums(rad, rg, x, y, z)
            n0, n1, n2 = nee(lights, lg, ph, rgb, x, y, z)
            if kept_tr.shape[0] > 0:
                b0, b1, b2 = kept_direct(kept_tr, q, active, b_ph, b_rgb)
            else:
                b0, b1, b2 = basis_direct(depth, bg, active, b_ph, b_rgb, b_tau, x, y, z)
            w0, w1, w2, inv = weight[0, q], weight[1, q], weight[2, q], weight[3, q]
            l0 += w0 * (n0 + b0)
            l1 += w1 * (n1 + b1)
            l2 += w2 * (n2 + b2)
            l3 += w0 * (r0 * inv)
            l4 += w1 * (r1 * inv)
            l5 += w2 * (r2 * inv)
        out[0, ray], out[1, ray], out[2, ray], out[3, ray], out[4, ray], out[5, ray] = l0, l1, l2, l3, l4, l5


@njit(cache=True, parallel=True)
def _sum_kept(m: Medium, rad: np.ndarray, lights: np.ndarray, travel: np.ndarray, rgb: np.ndarray, basis: BasisDirect,
              g: float, d: np.ndarray, first: np.ndarray, pos: np.ndarray, weight: np.ndarray,
              kept_tr: np.ndarray) -> np.ndarray:
    n = d.shape[1]
    out = np.empty((6, n))
    tasks = (n + TASK_ITEMS - 1) // TASK_ITEMS
    stride = task_stride(tasks)
    for task in prange(tasks):
        b = (task * stride) % tasks
        _sum_items(m, rad, lights, travel, rgb, basis, g, d, first, pos, weight, kept_tr, out, b * TASK_ITEMS,
                   min(n, (b + 1) * TASK_ITEMS))
    return out


@njit(cache=True)
def _kept_cells(m: Medium, pos: np.ndarray, weight: np.ndarray, dv: np.ndarray, gx: int, gy: int,
                gz: int) -> np.ndarray:
    """For kept samples at ``pos`` (3, n): weight[3] = 1 / s at each (``dv``: the transfer grid's interpolation
    weights s_v, ``radiance.interpolation_weights``, trilinear; 0 where it is 0, as the march divides), and the
    cells of a (gx, gy, gz) light grid their stencils read."""
    out = np.zeros((gx, gy, gz), dtype=np.bool_)
    rg = grid_of(m, dv.shape[0], dv.shape[1], dv.shape[2])
    lg = grid_of(m, gx, gy, gz)
    for q in range(pos.shape[1]):
        x, y, z = pos[0, q], pos[1, q], pos[2, q]
        i, j, k, fx, fy, fz = stencil(rg, x, y, z)
        v = trilinear(dv, i, j, k, fx, fy, fz)
        weight[3, q] = 1.0 / v if v > 0.0 else 0.0
        i, j, k, _, _, _ = stencil(lg, x, y, z)
        for corner in range(8):
            out[i + (corner & 1), j + ((corner >> 1) & 1), k + (corner >> 2)] = True
    return out


class _Frame:
    """What one frame's lighting gives the camera: the lighting's projection, the radiance volume towards the eye,
    the light volumes (of ``cells``, a mask of the light grid, when given; ``previous``'s when a frame of the same
    view had the same directional lights), the basis lighting's direct term (its weights on the quadrature
    directions and the transfer's optical-depth volumes, ``runtime/pvrt/direct.py``), and the sky along view
    directions."""

    def __init__(self, scene: Scene, lights: tuple, transfer: Transfer, timer: StageTimer, *, sky, direct: str,  # noqa: ANN001
                 rotation: np.ndarray | None, light_grid: int, skip_empty: bool, cells: np.ndarray | None = None,
                 previous: _Frame | None = None):
        m = scene.medium()
        with timer("project_lighting"):
            self.lighting = scene_lighting(lights, transfer.basis, sky=sky, direct=direct, rotation=rotation)
        with timer("radiance_volume"):
            self.rad = radiance_volume(transfer, self.lighting, scene.camera.eye, scene.g)
        with timer("light_volumes"):
            if previous is not None and np.array_equal(previous.lighting.nee_directions,
                                                       self.lighting.nee_directions):
                self.lights = previous.lights  # only the sky, a colour or a power changed: the same shadows
            else:
                self.lights = light_volumes(m, self.lighting.nee_directions, light_grid,
                                            float(scene.volume.voxel_size), skip_empty, cells)
        with timer("direct_volumes"):  # once per transfer (cached on it); then only the weights change
            w = direct_weights(transfer.basis, self.lighting.direct_coeffs)
            active = np.flatnonzero(np.any(w != 0.0, axis=1))
            self.basis: BasisDirect = NO_BASIS_DIRECT
            if len(active):
                depth = direct_volumes(transfer, m, light_grid, DIRECT_STEP * float(scene.volume.voxel_size),
                                       skip_empty)
                travel = np.ascontiguousarray(-quadrature(transfer.basis)[0][active])  # the light arrives from w_q
                self.basis = (depth, active.astype(np.int64), travel, np.ascontiguousarray(w[active]))
        self.travel = np.ascontiguousarray(self.lighting.nee_directions, dtype=np.float64)
        self.rgb = np.ascontiguousarray(self.lighting.nee_rgb, dtype=np.float64)
        self.see_sky = self.lighting.sky is not None or bool(np.any(self.lighting.constant_sky > 0))

    def sky_at(self, dirs: np.ndarray) -> np.ndarray:
        """(3, n) view directions -> (3, n) the radiance they see from the sky."""
        if self.lighting.sky is not None:
            return self.lighting.sky(np.ascontiguousarray(dirs.T)).T
        return np.broadcast_to(self.lighting.constant_sky[:, None], dirs.shape).astype(np.float64)

    def splat(self, film: Film, pixel: np.ndarray, d: np.ndarray, out: np.ndarray, trans: np.ndarray,
              distinct: bool) -> None:
        """Add the camera rays' layers: L_d and L_i from ``out``, L_e as the sky through ``trans`` (1 for the rays
        that miss the box) (``distinct``: no pixel repeats among the rays, :meth:`Film.splat`)."""
        film.splat("L_d", pixel, out[:3], distinct)
        film.splat("L_i", pixel, out[3:], distinct)
        if self.see_sky:
            film.splat("L_e", pixel, trans[None, :] * self.sky_at(d), distinct)


_NO_SAMPLES = (np.zeros(1, dtype=np.int64), np.zeros((3, 0), dtype=np.float32), np.zeros((3, 0), dtype=np.float32))


def render_pvrt(scene: Scene, *, transfer: Transfer, spp: int = 1, seed: int = 0, batch_size: int = 1 << 18,
                progress: bool = True, step: float = 1.0, direct: str = "nee", light_grid: int = DEFAULT_LIGHT_GRID,
                sky=None, rotation: np.ndarray | None = None,  # noqa: ANN001  (sky: SkyFunction)
                skip_empty: bool = True) -> RenderResult:
    """Render ``scene`` (its lights, plus ``sky``) from ``transfer`` (module docstring). ``stats`` records the
    notes of the lighting's projection (e.g. the NEE fall-back of a directional light). ``skip_empty``: camera
    and shadow rays look nothing up in empty macrocells and the light volumes march only the cells a camera sample
    in the medium can read (the same image, sooner; False: every sample and cell, the reference of the tests).
    Frames of one view under changing lights: :class:`Relighting`."""
    timer = StageTimer()
    t_start = time.perf_counter()
    transfer.check_scene(scene)
    m = scene.medium()
    frame = _Frame(scene, scene.lights, transfer, timer, sky=sky, direct=direct, rotation=rotation,
                   light_grid=light_grid, skip_empty=skip_empty)
    cam = scene.camera
    film = Film(cam.width, cam.height)
    h = step * scene.volume.voxel_size
    n_pixels = cam.width * cam.height
    for start in range(0, n_pixels * spp, batch_size):
        work = np.arange(start, min(start + batch_size, n_pixels * spp), dtype=np.int64)
        with timer("generate_camera_rays"):  # a ray that misses the box gets tmax 0: nothing to march, T = 1
            rays = generate_camera_rays(cam, work, seed)
            clip_rays_to_volume(m, rays)
        with timer("march"):
            out, trans = _march(m, frame.rad, frame.lights, frame.travel, frame.rgb, frame.basis, float(scene.g),
                                rays.o, rays.d, rays.tmax, rays.rng, h, skip_empty, _EVALUATE, *_NO_SAMPLES)
        frame.splat(film, rays.pixel, rays.d, out, trans, distinct=len(work) <= n_pixels)
    result = finish(film, timer, spp, t_start, {})
    result.stats["notes"] = "; ".join(frame.lighting.notes)  # type: ignore[assignment]
    return result


#: Samples a :class:`Relighting` keeps at most (28 bytes each: 470 MB); beyond, it marches every frame.
MAX_KEPT_SAMPLES = 1 << 24
#: Transmittances (samples x quadrature directions, float32: 256 MB) a :class:`Relighting` keeps at most for the
#: basis lighting's direct term; beyond, each frame looks up and exponentiates the optical depths again.
MAX_KEPT_TRANSMITTANCES = 1 << 26
_NO_KEPT_TR = np.zeros((0, 1), dtype=np.float32)


class Relighting:
    """PVRT frames of one view (scene, camera, g) under changing lights: the paper's relighting.

    A light change leaves the camera rays' samples in the medium as they were: their positions and weights
    T_s (1 - exp(-sigma_s dt)) albedo_s depend on the medium and the camera only. The constructor marches the
    camera rays twice (counting, then recording the samples: 28 bytes each, float32) and notes which light-volume
    cells they read; each :meth:`render` then projects the lighting, evaluates the radiance volume, marches the
    light volumes at those cells only (or reuses the last frame's when the directional lights did not move: an
    environment turned, a colour or power changed) and sums the kept samples (:func:`_sum_kept`): the same sums as
    :func:`render_pvrt` with the same ``seed``, up to the float32 positions and weights (relative 1e-6), without
    the walk through the medium. The first frame whose lighting has a basis direct term (a sky, an environment map)
    also keeps each sample's transmittances towards the quadrature directions (``runtime/pvrt/direct.py``; 4 bytes
    per sample and direction, up to :data:`MAX_KEPT_TRANSMITTANCES`): they depend on the medium only, and the
    later frames then weigh them instead of looking up and exponentiating 42 optical depths per sample. More than
    ``max_samples`` samples are not kept; every frame then marches."""

    def __init__(self, scene: Scene, transfer: Transfer, *, spp: int = 1, seed: int = 0,
                 batch_size: int = 1 << 18, step: float = 1.0, light_grid: int = DEFAULT_LIGHT_GRID,
                 max_samples: int = MAX_KEPT_SAMPLES) -> None:
        transfer.check_scene(scene)
        self.scene, self.transfer = scene, transfer
        self.spp, self.seed, self.batch_size, self.step, self.light_grid = spp, seed, batch_size, step, light_grid
        self.timings_ms: dict[str, float] = {}
        self.kept = False
        self._previous: _Frame | None = None  # the last frame: its light volumes serve a frame with the same lights
        self._tr: np.ndarray | None = None  # the samples' transmittances towards the quadrature directions
        t0 = time.perf_counter()
        m = scene.medium()
        cam = scene.camera
        h = step * scene.volume.voxel_size
        parts: dict[str, list[np.ndarray]] = {k: [] for k in ("pixel", "d", "first", "trans")}
        samples: list[tuple[np.ndarray, np.ndarray]] = []
        total = 0
        for start in range(0, cam.width * cam.height * spp, batch_size):
            rays = generate_camera_rays(cam, np.arange(start, min(start + batch_size, cam.width * cam.height * spp),
                                                       dtype=np.int64), seed)
            clip_rays_to_volume(m, rays)  # misses: tmax 0, no samples, T = 1
            count = np.zeros(len(rays) + 1, dtype=np.int64)
            _, trans = _march(m, *_empty_lighting(), float(scene.g), rays.o, rays.d, rays.tmax, rays.rng.copy(), h,
                              True, _COUNT, count, *_NO_SAMPLES[1:])
            total += int(count.sum())
            if total > max_samples:
                return  # too many to keep: render() marches
            first = np.zeros(len(rays) + 1, dtype=np.int64)
            np.cumsum(count[:-1], out=first[1:])
            pos = np.empty((3, int(first[-1])), dtype=np.float32)
            weight = np.empty((4, pos.shape[1]), dtype=np.float32)  # w albedo (RGB), then 1 / s_v (_kept_cells)
            _march(m, *_empty_lighting(), float(scene.g), rays.o, rays.d, rays.tmax, rays.rng.copy(), h, True,
                   _RECORD, first, pos, weight)
            samples.append((pos, weight))
            parts["pixel"].append(rays.pixel)
            parts["d"].append(rays.d)
            parts["first"].append(first[:-1] + sum(p.shape[1] for p, _ in samples[:-1]))
            parts["trans"].append(trans)
        self.pixel = np.concatenate(parts["pixel"])
        self.d = np.ascontiguousarray(np.concatenate(parts["d"], axis=1))
        self.first = np.append(np.concatenate(parts["first"]), total).astype(np.int64)
        self.trans = np.concatenate(parts["trans"])
        self.pos = np.ascontiguousarray(np.concatenate([p for p, _ in samples], axis=1))
        self.weight = np.ascontiguousarray(np.concatenate([w for _, w in samples], axis=1))
        # 1 / s_v of each sample into weight[3]; the light cells they read (a subset of the needed ones)
        self.cells = _kept_cells(m, self.pos, self.weight, interpolation_weights(transfer),
                                 *grid_shape(m.bsize, light_grid))
        self.kept = True
        self.timings_ms["keep_samples"] = (time.perf_counter() - t0) * 1e3

    @property
    def samples(self) -> int:
        """How many camera samples are kept (0 when there were too many)."""
        return self.pos.shape[1] if self.kept else 0

    def render(self, lights: tuple, *, sky=None, direct: str = "nee",  # noqa: ANN001  (sky: SkyFunction)
               rotation: np.ndarray | None = None) -> RenderResult:
        """The frame under ``lights`` (a scene's lights tuple), ``sky`` and ``rotation`` (as :func:`render_pvrt`)."""
        scene = replace(self.scene, lights=tuple(lights), _cache={})  # checks the lights as a scene does
        scene._cache["medium"] = self.scene.medium()  # the medium ignores the lights
        if not self.kept:
            return render_pvrt(scene, transfer=self.transfer, spp=self.spp, seed=self.seed,
                               batch_size=self.batch_size, progress=False, step=self.step, direct=direct,
                               light_grid=self.light_grid, sky=sky, rotation=rotation)
        timer = StageTimer()
        t_start = time.perf_counter()
        frame = _Frame(scene, scene.lights, self.transfer, timer, sky=sky, direct=direct, rotation=rotation,
                       light_grid=self.light_grid, skip_empty=True, cells=self.cells, previous=self._previous)
        self._previous = frame
        film = Film(scene.camera.width, scene.camera.height)
        depth = frame.basis[0]
        if len(frame.basis[1]) and self._tr is None and self.samples * depth.shape[3] <= MAX_KEPT_TRANSMITTANCES:
            with timer("keep_transmittances"):  # once per view: the optical-depth volumes are the transfer's
                self._tr = sample_transmittances(scene.medium(), depth, self.pos)
        with timer("sum_samples"):
            out = _sum_kept(scene.medium(), frame.rad, frame.lights, frame.travel, frame.rgb, frame.basis,
                            float(scene.g), self.d, self.first, self.pos, self.weight,
                            self._tr if len(frame.basis[1]) and self._tr is not None else _NO_KEPT_TR)
        frame.splat(film, self.pixel, self.d, out, self.trans, self.spp == 1)
        result = finish(film, timer, self.spp, t_start, {})
        result.stats["notes"] = "; ".join(frame.lighting.notes)  # type: ignore[assignment]
        return result


def _empty_lighting() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, BasisDirect]:
    """(rad, lights, travel, rgb, basis) placeholders for the marches that only count or record samples."""
    return (np.zeros((2, 2, 2, CHANNELS), dtype=np.float32), np.zeros((0, 2, 2, 2), dtype=np.float32), np.zeros((0, 3)),
            np.zeros((0, 3)), NO_BASIS_DIRECT)
