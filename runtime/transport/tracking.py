"""Free-flight sampling and transmittance estimation in heterogeneous media.

- **Delta tracking** (Woodcock et al. 1965; the paper's [51]) samples the distance to the next real
  collision: tentative collisions are drawn with the majorant, and accepted with probability
  ``sigma_t(x) / majorant``. The probability of escaping the medium equals the transmittance.
- **Ratio tracking** (Novak et al. 2014) estimates transmittance on shadow rays: the same tentative
  collisions, but the estimate is multiplied by ``1 - sigma_t / majorant`` instead of stopping.
  Once the estimate falls below ``RR_THRESHOLD`` it is Russian-rouletted (kept with probability 1/2,
  doubled), which keeps it unbiased while ending long shadow rays through dense media early.

- **Resampled collision** (the camera estimator ``forced`` of :mod:`runtime.wavefront.first_interaction`):
  the ratio-tracking walk, which also scores every tentative collision t_j with
  ``w_j = T_j sigma_t(t_j) / majorant`` (T_j: the walk's transmittance estimate before t_j) and keeps one of
  them with probability ``w_j / sum_k w_k`` (a weighted reservoir of size one). Tentative collisions are a
  Poisson process of rate majorant, so ``E[sum_j w_j f(t_j)] = integral T(t) sigma_t(t) f(t) dt`` for any f:
  ``W = sum_j w_j`` estimates the collision probability 1 - T(tmax), and W f(t_J) at the kept t_J estimates
  the integral with one evaluation of f. Derivation and measurements: docs/rendering.md.

  **The rest of an opaque ray** (:func:`camera_collision`, and shadow rays with ``switch``: :func:`ratio_track`):
  once the walk's transmittance estimate T_c falls below ``CAMERA_SWITCH`` (shadow rays: ``SHADOW_SWITCH``) at
  t_c, the rest of the ray is one delta-tracking flight from t_c, and a real collision t' there
  is one more candidate of weight T_c (T becomes 0); an escape keeps T = T_c. Given the walk up to t_c, the flight
  collides in [t, t + dt] with probability T(t_c -> t) sigma_t(t) dt, so E[T_c 1{t' in dt} f(t')] is the rest's
  share T(t) sigma_t(t) f(t) dt of the integral (T_c estimates T(t_c) without bias, independently of the flight),
  and the estimator stays unbiased. Where the walk would have gone on by ratio tracking and Russian roulette to
  a few optical depths, the flight stops after about one: dense media cost less, and for a ray that is opaque
  anyway the candidate's weight is nearly certain, so the noise barely changes. A shadow ray's rest is the same
  flight with the track-length estimate: T_c if it escapes, 0 at a real collision; its mean is T_c times the rest's
  transmittance, so the estimate of T(tmax) stays unbiased.

**A boosted majorant** (shadow rays, ``boost`` > 1): ratio tracking stays unbiased with any majorant at least
sigma_t, and a larger one lowers its variance. With tentative collisions at rate c mu over a homogeneous stretch
of extinction sigma and length L, the estimate prod (1 - sigma / (c mu)) over N ~ Poisson(c mu L) has mean
exp(-sigma L) and second moment exp(-2 sigma L + sigma^2 L / (c mu)): its relative variance exp(tau^2 / (c mu L))
- 1 falls as 1 / c while the lookups grow as c. Below the switch the rest's flight uses the plain majorant (a
flight's distribution does not depend on it; the rate may change at any point of a Poisson process).

All walk the majorant grid of :mod:`runtime.transport.medium` with a 3D DDA (Amanatides & Woo 1987) and use the
macrocell's local majorant; from an empty macrocell they leap over the cube of empty macrocells ahead of it
(``Medium.leap``), so empty space costs a few steps per ray. Tentative collisions are a Poisson process whose rate
is the majorant, piecewise constant along the ray: one exponential optical depth is drawn per tentative collision
and spent across macrocells (inversion of the piecewise-linear majorant optical depth), so a macrocell the ray
only crosses costs no random number. Boundary distances are computed in closed form from each plane's
index, and empty macrocells draw no random numbers, so leaping or stepping cell by cell gives the same samples
bit for bit (``build_medium(..., leap=False)`` steps; the tests compare both).

The kernels are inlined into their callers (``inline="always"``): numba passes the medium's arrays to a
compiled call with reference counting, which cost more than a short walk. After editing them, clear the
``__pycache__`` folders: numba's cache does not recompile a caller in another module when an inlined kernel
changes.

Kernels take one ray and return ``(value, rng_state)`` (``resampled_collision``: ``(t, W, T, rng_state)``);
``delta_track_batch``/``ratio_track_batch`` run them over structure-of-arrays ray batches (``o``/``d`` of
shape (3, n)). The interval [tmin, tmax] is clipped to the volume box first: outside it the medium is empty
(lookups clamp at the border, so an unclipped ray would otherwise see the border voxels extended to
infinity). :mod:`runtime.transport.tracking_numpy_baseline` is the
vectorized numpy baseline they are benchmarked and cross-checked against.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.transport.medium import Medium, borrowed_medium, extinction_at, intersect_box
from photon_fields.runtime.transport.rng import next_float

RR_THRESHOLD = 0.05
#: Shadow rays' (:func:`ratio_track` from NEE) transmittance estimate below which the rest of the ray is one
#: delta-tracking flight (module docstring): 0.3 made NEE 5-9 % cheaper at 512x512 on the embedded scenes for
#: 0.1-0.8 % more noise in L_d (bench/README.md); 0.5 saved 10-13 % for 0.2-2.9 % more.
SHADOW_SWITCH = 0.3
#: NEE's shadow rays (every renderer's) draw their tentative collisions at this many times the majorant until
#: ``SHADOW_SWITCH`` (module docstring, "a boosted majorant"). At 256x256, 1 spp, 2 made the neural frame's
#: error-squared times time 1.12x better on vortex, 1.27x on shell, 1.05x on blobs, level on head, and the path
#: tracer's 1.05x / 1.14x on vortex / shell; 4 was 0.94x on head. It costs NEE ~1.4x and a 512x512 frame with
#: denoising 7-9 % (bench/README.md).
SHADOW_BOOST = 2.0
#: The camera walk's transmittance estimate below which it finishes the ray by delta tracking (module docstring,
#: "the rest of an opaque ray"): 0.3 made the 512x512 first interactions 4-11 % cheaper on the embedded scenes
#: (alternated A/B) with the 1-spp frames' noise within 0.5 % (bench/README.md); 0.6 added 2-4 % noise on blobs
#: and vortex.
CAMERA_SWITCH = 0.3
#: Items per task of the parallel kernels whose per-item work inlines a tracking walk: ``prange`` runs over tasks
#: and each task calls a serial kernel over its items. numba's parfor passes then see a loop body of one call,
#: not the inlined walk, which cuts those kernels' compile time several-fold; the call costs nothing per item.
TASK_ITEMS = 256
#: A kernel given few items (the ray marcher's rays re-marched after a light-volume fill: a few hundred) splits
#: them into at least this many tasks, fewer items each (:func:`task_items`), so that every thread gets some.
MIN_TASKS = 64
_GOLDEN = 0.6180339887498949


@njit(cache=True)
def task_items(n: int) -> int:
    """Items per task for ``n`` items: :data:`TASK_ITEMS`, or fewer so that there are :data:`MIN_TASKS` tasks."""
    return max(1, min(TASK_ITEMS, n // MIN_TASKS))


@njit(cache=True)
def task_stride(tasks: int) -> int:
    """A stride coprime with ``tasks``, near ``tasks`` / golden ratio: task t of a ``prange`` over ``tasks`` then
    works on block ``(t * stride) % tasks`` of the items (a permutation of the blocks). numba's threading layer
    gives each thread one contiguous range of the ``prange`` (a static schedule), so when the costly items sit
    together (the rays through the dense half of an image) one thread gets them all; the golden-ratio stride
    spreads every contiguous range of tasks evenly over the items."""
    if tasks <= 2:
        return 1
    s = max(1, int(tasks * _GOLDEN))
    while math.gcd(s, tasks) != 1:
        s += 1
    return s
_DELTA, _RATIO, _RESAMPLE, _RECORD = 0, 1, 2, 3


@njit(cache=True, inline="always")
def _cell_index(p: float, bmin: float, cells_per_unit: float, n: int) -> int:
    """Index of the macrocell holding coordinate ``p`` on one axis, clamped to the grid."""
    return min(max(int(math.floor((p - bmin) * cells_per_unit)), 0), n - 1)


@njit(cache=True, inline="always")
def macrocell_of(m: Medium, x: float, y: float, z: float) -> tuple[int, int, int]:
    """Indices of the macrocell holding the point (clamped to the grid)."""
    cx, cy, cz = m.majorant.shape
    return (_cell_index(x, m.bmin[0], cx / m.bsize[0], cx), _cell_index(y, m.bmin[1], cy / m.bsize[1], cy),
            _cell_index(z, m.bmin[2], cz / m.bsize[2], cz))


@njit(cache=True, inline="always")
def majorant_at(m: Medium, x: float, y: float, z: float) -> float:
    """The majorant of the macrocell holding the point (the rate of the tentative collisions there)."""
    i, j, k = macrocell_of(m, x, y, z)
    return m.majorant[i, j, k]


@njit(cache=True, inline="always")
def _plane_distance(o: float, inv_d: float, bmin: float, cell_size: float, plane: int) -> float:
    """Ray distance to the macrocell boundary plane ``plane`` (0 .. n) of one axis. In closed form from the
    plane's index, so that every walk, leaping or not, computes the same distance for the same plane."""
    return (bmin + plane * cell_size - o) * inv_d


