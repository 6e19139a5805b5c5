"""Next-event estimation: light arriving at a scattering vertex directly from every light source.

For a vertex at ``p`` reached by a path travelling along ``d``, :func:`direct_light` returns

    sum over lights  f_g(d . l) * Le * Tr(p -> light)        (point: Le = I / r^2; directional: Le = E)
    + for the environment: f_g(d . l) * L_env(l) * Tr / pdf_l * w_nee,
      l ~ uniform sphere, pdf_l = 1/(4 pi) (constant) or l ~ the map's density p_w (environment map)

without the path throughput. The direction ``l``, ``Le / rgb`` and ``pdf_l`` of each light come from its
kind's branch in :func:`photon_fields.runtime.transport.emitters.sample_light_direction`; this module has no
per-kind code. Transmittance is estimated by ratio tracking (at a boosted majorant, ``SHADOW_BOOST``: less noise
for a few more lookups; :mod:`photon_fields.runtime.transport.tracking`). Delta lights (pdf inf: point and
directional) can only be reached by NEE, so their weight is 1. The environment can also be reached by
phase sampling; both strategies are combined with the power heuristic (Veach 1997):
``w_nee = pdf_l^2 / (pdf_l^2 + pdf_phase^2)``, and the phase-sampled escape gets the complement
(:func:`mis_weight_phase`, with the map's pdf of the escape direction for an environment map). Used by the
reference path tracer and, at the first vertex, by the neural renderer (paper Sec. 3.6, "Direct Illumination").

**One light per vertex** (:func:`direct_light_one`, ``one_light=True``; the first-interaction renderers' default,
:data:`LIGHT_SAMPLINGS`): instead of a shadow ray to every light, one light k is drawn with probability

    p_k = c_k / sum_j c_j,    c_k = f_g(d . l_k) * scale_k * (Le_r + Le_g + Le_b)_k

(its contribution without the shadow: what :func:`direct_light` would add for it at transmittance 1) and its term is
divided by p_k: unbiased for every light with c_k > 0, and a light with c_k = 0 adds nothing to either sum. One
shadow ray per vertex instead of one per light: where the lights' transmittances agree the estimate is exact in
luminance, and where one light is shadowed and a weaker one is not, the weaker one's light arrives in fewer samples
with a larger weight (pbrt-v4's power light sampler, made spatial by the falloff and the phase function). With one
light nothing is drawn and the result equals :func:`direct_light`'s bit for bit. The two passes over the lights
replay the same random numbers (only environments draw any), so the chosen light's direction is the one its
probability was computed with.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.borrowed import borrowed
from photon_fields.runtime.transport.emitters import check_light_kinds, sample_light_direction
from photon_fields.runtime.transport.environment_map import EnvMap, borrowed_env
from photon_fields.runtime.transport.medium import Medium, borrowed_medium, intersect_box
from photon_fields.runtime.transport.phase import hg_eval
from photon_fields.runtime.transport.rng import next_float
from photon_fields.runtime.transport.tracking import SHADOW_BOOST, SHADOW_SWITCH, TASK_ITEMS, ratio_track


@njit(cache=True, inline="always")
def mis_weight_phase(pdf_phase: float, pdf_light: float) -> float:
    """Power-heuristic weight of a phase-sampled direction that escapes to the environment."""
    if math.isinf(pdf_phase):
        return 1.0
    a = pdf_phase * pdf_phase
    return a / (a + pdf_light * pdf_light)


#: How NEE treats several lights: "all" (a shadow ray to every light, :func:`direct_light`) or "one" (one light per
#: vertex drawn by its unshadowed contribution, :func:`direct_light_one`; module docstring).
LIGHT_SAMPLINGS = ("all", "one")


@njit(cache=True, inline="always")
def _light_term(kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float, k: int, px: float,
                py: float, pz: float, dx: float, dy: float, dz: float, state: np.uint64, env_mis: bool
                ) -> tuple[float, float, float, float, float, float, float, float, float, np.uint64]:
    """Light k's sample from p (module docstring) without its shadow: (lx, ly, lz, r, g, b, distance, f, c, state)
    with f the phase function times the environment's MIS weight over its pdf (1 / pdf for a delta light's
    infinite one), so that f (r, g, b) times the transmittance is the light's term, and c = f (r + g + b) its
    unshadowed contribution (0: the light adds nothing here; only then is f 0 too)."""
    lx, ly, lz, lr, lg, lb, pdf_l, tend, state = sample_light_direction(kind[k], vec[k], rgb[k], env, px, py, pz,
                                                                        state)
    phase = hg_eval(g, dx * lx + dy * ly + dz * lz)
    scale = 1.0
    if not math.isinf(pdf_l):  # not a delta light (an environment): MIS against phase sampling
        if pdf_l <= 0.0:
            return lx, ly, lz, lr, lg, lb, tend, 0.0, 0.0, state
        w = 1.0
        if env_mis:
            w = 1.0 - mis_weight_phase(phase, pdf_l)
        scale = w / pdf_l
    f = phase * scale
    if f <= 0.0 or (lr + lg + lb) <= 0.0:
        return lx, ly, lz, lr, lg, lb, tend, 0.0, 0.0, state
    return lx, ly, lz, lr, lg, lb, tend, f, f * (lr + lg + lb), state


@njit(cache=True, inline="always")
def _shadow(m: Medium, px: float, py: float, pz: float, lx: float, ly: float, lz: float, tend: float,
            state: np.uint64, boost: float) -> tuple[float, np.uint64]:
    """Transmittance from p towards the light (direction l, ``tend`` away at most), by ratio tracking at ``boost``
    times the majorant, its rest below ``SHADOW_SWITCH`` by delta tracking
    (:mod:`photon_fields.runtime.transport.tracking`)."""
    t0, t1 = intersect_box(m, px, py, pz, lx, ly, lz)
    tr = 1.0
    if t0 < t1:
        tr, state = ratio_track(m, px, py, pz, lx, ly, lz, t0, min(t1, tend), state, SHADOW_SWITCH, boost)
    return tr, state


@njit(cache=True, inline="always")
def direct_light(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float, px: float,
                 py: float, pz: float, dx: float, dy: float, dz: float, state: np.uint64,
                 env_mis: bool, boost: float) -> tuple[float, float, float, np.uint64]:
    """NEE with a shadow ray to every light (module docstring): radiance (r, g, b) and the stream's state."""
    r = 0.0
    gr = 0.0
    b = 0.0
    for k in range(kind.shape[0]):
        lx, ly, lz, lr, lg, lb, tend, f, c, state = _light_term(kind, vec, rgb, env, g, k, px, py, pz, dx, dy, dz,
                                                                state, env_mis)
        if c <= 0.0:
            continue
        tr, state = _shadow(m, px, py, pz, lx, ly, lz, tend, state, boost)
        ft = f * tr
        r += ft * lr
        gr += ft * lg
        b += ft * lb
    return r, gr, b, state


