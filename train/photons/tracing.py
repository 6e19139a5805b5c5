"""Multi-phase photon tracing in heterogeneous media (paper Alg. 1, Sec. 3.2).

Parameters
----------
photons : int >= 1
    Target number of stored records ("photons in the map", as in the paper's Table 3). Photon paths are
    traced in fixed-size chunks until each phase holds at least ``ceil(photons / |G|)`` records; the map
    keeps every record of a phase's paths up to the one that reaches its quota.
phases : sequence of g in [-1, 1] (default ``models_spec.DEFAULT_MAP_PHASES``: 39 narrow bins over [-0.95, 0.95],
    read with a kernel in g, :mod:`photon_fields.runtime.photons.phase_window`; or a few phases such as
    ``models_spec.DEFAULT_PHASES``, the paper's G = {-0.75, 0, 0.75} with the midpoints)
    Each photon path scatters with one g of G at every vertex. Paths are assigned to the phases
    round-robin and every phase is traced until it holds ``photons / |G|`` records, so the phases are
    equally represented in the map ("equally distributed over ... the number of phases", Sec. 4.4)
    even though forward- and back-scattering photons leave different numbers of records per path.
record_floor : float in [0, 1) (default ``models_spec.RECORD_FLOOR``)
    Also record photons at null collisions, so that a tentative collision is a record with probability at least
    this; every record's weight is then bounded (:mod:`photon_fields.runtime.photons.photon_path`, "Records with a
    floor"). The records count towards ``photons`` like the others. 0: real collisions only.
max_bounces : int >= 2 (default 16)
    Maximum number of collisions of a photon path. A record at collision k is the light that reaches a
    camera vertex through k scattering vertices, so ``max_bounces = 16`` matches the path tracer's
    ``max_depth = 16``.
seed : int
    Photon path i uses random stream i of the seed (``runtime.transport.rng``): the map is identical for any
    number of threads, and chunking is fixed, so the record order is deterministic too.

Emission (power split by light power: a light is chosen with probability proportional to its total
RGB flux, and its photons carry flux / probability): each light kind's flux, emission cone and photon
sampler are in ``runtime.transport.emitters`` (:func:`emission_fluxes`, :func:`emit_photon`); every photon
is aimed at the volume's bounding sphere (a point light's cone towards it, a disk of parallel rays across it
for the directional and environment lights), so none is wasted on directions that cannot reach the volume.

Transport (:func:`photon_fields.runtime.photons.photon_path.trace_path`, shared with the PVRT precomputation): free
flights by delta tracking over the majorant grid; at each real collision the photon is recorded (from the second
collision on, Alg. 1's "skip first interaction"; with a record floor, also at some null collisions after the first) with
the power it *arrives* with, then Russian roulette with survival probability = max albedo component, and the surviving
power is multiplied by albedo / survival (Jensen's photon tracing: powers stay nearly constant, which keeps the density
estimate's variance low). Recording before the albedo differs from Alg. 1's listing on purpose: the albedo at the
camera's vertex is applied at render time from the full-resolution transfer function, so the field only has to learn the
smooth incident light (see ``runtime.photons.estimate``). Record powers are divided by the number of paths emitted for
their phase, so the records of each phase form a complete photon map on their own. Each record also keeps the index of
the light its path started from (the map's ``light`` array): the map then holds each light's photon map apart, which a
field with one output per light learns (:attr:`photon_fields.models_spec.encoding.FieldConfig.light_channels`); and its
collision number along the path and the scalar at the path's previous collision, from which an edit of the albedo alone
reweights the map exactly instead of retracing it (:mod:`photon_fields.runtime.photons.albedo_reweight`).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np
from numba import njit, prange

from photon_fields.models_spec import DEFAULT_MAP_PHASES
from photon_fields.models_spec.photon_map import MAX_LIGHTS, RECORD_FLOOR
from photon_fields.runtime.borrowed import borrowed
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.photon_map import PhotonMap, check_record_floor
from photon_fields.runtime.photons.photon_path import trace_path
from photon_fields.runtime.progress import progress_bar
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.emitters import emission_fluxes, emit_photon
from photon_fields.runtime.transport.environment_map import EnvMap, borrowed_env
from photon_fields.runtime.transport.medium import Medium, borrowed_medium
from photon_fields.runtime.transport.phase import check_g
from photon_fields.runtime.transport.rng import next_float, stream_state
from photon_fields.runtime.transport.tracking import TASK_ITEMS

CHUNK = 1 << 15  # photon paths per kernel call; fixed so results do not depend on anything else
#: Give up when the stored/emitted ratio says the target would need more than this many paths.
MAX_EMITTED_PER_TARGET = 2000
MIN_PATHS_BEFORE_GIVING_UP = 1 << 20
#: Rows per path for null records (``record_floor`` > 0) beyond its real collisions' (``photon_path.trace_path``).
NULL_ROWS = 32


def light_fluxes(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(flux (n_lights, 3) of the part of each light that can reach the bounding sphere, cone cos_max (n,)):
    :func:`photon_fields.runtime.transport.emitters.emission_fluxes` of the scene's packed lights."""
    kind, vec, rgb = scene.packed_lights()
    return emission_fluxes(scene.medium(), kind, vec, rgb, scene.packed_environment_map())