@njit(cache=True, inline="always")
def _next_boundary(o: float, inv_d: float, bmin: float, cell_size: float, cell: int, step: int) -> float:
    """Distance to where the ray leaves macrocell ``cell`` on one axis (inf if it does not move on it)."""
    if step > 0:
        return _plane_distance(o, inv_d, bmin, cell_size, cell + 1)
    if step < 0:
        return _plane_distance(o, inv_d, bmin, cell_size, cell)
    return math.inf


@njit(cache=True, inline="always")
def _cube_exit(o: float, inv_d: float, bmin: float, cell_size: float, cell: int, step: int, r: int) -> float:
    """Distance to where the ray leaves the ``r`` cells from ``cell`` on in its direction on one axis."""
    if step > 0:
        return _plane_distance(o, inv_d, bmin, cell_size, cell + r)
    if step < 0:
        return _plane_distance(o, inv_d, bmin, cell_size, cell - r + 1)
    return math.inf


@njit(cache=True, inline="always")
def _within(i: int, cell: int, step: int, r: int) -> int:
    """``i`` clamped to the ``r`` cells from ``cell`` on in direction ``step`` (0 counts as forward)."""
    if step < 0:
        return min(max(i, cell - r + 1), cell)
    return min(max(i, cell), cell + r - 1)