@njit(cache=True, inline="always")
def _draw_one_light(kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float, px: float, py: float,
                    pz: float, dx: float, dy: float, dz: float, state: np.uint64, env_mis: bool
                    ) -> tuple[float, float, float, float, float, float, float, float, float, float, np.uint64]:
    """The light k :func:`direct_light_one` draws (module docstring), without its shadow: (lx, ly, lz, distance,
    f r, f g, f b, sum_j c_j, c_k, state); its term is (f r, f g, f b) times the transmittance times sum_j c_j / c_k,
    and sum_j c_j is 0 (c_k 1) where no light adds anything."""
    n = kind.shape[0]
    state, u = next_float(state)
    start = state
    total = 0.0
    for k in range(n):
        _, _, _, _, _, _, _, _, c, state = _light_term(kind, vec, rgb, env, g, k, px, py, pz, dx, dy, dz, state,
                                                       env_mis)
        total += c
    if total > 0.0:
        state = start  # replay the same samples (only environments draw random numbers) up to the chosen light
        target = u * total
        acc = 0.0
        for k in range(n):
            lx, ly, lz, lr, lg, lb, tend, f, c, state = _light_term(kind, vec, rgb, env, g, k, px, py, pz, dx, dy, dz,
                                                                    state, env_mis)
            acc += c
            if c > 0.0 and (target < acc or acc >= total):  # acc reaches total at the last light with c > 0
                return lx, ly, lz, tend, f * lr, f * lg, f * lb, total, c, state
    return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, state