@njit(cache=True)
def _trace_paths(m: Medium, kind: np.ndarray, vec: np.ndarray, env: EnvMap, power: np.ndarray, cos_max: np.ndarray,
                 light_cdf: np.ndarray, phases: np.ndarray, active: np.ndarray, seed: int, first: int, lo: int, hi: int,
                 max_bounces: int, floor: float, slots: int,
                 out_pos: np.ndarray, out_dir: np.ndarray, out_pow: np.ndarray, out_phase: np.ndarray,
                 out_light: np.ndarray, out_bounce: np.ndarray, out_prev: np.ndarray, out_count: np.ndarray,
                 out_lost: np.ndarray) -> None:
    """Paths lo..hi-1 of :func:`_trace_chunk`, serially (``TASK_ITEMS`` in the tracking module says why)."""
    m, env = borrowed_medium(m), borrowed_env(env)  # no reference counting per path (runtime/borrowed.py)
    kind, vec, power, cos_max, light_cdf = borrowed(kind), borrowed(vec), borrowed(power), borrowed(cos_max), \
        borrowed(light_cdf)
    cx, cy, cz = m.bmin[0] + 0.5 * m.bsize[0], m.bmin[1] + 0.5 * m.bsize[1], m.bmin[2] + 0.5 * m.bsize[2]
    radius = 0.5 * math.sqrt(m.bsize[0] ** 2 + m.bsize[1] ** 2 + m.bsize[2] ** 2)
    rows = slots + 1  # the first collision's record too, which is not stored
    hit_pos, hit_dir, hit_pow = np.empty((rows, 3)), np.empty((rows, 3)), np.empty((rows, 3))
    hit_coll, hit_scalar = np.empty(rows, dtype=np.int64), np.empty(max_bounces)
    for i in range(lo, hi):
        st = stream_state(np.uint64(seed), np.uint64(first + i))
        st, u = next_float(st)
        li = 0
        while li < light_cdf.shape[0] - 1 and u >= light_cdf[li]:
            li += 1
        st, u1 = next_float(st)
        st, u2 = next_float(st)
        st, u3 = next_float(st)
        st, u4 = next_float(st)
        ox, oy, oz, dx, dy, dz, sr, sg, sb = emit_photon(kind[li], vec[li], env, cos_max[li], cx, cy, cz, radius,
                                                         u1, u2, u3, u4)
        ph = active[i % active.shape[0]]
        g = phases[ph]
        br, bg, bb = power[li, 0] * sr, power[li, 1] * sg, power[li, 2] * sb
        count = 0
        n, st, lost = trace_path(m, g, ox, oy, oz, dx, dy, dz, br, bg, bb, st, max_bounces, floor, hit_pos, hit_dir,
                                 hit_pow, hit_coll, hit_scalar)
        for r in range(n):
            c = hit_coll[r]
            if c >= 2:  # Alg. 1: the first interaction (and the flight to it) is direct light, not stored
                k = i * slots + count
                for a in range(3):
                    out_pos[k, a] = hit_pos[r, a]
                    out_dir[k, a] = hit_dir[r, a]
                    out_pow[k, a] = hit_pow[r, a]
                out_phase[k] = ph
                out_light[k] = li
                out_bounce[k] = c
                out_prev[k] = hit_scalar[c - 2]  # the previous collision played its roulette on this
                count += 1
        out_count[i] = count
        out_lost[i] = lost