@njit(cache=True, inline="always")
def _sign(d: float) -> int:
    return 1 if d > 0.0 else (-1 if d < 0.0 else 0)


@njit(cache=True, inline="always")
def empty_run(m: Medium, x: float, y: float, z: float, dx: float, dy: float, dz: float) -> float:
    """How far the ray from (x, y, z) along d stays in empty space: the distance to where it leaves the cube of
    empty macrocells cornered at the point's macrocell towards the ray's octant (``Medium.leap``), 0 if that
    macrocell is not empty. sigma_t is exactly 0 there (the majorant bounds the trilinear stencil), so a
    quadrature along the ray may skip its samples in [0, empty_run) without changing its sum."""
    ix, iy, iz = macrocell_of(m, x, y, z)
    return empty_run_in(m, ix, iy, iz, x, y, z, dx, dy, dz)


@njit(cache=True, inline="always")
def empty_run_in(m: Medium, ix: int, iy: int, iz: int, x: float, y: float, z: float, dx: float, dy: float,
                 dz: float) -> float:
    """:func:`empty_run` for a point whose macrocell (``macrocell_of``) the caller has already, for its own lookups
    there too."""
    cx, cy, cz = m.majorant.shape
    bx, by, bz = m.bmin[0], m.bmin[1], m.bmin[2]
    sx, sy, sz = _sign(dx), _sign(dy), _sign(dz)
    r = int(m.leap[(sx >= 0) + 2 * (sy >= 0) + 4 * (sz >= 0), ix, iy, iz])
    if r == 0:
        return 0.0
    ex = _cube_exit(x, 1.0 / dx if sx != 0 else math.inf, bx, m.bsize[0] / cx, ix, sx, r)
    ey = _cube_exit(y, 1.0 / dy if sy != 0 else math.inf, by, m.bsize[1] / cy, iy, sy, r)
    ez = _cube_exit(z, 1.0 / dz if sz != 0 else math.inf, bz, m.bsize[2] / cz, iz, sz, r)
    return max(0.0, min(ex, ey, ez))