@njit(cache=True, inline="always")
def direct_light_one(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float, px: float,
                     py: float, pz: float, dx: float, dy: float, dz: float, state: np.uint64,
                     env_mis: bool, boost: float) -> tuple[float, float, float, np.uint64]:
    """:func:`direct_light`'s estimate with one shadow ray: one light drawn by its unshadowed contribution (module
    docstring), for two lights or more (:func:`direct_light_batch` gives a single light to :func:`direct_light`,
    which draws nothing: the same numbers)."""
    lx, ly, lz, tend, fr, fg, fb, total, c, state = _draw_one_light(kind, vec, rgb, env, g, px, py, pz, dx, dy, dz,
                                                                    state, env_mis)
    if total <= 0.0:
        return 0.0, 0.0, 0.0, state
    tr, state = _shadow(m, px, py, pz, lx, ly, lz, tend, state, boost)
    s = tr * total / c
    return fr * s, fg * s, fb * s, state


# The two kinds of task and their parallel loops are written out as top-level functions, not made by a factory:
# numba keys a closure's cache entry by a pickle of its cells, and a captured dispatcher pickles with a uuid of its
# own process, so every new process missed the cache and compiled NEE again (every command-line render from
# 2026-11-27 to 11-30: bench/README.md; tests/runtime/test_kernel_cache.py). One loop per kind of task: a compiled call
# per item passed the medium's arrays with reference counting, which cost more than many shadow rays' walks, and
# one function inlining both kinds took minutes to compile. ``TASK_ITEMS`` in tracking.py says why tasks.


@njit(cache=True)
def _every_light_items(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float,
                       o: np.ndarray, d: np.ndarray, states: np.ndarray, env_mis: bool, boost: float,
                       out: np.ndarray, lo: int, hi: int) -> None:
    """A task of :func:`direct_light_batch`: :func:`direct_light` at items lo..hi-1."""
    m, env = borrowed_medium(m), borrowed_env(env)  # no reference counting in the loop (runtime/borrowed.py)
    kind, vec, rgb = borrowed(kind), borrowed(vec), borrowed(rgb)
    for i in range(lo, hi):
        out[0, i], out[1, i], out[2, i], states[i] = direct_light(
            m, kind, vec, rgb, env, g, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i], states[i], env_mis, boost)


@njit(cache=True)
def _one_light_items(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float,
                     o: np.ndarray, d: np.ndarray, states: np.ndarray, env_mis: bool, boost: float, out: np.ndarray,
                     lo: int, hi: int) -> None:
    """A task of :func:`direct_light_batch`: :func:`direct_light_one` at items lo..hi-1."""
    m, env = borrowed_medium(m), borrowed_env(env)  # no reference counting in the loop (runtime/borrowed.py)
    kind, vec, rgb = borrowed(kind), borrowed(vec), borrowed(rgb)
    for i in range(lo, hi):
        out[0, i], out[1, i], out[2, i], states[i] = direct_light_one(
            m, kind, vec, rgb, env, g, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i], states[i], env_mis, boost)


# A parallel loop per kind of task, chosen by :func:`direct_light_batch` in Python: one parallel function calling
# either kind compiled both wherever it was used (a cold path-traced render spent ~40 % of its time compiling the
# one-light loop it never ran: bench/README.md, "A stage of its own"), also with the choice as a literal argument
# (numba did not prune the other call inside the prange body); a factory writing them once missed the cache (above).


@njit(cache=True, parallel=True)
def _every_light_batch(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float,
                       o: np.ndarray, d: np.ndarray, states: np.ndarray, env_mis: bool, boost: float) -> np.ndarray:
    n = o.shape[1]
    out = np.empty((3, n))
    for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):
        lo, hi = task * TASK_ITEMS, min(n, (task + 1) * TASK_ITEMS)
        _every_light_items(m, kind, vec, rgb, env, g, o, d, states, env_mis, boost, out, lo, hi)
    return out


@njit(cache=True, parallel=True)
def _one_light_batch(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float,
                     o: np.ndarray, d: np.ndarray, states: np.ndarray, env_mis: bool, boost: float) -> np.ndarray:
    n = o.shape[1]
    out = np.empty((3, n))
    for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):
        lo, hi = task * TASK_ITEMS, min(n, (task + 1) * TASK_ITEMS)
        _one_light_items(m, kind, vec, rgb, env, g, o, d, states, env_mis, boost, out, lo, hi)
    return out


