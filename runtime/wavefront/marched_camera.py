"""The "marched" camera estimator: every stratum of a camera ray scatters the cached light; one point is corrected.

Parameters (module constants)
-----------------------------
STRATA_PER_DEPTH : float
    Strata per unit of majorant optical depth (2: half an optical depth each; bench/README.md has why not 1).
STRATUM_VOXELS, STRATUM_BOX_FRACTION : float
    The longest stratum: ``STRATUM_VOXELS`` voxels (2: against 1, 10-20 % less time in the walk for the same error on
    vortex, shell and head, blobs 0.192 -> 0.197 at 1 spp; 4 saved no more), or ``STRATUM_BOX_FRACTION`` of the
    box's longest side (1/48: two voxels of a 96^3 volume) where that is longer, so that a finer volume's walk does
    not take more strata for the same medium (docs/rendering.md, "Strata at 256^3").
CORRECTION_SHADOW_BOOST : float
    The picks' shadow rays (NEE, whose difference from the cache is the correction) estimate their transmittance by
    residual ratio tracking over strata as the walk's, against a control linear between the strata's points
    (:mod:`photon_fields.runtime.transport.residual_tracking`, :func:`correction_nee`), with events at this many
    times the majorant (1). With the cached light's noise gone, the shadow rays' transmittance noise was most of the
    marched L_d's at thin walls; against ratio tracking at 4x the majorant (every other shadow ray's
    ``tracking.SHADOW_BOOST`` is 2) it gains most on the thin-walled scenes (bench/README.md, "Residual shadow rays
    for the marched picks", and "A stage of its own" for why these are stages apart from every renderer's NEE).
RESIDUAL_BOOST : float
    The residual tracker's events at this many times the majorant (2; the factors' spread, which makes W noisy at
    walls, falls as 1 / boost, and each event is a lookup). With the piecewise-linear control below, 2 and 4 are
    level in efficiency on shell, head and blobs, and 2 is 5 % better on vortex; 1 loses on shell and head
    (bench/README.md, "A linear control").
PICKS : int
    Points drawn from one walk's candidates, each with its own shadow ray (NEE) and field query, weighted W / PICKS
    (3: the walk is most of the cost, so more points per walk pay; 4 gained no more: docs/rendering.md).

The forced estimator (:mod:`photon_fields.runtime.wavefront.first_interaction`) gives every ray that crosses the
medium one collision x, weighted by the walk's estimate W of 1 - T; its L_d is W a(x) NEE(x). On sparse media most
of a 1-spp frame's noise is where along the ray x falls, and the one shadow ray there: the ray marcher, whose
light volume holds each delta light's transmittance on a grid, has neither noise, but its L_d is biased by the
cache (docs/rendering.md, "The light volume as a control variate"). This estimator takes the cache as a control
variate and corrects it at one point, so it is unbiased and keeps most of the march's smoothness.

**Strata.** Per macrocell that the ray crosses with majorant mu > 0, its stretch [t_a, t_b] is cut into n equal
strata of length l no longer than ``STRATUM_VOXELS`` voxels and 1 / (STRATA_PER_DEPTH mu) (a partition fixed by
the medium and the ray); each stratum k is sampled at t_k = its start + u l with one jitter u per ray, so that
``sum_k l f(t_k)`` is an unbiased estimate of the integral of f along the ray.

**Transmittance to each point: residual ratio tracking** (Novak et al. 2014; the derivation in
:mod:`photon_fields.runtime.transport.residual_tracking`). The walk's strata are the tracker's: sigma_t(t_k),
looked up once per stratum (which also gives the albedo there), is the control's value at t_k, and the control is
linear between consecutive points of a run of occupied macrocells (constant before a run's first point and after
its last; until 2026-11-30 it was constant per stratum). The points depend on the jitter u and the medium only, so
the control is fixed before any event is drawn, and

    T^(t) = exp(-integral_0^t sigma_c) * prod_{events e < t} (1 - (sigma_t(e) - sigma_c(e)) / mu(e))

over events at ``RESIDUAL_BOOST`` times the majorant is an unbiased estimate of T(t). The linear control's residual
is 3-16x smaller in mean square than the constant one's over the embedded scenes' camera rays, which makes the
walk's W much less noisy at walls (1-spp efficiency +5-40 %; bench/README.md, "A linear control").

**The opaque rest.** Once the estimate T^(t_k) at a point falls below ``CAMERA_SWITCH`` (the forced walk's switch,
:mod:`photon_fields.runtime.transport.tracking`), the point's stratum is tracked to its end with the control
constant (chosen from what precedes t_k, so still independent of the events it weighs), and the rest of the ray
from there is one delta-tracking flight, whose real collision, if any, is one more candidate of weight T_c =
T^(stratum's end) (the transmittance estimate at the end becomes 0; an escape keeps T_c). The flight must start
at the stratum's end, not at t_k: the stratum's candidate already stands for all of it. Unbiased for the same
reason as the forced walk's rest: T_c is an unbiased estimate of T at the switch and independent of the flight,
which collides in dt with probability T(t_c -> t) sigma_t dt. A dense wall costs a flight of about one optical
depth instead of strata down to a few per cent.

**The estimator.** w_k = l sigma_t(t_k) T^(t_k) estimates, summed against f, the integral of T sigma_t f along the
ray (the pdf of delta tracking's first collision, unnormalised). With the light volume's delta-light direct light
D_lv (the ray marcher's, :mod:`photon_fields.runtime.transport.light_volume`; phase and fall-off at t_k) and one
index J drawn with probability |w_J| / sum |w_k| over the candidates (the strata and the rest's collision; a
reservoir of size one along the walk), W = sign(w_J) sum |w_k|:

    L_d = sum_k w_k a_k D_lv(x_k) + W a_J (NEE - D_lv)(x_J),    L_i = W a_J Q(x_J, d, g)

Both terms of L_d and L_i are unbiased for the path tracer's single-scattering and multiply-scattered light at
the first collision (given the walk, W a_J g(x_J) has mean sum_k w_k a_k g(x_k) for any g). ``PICKS``
reservoirs draw J_1 .. J_P from the same walk, and the correction and L_i are their mean, each point with its own
shadow ray and field query: the same mean, and the walk, which is most of the cost, serves P points. The reservoirs
share one random number u_k per candidate, shifted by q / P (mod 1) for reservoir q: each reservoir still sees
independent uniform numbers, so each pick has the single pick's distribution, but at every candidate the number of
reservoirs that take it is P p_k rounded up or down (p_k its acceptance probability), not binomial: the picks are
stratified over the walk's candidates and coincide less often than independent ones would. So the image converges
to the delta and forced estimators' (tests/runtime/wavefront/test_camera_estimators.py, with a light volume of
random values too). NEE includes the environment light, which D_lv does not hold: its single scattering is
estimated at x_J alone. The transmittance estimate T^ at the ray's end weighs the environment behind the volume.

Where the variance goes: the sum over strata replaces "where along the ray" by a stratified quadrature of a
smooth cached light; the correction's noise is W (NEE - D_lv), small where the cache is close (away from sharp
lit walls), and averaged over the ``PICKS`` points with L_i's field queries. Costs and figures:
docs/rendering.md, bench/README.md.

**The cache.** The light volume is filled on demand (a stratum that reads an unfilled cell marks it, the marked
cells are marched, those rays walked once more from the same random state: the same sums as with a filled
volume), and kept in the scene's cache, shared with the ray marcher (``camera_light_volume`` in
runtime/renderers/ray_marcher.py gives it to the renderers, which pass it here).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from photon_fields.runtime.borrowed import borrowed
from photon_fields.runtime.scene.lights import DIRECTIONAL
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.cell_grid import Grid, stencil
from photon_fields.runtime.transport.direct_light import sample_lights_batch
from photon_fields.runtime.transport.emitters import delta_light_direction
from photon_fields.runtime.transport.environment_map import EnvMap
from photon_fields.runtime.transport.light_volume import (
    LightVolume,
    fill_wanted,
    light_transmittance,
    prefetch_light_stencil,
    want_stencil,
)
from photon_fields.runtime.transport.macrocell_walk import enter_macrocell, leap_if_empty, step_macrocell
from photon_fields.runtime.transport.medium import (
    Medium,
    albedo_at,
    borrowed_medium,
    extinction_albedo_at,
    prefetch_scalar_stencil,
    worth_prefetching,
)
from photon_fields.runtime.transport.phase import hg_eval
from photon_fields.runtime.transport.residual_tracking import (
    close_run,
    constant_control_events,
    events_to_point,
    flight_collision,
    shadowed_light_batch,
    strata_in,
)
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import CAMERA_SWITCH, SHADOW_SWITCH, _sign, task_items, task_stride
from photon_fields.runtime.wavefront.batches import RenderCancelledError
from photon_fields.runtime.wavefront.depth_bounds import DepthBounds, ray_interval
from photon_fields.runtime.wavefront.rays import camera_ray, clip_to_box

STRATA_PER_DEPTH = 2.0
STRATUM_VOXELS = 2.0
STRATUM_BOX_FRACTION = 1.0 / 48.0
PICKS = 3
CORRECTION_SHADOW_BOOST = 1.0
RESIDUAL_BOOST = 2.0
#: Status of a work item (the values of first_interaction's MISSED_BOX, ESCAPED, INTERACTED).
_MISSED_BOX, _ESCAPED, _INTERACTED = 0, 1, 2


@dataclass
class MarchedItems:
    """Per work item of one batch, structure of arrays: per pick p the picked point ``x`` (P, 3, n), the albedo
    there (P, 3, n), its weight sign(w_J) W / P (P, n) and ``cached_at_pick`` = D_lv(x_J) (P, 3, n); per item the
    ray direction ``d`` (3, n), the random state after the walk (n,), the strata's sum ``cached`` =
    sum_k w_k a_k D_lv(x_k) (3, n), ``status`` (n,) and the transmittance estimate to the ray's end ``transmit``
    (n,)."""

    x: np.ndarray
    d: np.ndarray
    albedo: np.ndarray
    weight: np.ndarray
    rng: np.ndarray
    cached: np.ndarray
    cached_at_pick: np.ndarray
    status: np.ndarray
    transmit: np.ndarray

    @classmethod
    def empty(cls, n: int, picks: int) -> MarchedItems:
        return cls(np.empty((picks, 3, n)), np.empty((3, n)), np.empty((picks, 3, n)), np.empty((picks, n)),
                   np.empty(n, np.uint64), np.empty((3, n)), np.empty((picks, 3, n)), np.empty(n, np.uint8),
                   np.empty(n))

    def put(self, idx: np.ndarray, other: MarchedItems) -> None:
        for name in ("x", "d", "albedo", "weight", "rng", "cached", "cached_at_pick", "status", "transmit"):
            getattr(self, name)[..., idx] = getattr(other, name)


@njit(cache=True, inline="always")
def cached_direct(kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, ray_phase: np.ndarray,
                  lv: np.ndarray, wanted: np.ndarray, grid: Grid, x: float, y: float, z: float, dx: float, dy: float,
                  dz: float) -> tuple[float, float, float, bool]:
    """D_lv at x for a ray along d: every delta light's phase, fall-off, colour and cached transmittance; False
    (and the unfilled corners marked, :func:`want_stencil`) when a cell it reads is not filled yet.
    ``ray_phase``: the phase of each directional light for this ray (the same at every point of it)."""
    ci, cj, ck, fx, fy, fz = stencil(grid, x, y, z)
    r = gg = b = 0.0
    ok = True
    for k in range(kind.shape[0]):
        lx, ly, lz, scale, _ = delta_light_direction(kind[k], vec[k], x, y, z)
        if scale <= 0.0:
            continue
        tl = light_transmittance(lv, k, ci, cj, ck, fx, fy, fz)
        if tl < 0.0:
            want_stencil(lv, wanted, k, ci, cj, ck)
            ok = False
            continue
        ph = ray_phase[k] if kind[k] == DIRECTIONAL else hg_eval(g, dx * lx + dy * ly + dz * lz)
        c = ph * scale * tl
        r += c * rgb[k, 0]
        gg += c * rgb[k, 1]
        b += c * rgb[k, 2]
    return r, gg, b, ok


@njit(cache=True, inline="always")
def _score(kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, ray_phase: np.ndarray, lv: np.ndarray,
           wanted: np.ndarray, grid: Grid, x: float, y: float, z: float, dx: float, dy: float, dz: float, a0: float,
           a1: float, a2: float, w: float, w_abs: float, m0: float, m1: float, m2: float, i: int, state: np.uint64,
           out_x: np.ndarray, out_a: np.ndarray, at_pick: np.ndarray, out_w: np.ndarray,
           missed: np.ndarray) -> tuple[float, float, float, float, np.uint64]:
    """One candidate of weight w at x (albedo a): its share w a D_lv(x) added to the strata's sum (m0, m1, m2) and
    its turn in each pick's reservoir (kept with probability |w| / the running sum of |w|, written to item i's pick,
    ``out_w`` its w until the walk's end; one random number for all the reservoirs, shifted by q / P for reservoir q:
    the module docstring): (the sum, the sum of |w|, state). A cache cell not filled yet marks the
    item ``missed``."""
    l0, l1, l2, ok = cached_direct(kind, vec, rgb, g, ray_phase, lv, wanted, grid, x, y, z, dx, dy, dz)
    if not ok:
        missed[i] = True
    if w != 0.0:
        w_abs += abs(w)
        state, u = next_float(state)
        step = 1.0 / out_w.shape[0]
        for q in range(out_w.shape[0]):
            v = u + q * step
            if v >= 1.0:
                v -= 1.0
            if v * w_abs < abs(w):
                out_x[q, 0, i], out_x[q, 1, i], out_x[q, 2, i] = x, y, z
                out_a[q, 0, i], out_a[q, 1, i], out_a[q, 2, i] = a0, a1, a2
                at_pick[q, 0, i], at_pick[q, 1, i], at_pick[q, 2, i] = l0, l1, l2
                out_w[q, i] = w
    return m0 + w * a0 * l0, m1 + w * a1 * l1, m2 + w * a2 * l2, w_abs, state


@njit(cache=True)
def _march_items(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, eye: np.ndarray,
                 origin: np.ndarray, du: np.ndarray, dv: np.ndarray, width: int, n_pixels: int, work: np.ndarray,
                 s0: np.uint64, near: np.ndarray, far: np.ndarray, tile: int,
                 walk: tuple[float, float, float, float], lv: np.ndarray, wanted: np.ndarray, grid: Grid,
                 out_x: np.ndarray, out_d: np.ndarray, out_a: np.ndarray, out_w: np.ndarray, out_rng: np.ndarray,
                 cached: np.ndarray, at_pick: np.ndarray, status: np.ndarray, transmit: np.ndarray, missed: np.ndarray,
                 ray_phase: np.ndarray, prefetch: bool, lo: int, hi: int) -> None:
    """Items lo .. hi - 1 of :func:`_march`, serially (the walk of the module docstring). ``walk``: the longest
    stratum (world units), strata per majorant optical depth, the switch to the opaque rest, the residual events'
    boost (:func:`march_camera_rays`). ``ray_phase``: the task's scratch, one value per light (the caller's, so that
    it can be borrowed here)."""
    voxel, per_depth, switch, boost = walk
    m = borrowed_medium(m)  # no reference counting in the loops below (runtime/borrowed.py)
    kind, vec, rgb, lv, wanted = borrowed(kind), borrowed(vec), borrowed(rgb), borrowed(lv), borrowed(wanted)
    out_x, out_a, at_pick, out_w = borrowed(out_x), borrowed(out_a), borrowed(at_pick), borrowed(out_w)
    missed, ray_phase = borrowed(missed), borrowed(ray_phase)
    for i in range(lo, hi):
        dx, dy, dz, p, s = camera_ray(origin, du, dv, width, n_pixels, work[i], s0)
        hit, ox, oy, oz, tmax = clip_to_box(m, eye[0], eye[1], eye[2], dx, dy, dz)
        transmit[i] = 1.0
        for q in range(out_w.shape[0]):
            out_w[q, i] = 0.0
        cached[0, i] = cached[1, i] = cached[2, i] = 0.0
        if not hit:
            status[i] = _MISSED_BOX
            continue
        status[i] = _ESCAPED
        t, tmax = ray_interval(near, far, tile, width, p, eye, ox, oy, oz, dx, dy, dz, tmax)
        if not t < tmax:
            continue
        for k in range(kind.shape[0]):
            if kind[k] == DIRECTIONAL:
                ray_phase[k] = hg_eval(g, -(dx * vec[k, 0] + dy * vec[k, 1] + dz * vec[k, 2]))
        s, u = next_float(s)  # the strata's jitter
        sx, sy, sz = _sign(dx), _sign(dy), _sign(dz)
        ivx = 1.0 / dx if sx != 0 else math.inf
        ivy = 1.0 / dy if sy != 0 else math.inf
        ivz = 1.0 / dz if sz != 0 else math.inf
        octant = (sx >= 0) + 2 * (sy >= 0) + 4 * (sz >= 0)
        ix, iy, iz, nx_t, ny_t, nz_t = enter_macrocell(m, ox, oy, oz, dx, dy, dz, ivx, ivy, ivz, t)
        tau = -1.0
        ratio = 1.0  # the residual tracker's product; the transmittance estimate is exp(-tau_c) ratio
        tau_c = 0.0
        w_abs = 0.0
        m0 = m1 = m2 = 0.0
        rest = -1.0  # >= 0: the transmittance estimate where the rest's flight began
        done = False
        # The last point's tail, not tracked yet: [p_t, p_b] in a macrocell of majorant p_mu, sigma_t p_s at p_t.
        pend = False
        p_t = p_b = p_mu = p_s = 0.0
        while not done:
            leapt, inside, t, ix, iy, iz, nx_t, ny_t, nz_t = leap_if_empty(m, ox, oy, oz, dx, dy, dz, ivx, ivy, ivz,
                                                                          octant, ix, iy, iz, t, nx_t, ny_t, nz_t)
            pend, tau, ratio, dc, s = close_run(m, ox, oy, oz, dx, dy, dz, leapt, ix, iy, iz, pend, p_t, p_b,
                                                boost * p_mu, p_s, tau, ratio, s)
            tau_c += dc
            if leapt:
                if not inside or t >= tmax:
                    break
                continue
            t_end = min(nx_t, ny_t, nz_t, tmax)
            mu = m.majorant[ix, iy, iz]
            if mu > 0.0 and t_end > t and rest < 0.0:
                n, length = strata_in(t, t_end, mu, per_depth, voxel)
                for j in range(n):
                    a = t + j * length
                    b = t_end if j == n - 1 else a + length
                    tk = a + u * (b - a)
                    x, y, z = ox + tk * dx, oy + tk * dy, oz + tk * dz
                    if prefetch:  # the next stratum's point: its loads start under this one's work (prefetch.py)
                        qx, qy, qz = x + length * dx, y + length * dy, z + length * dz
                        prefetch_scalar_stencil(m, qx, qy, qz)
                        prefetch_light_stencil(lv, grid, qx, qy, qz)
                    sc, a0, a1, a2 = extinction_albedo_at(m, x, y, z)
                    tau, ratio, dc, s = events_to_point(m, ox, oy, oz, dx, dy, dz, a, tk, boost * mu, sc, pend, p_t,
                                                        p_b, boost * p_mu, p_s, tau, ratio, s)
                    tau_c += dc
                    tr = math.exp(-tau_c) * ratio
                    if sc > 0.0:
                        m0, m1, m2, w_abs, s = _score(kind, vec, rgb, g, ray_phase, lv, wanted, grid, x, y, z, dx,
                                                      dy, dz, a0, a1, a2, (b - a) * sc * tr, w_abs, m0, m1, m2, i, s,
                                                      out_x, out_a, at_pick, out_w, missed)
                    pend, p_t, p_b, p_mu, p_s = True, tk, b, mu, sc
                    if tr < switch:  # the stratum's tail with the point's value, then the rest by the flight below
                        tau, ratio, dc, s = constant_control_events(m, ox, oy, oz, dx, dy, dz, tk, b, boost * mu, sc,
                                                                    tau, ratio, s)
                        tau_c += dc
                        rest = math.exp(-tau_c) * ratio
                        t = b
                        pend = False
                        break
            if mu > 0.0 and t_end > t and rest >= 0.0:
                tau, tc, s = flight_collision(m, ox, oy, oz, dx, dy, dz, t, t_end, mu, tau, s)
                if tc < math.inf:
                    x, y, z = ox + tc * dx, oy + tc * dy, oz + tc * dz
                    a0, a1, a2 = albedo_at(m, x, y, z)
                    m0, m1, m2, w_abs, s = _score(kind, vec, rgb, g, ray_phase, lv, wanted, grid, x, y, z, dx,
                                                  dy, dz, a0, a1, a2, rest, w_abs, m0, m1, m2, i, s, out_x, out_a,
                                                  at_pick, out_w, missed)
                    rest = 0.0
                    done = True
            if done or t_end >= tmax:
                break
            t = t_end
            ix, iy, iz, nx_t, ny_t, nz_t, inside = step_macrocell(m, ox, oy, oz, ivx, ivy, ivz, sx, sy, sz, ix, iy,
                                                                  iz, nx_t, ny_t, nz_t)
            if not inside:
                break
        if pend:  # the last point's tail, for the transmittance to the ray's end
            tau, ratio, dc, s = constant_control_events(m, ox, oy, oz, dx, dy, dz, p_t, p_b, boost * p_mu, p_s, tau,
                                                        ratio, s)
            tau_c += dc
        transmit[i] = rest if rest >= 0.0 else math.exp(-tau_c) * ratio
        cached[0, i], cached[1, i], cached[2, i] = m0, m1, m2
        if w_abs > 0.0:
            status[i] = _INTERACTED
            for q in range(out_w.shape[0]):  # each pick's sign(w_J) W / P
                out_w[q, i] = (w_abs if out_w[q, i] > 0.0 else -w_abs) / out_w.shape[0]
            out_d[0, i], out_d[1, i], out_d[2, i] = dx, dy, dz
            out_rng[i] = s


@njit(cache=True, parallel=True)
def _march(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, g: float, eye: np.ndarray,
           origin: np.ndarray, du: np.ndarray, dv: np.ndarray, width: int, n_pixels: int, work: np.ndarray,
           seed: int, near: np.ndarray, far: np.ndarray, tile: int, walk: tuple[float, float, float, float],
           lv: np.ndarray, wanted: np.ndarray, grid: Grid, out_x: np.ndarray, out_d: np.ndarray, out_a: np.ndarray,
           out_w: np.ndarray, out_rng: np.ndarray, cached: np.ndarray, at_pick: np.ndarray, status: np.ndarray,
           transmit: np.ndarray, prefetch: bool) -> np.ndarray:
    n = work.shape[0]
    missed = np.zeros(n, np.bool_)
    per_task = task_items(n)
    tasks = (n + per_task - 1) // per_task
    stride = task_stride(tasks)
    s0 = np.uint64(seed)
    for task in prange(tasks):
        b = (task * stride) % tasks  # golden-ratio order: each thread gets dense and empty blocks alike
        _march_items(m, kind, vec, rgb, g, eye, origin, du, dv, width, n_pixels, work, s0, near, far, tile, walk,
                     lv, wanted, grid, out_x, out_d, out_a, out_w, out_rng, cached, at_pick, status, transmit, missed,
                     np.empty(kind.shape[0]), prefetch, b * per_task, min(n, (b + 1) * per_task))
    return missed


def longest_stratum(scene: Scene) -> float:
    """The longest stratum of the walk on ``scene``'s volume, in world units (``STRATUM_VOXELS``,
    ``STRATUM_BOX_FRACTION``)."""
    return max(float(scene.volume.voxel_size) * STRATUM_VOXELS, STRATUM_BOX_FRACTION)


def correction_nee(scene: Scene, m: Medium, lights: tuple[np.ndarray, np.ndarray, np.ndarray, EnvMap], x: np.ndarray,
                   d: np.ndarray, states: np.ndarray, one_light: bool) -> np.ndarray:
    """NEE at the picks x (3, n) reached along d, radiance (3, n): the first-interaction renderers' light sampling
    (environment without MIS), the shadow rays by residual ratio tracking over strata as the walk's, events at
    ``CORRECTION_SHADOW_BOOST`` times the majorant (module docstring); advances ``states``."""
    kind, vec, rgb, env = lights
    samples, weight = sample_lights_batch(kind, vec, rgb, env, scene.g, x, d, states, False, one_light)
    return shadowed_light_batch(m, x, samples, weight, states, float(STRATA_PER_DEPTH), longest_stratum(scene),
                                float(CORRECTION_SHADOW_BOOST), float(SHADOW_SWITCH))


def march_camera_rays(scene: Scene, m: Medium, lv: LightVolume, work: np.ndarray, seed: int, bounds: DepthBounds,
                      cancel: object = None) -> MarchedItems:
    """Stage 1 of the marched estimator for work items ``work`` (``sample * pixels + pixel``; the camera ray of
    random stream w under ``seed``, as every renderer's): the walk of the module docstring per item. Rays that read
    unfilled light-volume cells mark them; the cells are marched and those rays walked again from the same random
    state, so the result is the one a filled volume gives. ``cancel`` (a callable or None) is asked during the
    fill; True stops with :class:`RenderCancelledError`."""
    kind, vec, rgb = scene.packed_lights()
    cam = scene.camera
    origin, du, dv = cam.image_plane()
    eye = np.ascontiguousarray(cam.eye, dtype=np.float64)
    walk = (longest_stratum(scene), float(STRATA_PER_DEPTH), float(CAMERA_SWITCH), float(RESIDUAL_BOOST))

    def run(items: np.ndarray) -> tuple[MarchedItems, np.ndarray]:
        out = MarchedItems.empty(items.shape[0], PICKS)
        missed = _march(m, kind, vec, rgb, float(scene.g), eye, origin, du, dv, cam.width, cam.width * cam.height,
                        items, int(seed), bounds.near, bounds.far, bounds.tile, walk, lv.values, lv.wanted, lv.grid,
                        out.x, out.d, out.albedo, out.weight, out.rng, out.cached, out.cached_at_pick, out.status,
                        out.transmit, worth_prefetching(m))
        return out, missed

    items, missed = run(work)
    if missed.any():
        idx = np.flatnonzero(missed)
        if not fill_wanted(m, kind, vec, lv, cancel):  # type: ignore[arg-type]
            raise RenderCancelledError(f"cancelled while filling the light volume for {idx.size} rays")
        again, still = run(work[idx])
        if still.any():
            raise RuntimeError("marched camera: a light-volume cell its rays read was not filled")  # cannot happen
        items.put(idx, again)
    return items


class CachedLight(NamedTuple):
    """The interacting items' light-volume terms: ``strata`` = sum_k w_k a_k D_lv(x_k) (3, rays), the control
    variate's integral, and ``at_pick`` = D_lv(x_J) (3, picks), what the correction subtracts at each pick."""

    strata: np.ndarray
    at_pick: np.ndarray


class MarchedPicks(NamedTuple):
    """One batch's picks, structure of arrays, pick-major: the ``rays`` interacting rays' first picks in work-item
    order, then their second picks, and so on (so each run of ``rays`` entries has distinct pixels). ``pixel``
    (n,), ``x``, ``d``, ``albedo`` (3, n), ``rng`` (n,): the walk's state for the first pick, salted copies of it for
    the others (their own shadow rays and bounces), ``weight`` (n,): sign(w_J) W / P."""

    pixel: np.ndarray
    x: np.ndarray
    d: np.ndarray
    albedo: np.ndarray
    rng: np.ndarray
    weight: np.ndarray
    rays: int


#: Salt of the random streams of the second and later picks: pick q's state is the ray's xor q times this (mod 2^64).
_PICK_SALT = 0xD1B54A32D192ED03


@njit(cache=True, parallel=True)
def _pack_picks(idx: np.ndarray, start: int, n_pixels: int, x: np.ndarray, d: np.ndarray, albedo: np.ndarray,
                weight: np.ndarray, rng: np.ndarray, at_pick: np.ndarray, salts: np.ndarray, o_pixel: np.ndarray,
                o_x: np.ndarray, o_d: np.ndarray, o_albedo: np.ndarray, o_rng: np.ndarray, o_weight: np.ndarray,
                o_at_pick: np.ndarray) -> None:
    """:func:`compact_marched`'s copies in one pass: item ``idx[j]``'s pick q to entry q k + j (k = len(idx))."""
    k = idx.shape[0]
    for j in prange(k):
        i = idx[j]
        px = (start + i) % n_pixels
        for q in range(x.shape[0]):
            o = q * k + j
            o_pixel[o] = px
            o_rng[o] = rng[i] ^ salts[q]
            o_weight[o] = weight[q, i]
            for c in range(3):
                o_x[c, o] = x[q, c, i]
                o_d[c, o] = d[c, i]
                o_albedo[c, o] = albedo[q, c, i]
                o_at_pick[c, o] = at_pick[q, c, i]


def compact_marched(items: MarchedItems, start: int, n_pixels: int) -> tuple[MarchedPicks, CachedLight]:
    """The interacting items' picks (:class:`MarchedPicks`) and cached light (the strata's sum is 0 on every other
    item), copied in one parallel pass (numpy's takes, tiles and transposes took ~3x as long: bench/README.md)."""
    idx = np.flatnonzero(items.status == _INTERACTED)
    picks, k = items.x.shape[0], idx.size
    salts = np.array([_PICK_SALT * q % 2**64 for q in range(picks)], dtype=np.uint64)
    n = picks * k
    flat = MarchedPicks(np.empty(n, np.int64), np.empty((3, n)), np.empty((3, n)), np.empty((3, n)),
                        np.empty(n, np.uint64), np.empty(n), k)
    at_pick = np.empty((3, n))
    _pack_picks(idx, int(start), int(n_pixels), items.x, items.d, items.albedo, items.weight, items.rng,
                items.cached_at_pick, salts, flat.pixel, flat.x, flat.d, flat.albedo, flat.rng, flat.weight, at_pick)
    return flat, CachedLight(items.cached[:, idx], at_pick)


def correction_direct(nee: np.ndarray, cached: CachedLight) -> np.ndarray:
    """(NEE - D_lv)(x_J) per pick (3, n): what the strata's cached sum misses there (the module docstring)."""
    return nee - cached.at_pick