@njit(cache=True, inline="always")
def _track(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
           tmax: float, state: np.uint64, mode: int, floor: float = 0.0, switch: float = 0.0,
           boost: float = 1.0) -> tuple[float, float, float, np.uint64]:
    """Shared walk, returning (t, W, T, state).

    ``switch`` (modes _RESAMPLE and _RATIO): below this transmittance estimate, the rest of the ray by delta
    tracking (module docstring). ``boost`` (mode _RATIO): tentative collisions at ``boost`` times the majorant
    until the switch (module docstring, "a boosted majorant"). mode _DELTA: t = the real-collision distance (inf
    on escape). mode _RECORD: delta tracking that also stops at a null collision where sigma_t > 0 if its
    acceptance draw u is below ``floor`` (:func:`record_track`); W = 1 at a real collision, 0 at such a null one.
    mode _RATIO: T = the transmittance estimate over [tmin, tmax]. mode _RESAMPLE: the ratio-tracking walk that
    also keeps one tentative collision t (inf if none scored) with W = sum of the scores (module docstring) and T
    its transmittance estimate.

    The walk: a 3D DDA over the majorant grid; in a macrocell with majorant > 0 the optical depth to the next
    tentative collision is spent (module docstring); from an empty macrocell it leaps over the cube of empty macrocells
    ahead of it (``Medium.leap``). Inlined into every caller: a call passing the medium's arrays costs more
    than a short walk. (Its DDA is written out here, not through the helpers above that the marched camera walk
    uses: calling them inline made every kernel that inlines this walk compile 35-65 % slower.)"""
    t0, t1 = intersect_box(m, ox, oy, oz, dx, dy, dz)
    tmin = max(tmin, t0)
    tmax = min(tmax, t1)
    kept = math.inf
    w_sum = 0.0
    tr = 1.0
    if tmin >= tmax:
        return kept, w_sum, tr, state
    cx, cy, cz = m.majorant.shape
    bx, by, bz = m.bmin[0], m.bmin[1], m.bmin[2]
    hx, hy, hz = m.bsize[0] / cx, m.bsize[1] / cy, m.bsize[2] / cz
    gx, gy, gz = cx / m.bsize[0], cy / m.bsize[1], cz / m.bsize[2]
    sx, sy, sz = _sign(dx), _sign(dy), _sign(dz)
    ivx = 1.0 / dx if sx != 0 else math.inf
    ivy = 1.0 / dy if sy != 0 else math.inf
    ivz = 1.0 / dz if sz != 0 else math.inf
    t = tmin
    ix = _cell_index(ox + t * dx, bx, gx, cx)
    iy = _cell_index(oy + t * dy, by, gy, cy)
    iz = _cell_index(oz + t * dz, bz, gz, cz)
    nx_t = _next_boundary(ox, ivx, bx, hx, ix, sx)
    ny_t = _next_boundary(oy, ivy, by, hy, iy, sy)
    nz_t = _next_boundary(oz, ivz, bz, hz, iz, sz)
    octant = (sx >= 0) + 2 * (sy >= 0) + 4 * (sz >= 0)
    tau = -1.0  # majorant optical depth left to the next tentative collision (< 0: not drawn yet)
    rest = False  # past ``switch``: the rest of the ray by delta tracking
    while True:
        r = int(m.leap[octant, ix, iy, iz])
        if r >= 2:
            # The r^3 macrocells from this one on towards the ray's octant are empty: go to where the ray leaves
            # them. The index on the exit axis is known; on the others the cube bounds the one found from the
            # position.
            ex = _cube_exit(ox, ivx, bx, hx, ix, sx, r)
            ey = _cube_exit(oy, ivy, by, hy, iy, sy, r)
            ez = _cube_exit(oz, ivz, bz, hz, iz, sz, r)
            t = min(ex, ey, ez)
            if t >= tmax:
                break
            if ex <= ey and ex <= ez:
                iy = _within(_cell_index(oy + t * dy, by, gy, cy), iy, sy, r)
                iz = _within(_cell_index(oz + t * dz, bz, gz, cz), iz, sz, r)
                ix += sx * r
                if ix < 0 or ix >= cx:
                    break
            elif ey <= ez:
                ix = _within(_cell_index(ox + t * dx, bx, gx, cx), ix, sx, r)
                iz = _within(_cell_index(oz + t * dz, bz, gz, cz), iz, sz, r)
                iy += sy * r
                if iy < 0 or iy >= cy:
                    break
            else:
                ix = _within(_cell_index(ox + t * dx, bx, gx, cx), ix, sx, r)
                iy = _within(_cell_index(oy + t * dy, by, gy, cy), iy, sy, r)
                iz += sz * r
                if iz < 0 or iz >= cz:
                    break
            nx_t = _next_boundary(ox, ivx, bx, hx, ix, sx)
            ny_t = _next_boundary(oy, ivy, by, hy, iy, sy)
            nz_t = _next_boundary(oz, ivz, bz, hz, iz, sz)
            continue
        t_end = min(nx_t, ny_t, nz_t, tmax)
        maj = m.majorant[ix, iy, iz]
        if not rest:
            maj *= boost
        if maj > 0.0:
            while True:
                if tau < 0.0:
                    state, u = next_float(state)
                    tau = -math.log(1.0 - u)
                depth = maj * (t_end - t)
                if tau >= depth:
                    tau -= depth
                    break
                inv_maj = 1.0 / maj  # one division per tentative collision, not three
                t += tau * inv_maj
                tau = -1.0
                sigma = extinction_at(m, ox + t * dx, oy + t * dy, oz + t * dz)
                if rest:
                    state, u = next_float(state)
                    if u * maj < sigma:
                        if mode == _RATIO:  # the rest's collision: the light does not get through
                            return kept, w_sum, 0.0, state
                        w_sum += tr  # the rest's collision: one more candidate, of weight tr
                        state, u = next_float(state)
                        if u * w_sum < tr:
                            kept = t
                        return kept, w_sum, 0.0, state
                    continue
                if mode in (_DELTA, _RECORD):
                    state, u = next_float(state)
                    if u * maj < sigma:
                        return t, 1.0, tr, state
                    if mode == _RECORD and u < floor and sigma > 0.0:
                        return t, 0.0, tr, state
                    continue
                if mode == _RESAMPLE and sigma > 0.0:
                    w = tr * sigma * inv_maj
                    w_sum += w
                    state, u = next_float(state)
                    if u * w_sum < w:
                        kept = t
                tr *= 1.0 - sigma * inv_maj
                if tr < switch:
                    rest = True
                    maj = m.majorant[ix, iy, iz]  # the rest's flight at the plain majorant (tau is drawn anew)
                elif tr < RR_THRESHOLD:
                    state, u = next_float(state)
                    if u < 0.5:
                        return kept, w_sum, 0.0, state
                    tr *= 2.0
        if t_end >= tmax:
            break
        t = t_end
        # Step into the neighbouring macrocell across the nearest boundary.
        if nx_t <= ny_t and nx_t <= nz_t:
            ix += sx
            if ix < 0 or ix >= cx:
                break
            nx_t = _next_boundary(ox, ivx, bx, hx, ix, sx)
        elif ny_t <= nz_t:
            iy += sy
            if iy < 0 or iy >= cy:
                break
            ny_t = _next_boundary(oy, ivy, by, hy, iy, sy)
        else:
            iz += sz
            if iz < 0 or iz >= cz:
                break
            nz_t = _next_boundary(oz, ivz, bz, hz, iz, sz)
    return kept, w_sum, tr, state