def direct_light_batch(m: Medium, kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float,
                       o: np.ndarray, d: np.ndarray, states: np.ndarray, env_mis: bool = True,
                       one_light: bool = False, boost: float = SHADOW_BOOST) -> np.ndarray:
    """Stage: NEE at every vertex of a SoA batch; returns radiance (3, n) (times throughput later). ``env`` is
    the scene's environment map (``Scene.packed_environment_map()``, a placeholder when it has none).
    ``env_mis=False`` gives the environment's NEE full weight, for estimators that never reach the
    environment by phase sampling (the first-interaction renderers). ``one_light``: one shadow ray per vertex to a
    light drawn by its unshadowed contribution (:func:`direct_light_one`) instead of one to every light.
    ``boost``: shadow rays' tentative collisions at this many times the majorant (default
    :data:`photon_fields.runtime.transport.tracking.SHADOW_BOOST`, every renderer's; 1: plain ratio tracking)."""
    check_light_kinds(kind)
    one = one_light and kind.shape[0] > 1  # with one light, direct_light's numbers (nothing to draw)
    batch = _one_light_batch if one else _every_light_batch
    return batch(m, kind, vec, rgb, env, float(g), o, d, states, bool(env_mis), float(boost))


@njit(cache=True)
def _light_sample_items(kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float, o: np.ndarray,
                        d: np.ndarray, states: np.ndarray, env_mis: bool, one: bool, lights: np.ndarray,
                        weight: np.ndarray, lo: int, hi: int) -> None:
    """A task of :func:`sample_lights_batch` over items lo..hi-1."""
    env = borrowed_env(env)  # no reference counting in the loop (runtime/borrowed.py)
    kind, vec, rgb = borrowed(kind), borrowed(vec), borrowed(rgb)
    for i in range(lo, hi):
        px, py, pz, dx, dy, dz = o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i]
        s = states[i]
        if one:
            lx, ly, lz, tend, fr, fg, fb, total, c, s = _draw_one_light(kind, vec, rgb, env, g, px, py, pz, dx, dy,
                                                                        dz, s, env_mis)
            ratio = total / c
            lights[0, i], lights[1, i], lights[2, i], lights[3, i] = lx, ly, lz, tend
            weight[0, i], weight[1, i], weight[2, i] = fr * ratio, fg * ratio, fb * ratio
        else:
            for k in range(kind.shape[0]):
                lx, ly, lz, lr, lg, lb, tend, f, c, s = _light_term(kind, vec, rgb, env, g, k, px, py, pz, dx, dy, dz,
                                                                    s, env_mis)
                j = k * o.shape[1] + i
                lights[0, j], lights[1, j], lights[2, j], lights[3, j] = lx, ly, lz, tend
                weight[0, j], weight[1, j], weight[2, j] = f * lr, f * lg, f * lb  # 0 where c is 0
        states[i] = s


@njit(cache=True, parallel=True)
def sample_lights_batch(kind: np.ndarray, vec: np.ndarray, rgb: np.ndarray, env: EnvMap, g: float, o: np.ndarray,
                        d: np.ndarray, states: np.ndarray, env_mis: bool = True,
                        one_light: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Stage: NEE's light samples at every vertex of a SoA batch without their shadow rays, for a renderer that traces
    these by another estimator (the marched camera's picks): (lights (4, k n): direction and distance of shadow ray
    j n + i from vertex i, weight (3, k n): its term over the transmittance; 0 for a ray that adds nothing), k = 1
    with ``one_light`` (:func:`direct_light_one`'s draw) and two lights or more, else one ray per light. NEE is the
    sum over a vertex's rays of weight times their transmittance; ``states`` are advanced past the lights' draws,
    the shadow rays continue them."""
    check_light_kinds(kind)
    n = o.shape[1]
    one = one_light and kind.shape[0] > 1
    k = 1 if one else kind.shape[0]
    lights = np.empty((4, k * n))
    weight = np.empty((3, k * n))
    for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):
        lo, hi = task * TASK_ITEMS, min(n, (task + 1) * TASK_ITEMS)
        _light_sample_items(kind, vec, rgb, env, g, o, d, states, env_mis, one, lights, weight, lo, hi)
    return lights, weight