@njit(cache=True, parallel=True)
def _trace_chunk(m: Medium, kind: np.ndarray, vec: np.ndarray, env: EnvMap, power: np.ndarray, cos_max: np.ndarray,
                 light_cdf: np.ndarray, phases: np.ndarray, active: np.ndarray, seed: int, first: int, n: int,
                 max_bounces: int, floor: float, slots: int,
                 out_pos: np.ndarray, out_dir: np.ndarray, out_pow: np.ndarray, out_phase: np.ndarray,
                 out_light: np.ndarray, out_bounce: np.ndarray, out_prev: np.ndarray, out_count: np.ndarray,
                 out_lost: np.ndarray) -> None:
    """Trace photon paths first .. first + n - 1; path i scatters with phase active[i % len(active)],
    writes its records (with the index of the light it started from, the collision's number along the path and the
    scalar at the path's previous collision) to slots [i * slots, ...) and their number to out_count[i], and the
    number of null records it dropped for want of slots to out_lost[i] (``floor``: the record floor; ``slots``
    >= max_bounces - 1, and more with a floor). ``env``: the scene's environment map (its photons' power is scaled
    per channel by ``emit_photon``)."""
    for task in prange((n + TASK_ITEMS - 1) // TASK_ITEMS):
        _trace_paths(m, kind, vec, env, power, cos_max, light_cdf, phases, active, seed, first, task * TASK_ITEMS,
                     min(n, (task + 1) * TASK_ITEMS), max_bounces, floor, slots, out_pos, out_dir, out_pow, out_phase,
                     out_light, out_bounce, out_prev, out_count, out_lost)


def _check_progress(scene: Scene, stored: np.ndarray, emitted: np.ndarray, quota: int) -> None:
    """Refuse to loop (nearly) forever when the lights (almost) never reach the volume."""
    for k in range(stored.size):
        hopeless = stored[k] * MAX_EMITTED_PER_TARGET < quota
        if stored[k] < quota and emitted[k] >= MIN_PATHS_BEFORE_GIVING_UP and hopeless:
            reason = ("no photon from the lights scatters twice in the volume: the lights miss it, or the transfer "
                      "function makes it (nearly) empty or black") if stored[k] == 0 else (
                      f"only {stored[k]} records from {emitted[k]} photon paths: the lights barely reach the volume")
            raise InputError(f"scene '{scene.name}'", reason)


def check_phases(phases: Sequence[float], what: str = "phases") -> tuple[float, ...]:
    if len(phases) == 0:
        raise InputError(what, "the phase set G is empty")
    if len(phases) > 255:
        raise InputError(what, "at most 255 phases are supported")
    gs = tuple(check_g(g, what) for g in phases)
    if len(set(gs)) != len(gs):
        raise InputError(what, f"phase values must be distinct, got {list(phases)}")
    return gs


def trace_photons(scene: Scene, photons: int, *, phases: Sequence[float] = DEFAULT_MAP_PHASES, max_bounces: int = 16,
                  seed: int = 0, progress: bool = True,
                  on_progress: Callable[[int, int], None] | None = None, deadline: float | None = None,
                  min_photons: int = 0, record_floor: float = RECORD_FLOOR) -> PhotonMap:
    """Alg. 1: trace photon paths until the map holds at least ``photons`` records. ``on_progress(done, total)``
    is called after every chunk with the records stored so far (e.g. a
    :class:`photon_fields.runtime.io.progress.ProgressFile`'s update). ``deadline`` (a ``time.perf_counter()``
    value): stop after the chunk that passes it, once the map holds ``min_photons`` records (a time budget's
    retrace, ``pfn-train update``): the map is then the first chunks' paths, each phase normalized by its own
    emitted paths as always, and how many there are depends on the machine's speed."""
    if isinstance(photons, bool) or not isinstance(photons, (int, np.integer)) or photons < 1:
        raise InputError("photons", f"must be a positive integer, got {photons!r}")
    if not 2 <= max_bounces <= 1024:
        raise InputError("max_bounces", f"must be in [2, 1024] (photons are stored from the 2nd collision), "
                         f"got {max_bounces}")
    gs = check_phases(phases)
    m = scene.medium()
    kind, vec, _ = scene.packed_lights()
    env = scene.packed_environment_map()
    flux, cos_max = light_fluxes(scene)
    weight = flux.sum(axis=1)
    if weight.sum() <= 0:
        raise InputError("lights", "no light emits any power")
    p_light = weight / weight.sum()
    light_cdf = np.cumsum(p_light)
    light_cdf[-1] = 1.0
    # Unnormalized photon power: flux / P(light); divided by the number of its phase's paths at the end.
    with np.errstate(divide="ignore", invalid="ignore"):
        power = np.where(p_light[:, None] > 0, flux / p_light[:, None], 0.0)
    record_floor = check_record_floor(record_floor)
    slots = max_bounces - 1 + (NULL_ROWS if record_floor > 0 else 0)
    buf_pos = np.empty((CHUNK * slots, 3), dtype=np.float32)
    buf_dir = np.empty((CHUNK * slots, 3), dtype=np.float32)
    buf_pow = np.empty((CHUNK * slots, 3), dtype=np.float32)
    buf_phase = np.empty(CHUNK * slots, dtype=np.uint8)
    buf_light = np.zeros(CHUNK * slots, dtype=np.uint8)
    buf_bounce = np.zeros(CHUNK * slots, dtype=np.uint8)
    buf_prev = np.zeros(CHUNK * slots, dtype=np.float32)
    counts = np.empty(CHUNK, dtype=np.int64)
    lost = np.zeros(CHUNK, dtype=np.int64)
    lost_total = 0
    quota = -(-photons // len(gs))
    stored = np.zeros(len(gs), dtype=np.int64)
    emitted_per_phase = np.zeros(len(gs), dtype=np.int64)
    parts: list[list[tuple[np.ndarray, ...]]] = [[] for _ in gs]
    first_path = 0
    g_arr = np.asarray(gs, dtype=np.float64)
    t_start = time.perf_counter()
    with progress_bar(total=quota * len(gs), desc="tracing photons", unit="ph", unit_scale=True,
                      enabled=progress) as bar:
        while np.any(stored < quota):
            active = np.flatnonzero(stored < quota).astype(np.int64)
            _trace_chunk(m, kind, vec, env, power, cos_max, light_cdf, g_arr, active, int(seed), first_path, CHUNK,
                         max_bounces, float(record_floor), slots, buf_pos, buf_dir, buf_pow, buf_phase, buf_light,
                         buf_bounce, buf_prev, counts, lost)
            first_path += CHUNK
            lost_total += int(lost.sum())
            for j, ph in enumerate(active):
                paths = np.arange(j, CHUNK, len(active))  # this phase's paths in the chunk
                cum = np.cumsum(counts[paths])
                if stored[ph] + cum[-1] >= quota:  # keep whole paths, up to the one that reaches the quota
                    paths = paths[: int(np.searchsorted(cum, quota - stored[ph])) + 1]
                used = np.arange(slots)[None, :] < counts[paths, None]
                sel = (paths[:, None] * slots + np.arange(slots)[None, :])[used]
                parts[ph].append((buf_pos[sel], buf_dir[sel], buf_pow[sel], buf_phase[sel], buf_light[sel],
                                  buf_bounce[sel], buf_prev[sel]))
                stored[ph] += sel.size
                emitted_per_phase[ph] += paths.size
                bar.update(int(min(sel.size, quota * len(gs) - bar.n)))
            if on_progress is not None:
                on_progress(int(np.minimum(stored, quota).sum()), quota * len(gs))
            _check_progress(scene, stored, emitted_per_phase, quota)
            if deadline is not None and time.perf_counter() >= deadline and stored.sum() >= min_photons:
                break
    pos = np.concatenate([p[0] for ph_parts in parts for p in ph_parts])
    dirs = np.concatenate([p[1] for ph_parts in parts for p in ph_parts])
    ph_idx = np.concatenate([p[3] for ph_parts in parts for p in ph_parts])
    light = np.concatenate([p[4] for ph_parts in parts for p in ph_parts]) if len(kind) <= MAX_LIGHTS else None
    bounce = np.concatenate([p[5] for ph_parts in parts for p in ph_parts])
    prev = np.concatenate([p[6] for ph_parts in parts for p in ph_parts])
    # Normalize by the paths emitted for each record's own phase (each phase is a complete map).
    pw = np.concatenate([p[2] / np.float32(emitted_per_phase[k]) for k, ph_parts in enumerate(parts)
                         for p in ph_parts]).astype(np.float32)
    emitted = int(emitted_per_phase.sum())
    meta = {"seed": int(seed), "max_bounces": int(max_bounces), "trace_seconds": time.perf_counter() - t_start,
            "scene_name": scene.name, "emitted_per_phase": [int(e) for e in emitted_per_phase],
            "scene_parts": scene.fingerprint_parts(), "lights": scene.light_identities()}
    if record_floor > 0:
        meta["record_floor"] = float(record_floor)
    if lost_total:
        print(f"photon tracing: {lost_total} null records dropped (a path made more than {NULL_ROWS}); the map "
              "is slightly dark where they were", file=sys.stderr)
    return PhotonMap(pos, dirs, pw, ph_idx, gs, scene.fingerprint(), emitted, meta, light=light, bounce=bounce,
                     prev_scalar=prev)