@njit(cache=True, inline="always")
def delta_track(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
                tmax: float, state: np.uint64) -> tuple[float, np.uint64]:
    """Distance to the next real collision in [tmin, tmax), or inf if the ray leaves without one."""
    t, _, _, state = _track(m, ox, oy, oz, dx, dy, dz, tmin, tmax, state, _DELTA)
    return t, state


@njit(cache=True, inline="always")
def record_track(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
                 tmax: float, state: np.uint64, floor: float) -> tuple[float, bool, np.uint64]:
    """Delta tracking that stops at the next *record* (photon tracing's collision estimator with a floor,
    :mod:`photon_fields.runtime.photons.photon_path`): (t, real, state). A tentative collision at x with majorant
    m is a record with probability max(sigma_t(x) / m, ``floor``) where sigma_t(x) > 0, decided by the one draw that
    delta tracking makes there: real (the photon scatters) if u m < sigma_t(x), else a null record if u < floor.
    Null records leave the flight's distribution unchanged: the caller resumes the walk from t (free flight is
    memoryless). With floor 0 it is :func:`delta_track`, draw for draw. t is inf if the ray leaves first."""
    t, w, _, state = _track(m, ox, oy, oz, dx, dy, dz, tmin, tmax, state, _RECORD, floor)
    return t, w > 0.0, state


