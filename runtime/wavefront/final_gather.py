"""Final gather: one real bounce before the indirect-light estimate (photon mapping's final gathering, Jensen 1996).

The first-interaction renderers (paper Alg. 2) read the in-scattered indirect radiance Q(x, d, g) at the camera
ray's first interaction x straight from their estimator (the photon field, or the photon map's Eq. 5). Whatever
bias that estimate has (the field's 2-10 % on structured media, its blur across sharp bright edges: issue 13)
then goes into the image at full strength. A final gather estimates Q(x, d, g) one bounce further instead:

    Q(x, d, g) = integral p_g(d, w) L_s(x, w) dw,
    L_s(x, w)  = integral_0^t_max T(x, x + t w) sigma_s(x2) [NEE(x2, w) + Q(x2, w, g)] dt,   x2 = x + t w

(L_s: the radiance arriving at x along -w that has scattered at least once, at x2; its first part is x2's
single scattering, its second the light that scattered before x2). Sampling w from the phase function (pdf =
p_g, which cancels) and x2 from the camera estimator's collision (delta tracking, pdf sigma_t T; or "forced", a
collision resampled from the whole segment with weight W = the walk's estimate of its collision probability,
:func:`photon_fields.runtime.transport.tracking.resampled_collision`) gives the one-sample estimate

    Q^(x, d, g) = W a(x2) [NEE(x2, w) + Q_est(x2, w, g)]      (0 when the bounce leaves the box),

with a = sigma_s / sigma_t. NEE at x2 is exact in expectation, so only the light that scattered twice or more
before reaching the eye comes from the estimator, attenuated by a(x2) and averaged over the phase lobe: its bias
reaches the image reduced and blurred, at the cost of the bounce (a tracking, NEE, the estimator at x2: roughly
a second frame's work) and of its noise. A bounce that leaves the box scores 0: that path has only x as a
scattering vertex and belongs to L_d, which NEE at x already counts (the environment included, with full
weight). With an estimator that returns 0 the renderer's L_i is exactly the light of paths with two scattering
vertices: the path tracer's ``max_depth = 2`` L_i, which the tests check with block z-scores.

Random numbers: each item's bounce draws from its own stream derived from the item's state after the camera
tracking (:data:`GATHER_STREAM` mixed in), so the bounce neither reuses NEE's draws at x nor depends on whether
or when NEE runs; the same seed gives the same image.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.transport.direct_light import direct_light_batch
from photon_fields.runtime.transport.environment_map import EnvMap
from photon_fields.runtime.transport.medium import Medium, albedo_at, borrowed_medium, intersect_box
from photon_fields.runtime.transport.phase import sample_hg
from photon_fields.runtime.transport.rng import mix64, next_float
from photon_fields.runtime.transport.tracking import TASK_ITEMS, camera_collision
from photon_fields.runtime.wavefront.batches import StageTimer

#: Mixed into an item's random state to start its bounce's own stream.
GATHER_STREAM = np.uint64(0x5A17_F1E1_D6A7_4E55)


@njit(cache=True)
def _bounce_items(m: Medium, g: float, x: np.ndarray, d: np.ndarray, rng: np.ndarray, forced: bool, w_min: float,
                  x2: np.ndarray, w: np.ndarray, weight: np.ndarray, states: np.ndarray, hit: np.ndarray,
                  lo: int, hi: int) -> None:
    """:func:`_bounce` for items lo..hi-1 (one task; ``TASK_ITEMS`` in tracking.py says why)."""
    m = borrowed_medium(m)  # no reference counting in the loop (runtime/borrowed.py)
    for i in range(lo, hi):
        s = mix64(rng[i] ^ GATHER_STREAM)
        s, u1 = next_float(s)
        s, u2 = next_float(s)
        wx, wy, wz, _ = sample_hg(g, d[0, i], d[1, i], d[2, i], u1, u2)
        px, py, pz = x[0, i], x[1, i], x[2, i]
        _, t1 = intersect_box(m, px, py, pz, wx, wy, wz)
        t, wt, _, s = camera_collision(m, px, py, pz, wx, wy, wz, 0.0, max(t1, 0.0), s, forced, w_min)
        states[i] = s
        w[0, i], w[1, i], w[2, i] = wx, wy, wz
        if not math.isfinite(t):
            continue
        hit[i] = True
        qx, qy, qz = px + t * wx, py + t * wy, pz + t * wz
        x2[0, i], x2[1, i], x2[2, i] = qx, qy, qz
        ar, ag, ab = albedo_at(m, qx, qy, qz)
        weight[0, i], weight[1, i], weight[2, i] = wt * ar, wt * ag, wt * ab


@njit(cache=True, parallel=True)
def _bounce(m: Medium, g: float, x: np.ndarray, d: np.ndarray, rng: np.ndarray, forced: bool, w_min: float,
            x2: np.ndarray, w: np.ndarray, weight: np.ndarray, states: np.ndarray) -> np.ndarray:
    """Per item: a direction w ~ p_g(d, .) and the next collision x2 along it (the camera estimator's way).
    Writes w (every item), and for the items that collide x2 and ``weight`` = W a(x2) (3 channels); ``states``
    gets each item's stream state; returns whether it collided."""
    n = x.shape[1]
    hit = np.zeros(n, np.bool_)
    for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):
        _bounce_items(m, g, x, d, rng, forced, w_min, x2, w, weight, states, hit, task * TASK_ITEMS,
                      min(n, (task + 1) * TASK_ITEMS))
    return hit


def gather_indirect(m: Medium, lights: tuple[np.ndarray, np.ndarray, np.ndarray, EnvMap], g: float, x: np.ndarray,
                    d: np.ndarray, rng: np.ndarray, estimator: object, forced: bool, w_min: float,
                    timer: StageTimer, one_light: bool = False) -> np.ndarray:
    """Q^(x, d, g) at every item of a SoA batch (module docstring): (3, n). ``lights`` is
    ``Scene.packed_lights()`` followed by ``Scene.packed_environment_map()``; ``estimator`` an
    ``IndirectEstimator`` evaluated at the bounces' collisions;
    ``forced`` / ``w_min`` the camera estimator's choice and weight floor, used for the bounce too; ``one_light``
    the NEE's light sampling (``runtime.transport.direct_light``), as at the first interaction. ``rng`` is
    read, not advanced. Sub-stages are timed as ``final_gather.bounce`` / ``.direct`` / ``.estimator``."""
    n = x.shape[1]
    x2, w, weight = np.empty((3, n)), np.empty((3, n)), np.empty((3, n))
    states = np.empty(n, np.uint64)
    with timer("final_gather.bounce"):
        hit = _bounce(m, float(g), x, d, rng, forced, float(w_min), x2, w, weight, states)
    q = np.zeros((3, n))
    idx = np.flatnonzero(hit)
    if idx.size == 0:
        return q
    x2, w, weight, states = (np.ascontiguousarray(x2[:, idx]), np.ascontiguousarray(w[:, idx]),
                             weight[:, idx], states[idx])
    kind, vec, rgb, env = lights
    with timer("final_gather.direct"):
        arriving = direct_light_batch(m, kind, vec, rgb, env, float(g), x2, w, states, False, one_light)
    with timer("final_gather.estimator"):
        arriving += estimator(x2, w, g)
    q[:, idx] = weight * arriving
    return q