@njit(cache=True, inline="always")
def ratio_track(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
                tmax: float, state: np.uint64, switch: float = 0.0, boost: float = 1.0) -> tuple[float, np.uint64]:
    """Unbiased transmittance estimate over [tmin, tmax]; below ``switch`` the rest of the ray by delta tracking;
    tentative collisions at ``boost`` (>= 1) times the majorant before it (module docstring)."""
    _, _, tr, state = _track(m, ox, oy, oz, dx, dy, dz, tmin, tmax, state, _RATIO, 0.0, switch, boost)
    return tr, state


@njit(cache=True, inline="always")
def resampled_collision(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
                        tmax: float, state: np.uint64) -> tuple[float, float, float, np.uint64]:
    """One collision resampled from the ratio-tracking walk over [tmin, tmax] (module docstring):
    (t, W, T, state) with t the kept distance (inf if no tentative collision scored), W the estimate of
    1 - T(tmax) that weights it, T the estimate of T(tmax)."""
    return _track(m, ox, oy, oz, dx, dy, dz, tmin, tmax, state, _RESAMPLE)


@njit(cache=True, inline="always")
def camera_collision(m: Medium, ox: float, oy: float, oz: float, dx: float, dy: float, dz: float, tmin: float,
                     tmax: float, state: np.uint64, forced: bool,
                     w_min: float) -> tuple[float, float, float, np.uint64]:
    """The first-interaction renderers' collision along a ray (their camera estimators): (t, W, T, state).

    ``forced`` False: delta tracking, W = 1, T = 1 if the ray escapes else 0 (an unbiased estimate of the
    transmittance). ``forced`` True: :func:`resampled_collision`, with Russian roulette on a small weight: a
    collision of weight W < ``w_min`` is kept with probability W / ``w_min`` and then weighted ``w_min``, which
    bounds the work per collision. t is inf when no collision is kept. Forced walks past ``CAMERA_SWITCH`` finish
    the ray by delta tracking (module docstring)."""
    # One inlined walk for both modes (the mode is a runtime value): two would double the caller's compile time.
    t, w, tr, state = _track(m, ox, oy, oz, dx, dy, dz, tmin, tmax, state, _RESAMPLE if forced else _DELTA, 0.0,
                             CAMERA_SWITCH if forced else 0.0)
    if not forced:
        return t, 1.0, 0.0 if math.isfinite(t) else 1.0, state
    if math.isfinite(t) and w < w_min:
        state, u = next_float(state)
        t = t if u * w_min < w else math.inf
        w = w_min
    return t, w, tr, state


@njit(cache=True)
def _track_items(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray, states: np.ndarray,
                 mode: int, switch: float, boost: float, out: np.ndarray, lo: int, hi: int) -> None:
    m = borrowed_medium(m)  # no reference counting in the loop (runtime/borrowed.py)
    for i in range(lo, hi):
        t, _, tr, states[i] = _track(m, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i], tmin[i], tmax[i],
                                     states[i], mode, 0.0, switch, boost)
        out[i] = t if mode == _DELTA else tr


@njit(cache=True, parallel=True, nogil=True)
def _track_batch(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray, states: np.ndarray,
                 mode: int, switch: float = 0.0, boost: float = 1.0) -> np.ndarray:
    n = o.shape[1]
    out = np.empty(n)
    for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):
        _track_items(m, o, d, tmin, tmax, states, mode, switch, boost, out, task * TASK_ITEMS,
                     min(n, (task + 1) * TASK_ITEMS))
    return out


def delta_track_batch(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray,
                      states: np.ndarray) -> np.ndarray:
    """Batch delta tracking over SoA rays (o, d: (3, n)); advances ``states`` in place."""
    return _track_batch(m, o, d, tmin, tmax, states, _DELTA)


def ratio_track_batch(m: Medium, o: np.ndarray, d: np.ndarray, tmin: np.ndarray, tmax: np.ndarray,
                      states: np.ndarray, switch: float = 0.0, boost: float = 1.0) -> np.ndarray:
    """Batch ratio tracking over SoA rays (:func:`ratio_track`, ``switch`` and ``boost`` as there); advances
    ``states`` in place."""
    return _track_batch(m, o, d, tmin, tmax, states, _RATIO, switch, boost)
