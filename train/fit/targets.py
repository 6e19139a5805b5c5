"""Training samples and their photon-map targets (paper Sec. 3.3, Eq. 5 and Eq. 6).

Every training step draws a fresh batch (Sec. 3.3: "regenerate a new batch ... for every training step"):

- x uniform in the volume's world box (``sampling="box"``, the paper's "uniformly sampled set of grid
  coordinates"), or uniform over the medium's support, the points with sigma_t(x) > 0
  (``sampling="support"``, by rejection in the non-empty macrocells): the renderer only ever queries
  the field at real collisions, where sigma_t > 0, so samples in empty space train an answer nobody
  asks for; on ``vortex`` 98 % of the box is empty; or (``sampling="visible"``) :data:`VISIBLE_SHARE` of them
  where a camera around the volume sees the medium, with the direction it sees it from
  (:mod:`photon_fields.train.fit.visible_points`; each such point serves :data:`VISIBLE_REUSE` samples, each
  with its own g), the rest uniform over the support: the renderer's queries concentrate at the seen surfaces,
  and a field fitted uniformly over the support was 2-6 % dark there on the CT-like ``head`` (docs/training.md);
- d uniform on the unit sphere (the camera ray's travel direction, :mod:`photon_fields.models_spec.encoding`);
- g uniform from the photon map's phase set G (``g_sampling="discrete"``, the paper), or uniform over
  [min G, max G] (``"continuous"``): the photons then come from one of the two phases around g, chosen with
  the tent weights of :func:`photon_fields.models_spec.encoding.phase_features` (so the target's mean is their
  linear interpolation), and the phase function is evaluated at g itself. Only the light's earlier bounces
  are interpolated, not the last one, whose dependence on g is the sharpest (L_i is strongly convex in g near
  |g| = 0.75); and the field sees every g it will be asked for, not only the phases; ``"mixed"``: half the
  samples continuous, half at the phases (where the targets interpolate nothing); or ``"window"``, for a map
  traced in narrow phase bins (:data:`photon_fields.models_spec.photon_map.PHASE_BINS`): g over the range whose
  kernel in g is whole (:func:`photon_fields.runtime.photons.phase_window.window_range`, [-0.8, 0.8] for
  PHASE_BINS) with the arcsine density 1 / (pi sqrt((g - lo)(hi - g))) (Chebyshev's, g = lo + (hi - lo)
  (1 - cos(pi u)) / 2: the ends, where L_i changes fastest with g and a fit is held from one side only, get
  more samples; uniform g left the field 11-15 % off at g = -0.75 on blobs, docs/training.md), the photons
  from the triangular kernel of half-width PHASE_WINDOW centred at g itself (one search structure answers every
  g: :meth:`photon_fields.runtime.photons.estimate.PhotonMapEstimator.binned_index`), the phase function at g
  itself. Nothing is interpolated between distant phases: the earlier bounces are averaged over +-0.15 of g,
  the last bounce is exact. (Until 2026-11-27 the kernel sat on one of the two prebuilt window centres 0.1 apart
  next to g, chosen with tent weights: its mean was g, but the mixture is a wider kernel, whose average of the
  light's earlier bounces was ~0.8 % bright where L_i is convex in g, at the ends of the range; and the 17
  windows held each photon ~2.2 times.)

and the target is Q(x, d, g) of :class:`photon_fields.runtime.photons.estimate.PhotonMapEstimator` (Eq. 5 with 1/sigma_t
photon weights and the support-fraction boundary correction) with K photons and the schedule's current
r_max, log-encoded with Eq. 6. The per-phase search structures are the estimator's own
(``PhotonMapEstimator.index``, weights Phi / sigma_t at the photon), built once per sampler, i.e. once per
fit. The estimate equals ``PhotonMapEstimator(pmap, medium, k=k, radius=r)(x, d, g)`` exactly (tested);
the only difference is speed: the support fraction (64 volume lookups per query) is computed only for
queries that found a photon, the others are 0 whatever it is (70-98 % of box samples at the early,
small radii of the schedule).

Parameters
----------
pmap : photon_fields.runtime.photons.photon_map.PhotonMap
    The multi-phase photon map (every phase must hold photons).
medium : photon_fields.runtime.transport.medium.Medium
    The scene's medium (extinction for the photon weights, the box, the support).
k : int (default 1024)
    Photons per estimate (the paper's K).
psi : float
    Eq. 6 precision of the encoded targets.
seed : int
    Seeds the sampler's own ``numpy.random.Generator`` (training batches); the validation set uses an
    independent stream of the same seed, so its size never changes the training batches.
sampling : "box", "support" or "visible"
g_sampling : "discrete", "continuous", "mixed" or "window"
lights : int (default 1)
    1: targets for all lights together (n, 3); or the map's number of lights (it must record each photon's light):
    each light's part apart (n, 3 lights), from the same search (:class:`PhotonMapEstimator`'s ``lights``).
background : bool (default False)
    Compute the next pool in a worker thread (below, "Targets beside the training"); :meth:`TargetSampler.close`
    stops it.

Targets ahead. The estimates are computed for several steps' batches at once (:data:`TARGETS_PER_SET` per
phase, or :data:`BINNED_POOL_SETS` times that from the binned index; :meth:`TargetSampler.sample` then hands them
out a batch at a time): every sample is still drawn fresh and used once, but a search structure answers many
queries per call instead of a batch's share (256 of 4096 with 16 phases), and the Morton-ordered queries then
find their photons in cache (the binned index took 1.6x as long per query in calls of 4096 as in one call of
65536). The pool is dropped when the schedule's radius changes. Measured in bench/README.md ("Targets ahead").

Targets beside the training (``background=True``, what the fits use): while the steps consume one pool, a
worker thread draws and estimates the next, so the estimates (numba, the GIL released) run on one core while
torch's small training step, mostly serial, runs on the other. The pools are the same as without the worker:
the worker is the only user of the training stream, draws each pool in turn, and a pool drawn at a radius the
schedule has left is estimated again from the same draws at the radius asked for (the draws do not depend on
the radius). It takes all but one of the caller's numba threads; a caller with one thread (``--threads 1``)
computes the pools itself, as before. Measured in bench/README.md ("Targets beside the training").

Timing: every :meth:`TargetSampler.sample` adds its wall time to ``seconds`` (what the step waited for its
targets: the estimates it computed itself, or the rest of the worker's pool) and its batch size to ``queries``;
``background_seconds`` sums the worker's time per pool; ``estimated`` counts the targets computed.
:mod:`photon_fields.train.fit.loop` reports the seconds per step next to the training step.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np
import torch
from numba import njit, prange

from photon_fields.models_spec.encoding import direction_input, encode_radiance, normalize_position
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.estimate import DEFAULT_K, PhotonMapEstimator, ball_pattern, support_fraction
from photon_fields.runtime.photons.knn_radiance import indexed_radiance
from photon_fields.runtime.photons.phase_window import PHASE_WINDOW, check_window, window_range
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.transport.medium import Medium, extinction_at
from photon_fields.train.fit.visible_points import uniform_directions, visible_points

SAMPLING_MODES = ("box", "support", "visible")
#: ``sampling="visible"``: the share of samples at the first collisions of rays from outside the volume
#: (:mod:`photon_fields.train.fit.visible_points`); the rest are uniform over the support (a camera inside the
#: volume, the final gather's queries). Three quarters since 2026-11-27 (a half before): the field's error where a
#: camera looks from is what the image shows, and it was the field's, not its targets' (docs/training.md, "Three
#: quarters of the samples where cameras look").
VISIBLE_SHARE = 0.75
#: ``sampling="visible"``: samples per traced collision. Each copy of a point gets its own g, hence its target
#: from the photons of another kernel in g: nearly independent targets for a quarter of the rays (on a sparse
#: medium most rays leave without a collision, and tracing them costs more than the targets).
VISIBLE_REUSE = 4
G_SAMPLING_MODES = ("discrete", "continuous", "mixed", "window")
#: ``g_sampling="window"``: the pool of the binned index (one structure for every g) holds this many sets of
#: :data:`TARGETS_PER_SET` targets.
BINNED_POOL_SETS = 16
#: Targets computed at once per phase of the map (per set of the binned index's pool): the pool
#: :meth:`TargetSampler.sample` serves from.
TARGETS_PER_SET = 4096
_MAX_REJECTION_DRAWS = 1 << 26  # candidates before giving up on an (almost) empty support


@njit(cache=True, parallel=True, nogil=True)
def in_support(m: Medium, x: np.ndarray) -> np.ndarray:
    """sigma_t(x_i) > 0 for world points x (n, 3) (parallel; elementwise, so thread-count independent)."""
    out = np.empty(x.shape[0], dtype=np.bool_)
    for i in prange(x.shape[0]):
        out[i] = extinction_at(m, x[i, 0], x[i, 1], x[i, 2]) > 0.0
    return out


@dataclass
class TargetBatch:
    """One batch of network inputs (float32 tensors) and encoded targets, plus the raw estimate."""

    pos: torch.Tensor  # (n, 3) normalized position in [0, 1]^3
    dirs: torch.Tensor  # (n, 2) direction on the unit square
    g: torch.Tensor  # (n, 1)
    target: torch.Tensor  # (n, 3 lights) Eq. 6 encoded Q (each light's part apart with the sampler's lights > 1)
    q: np.ndarray  # (n, 3 lights) float64 Q (decoded units)
    found: np.ndarray  # (n,) photons used per query
    seconds: float  # wall time to draw and estimate this batch


def check_phase_bins(pmap: PhotonMap) -> None:
    """Refuse a map with an empty phase bin: its g would have no target at all."""
    counts = np.bincount(pmap.phase, minlength=len(pmap.phases)) if len(pmap) else np.zeros(len(pmap.phases), int)
    empty = [g for g, c in zip(pmap.phases, counts, strict=True) if c == 0]
    if empty:
        raise InputError("photon map", f"phase bin(s) g = {empty} hold no photons (per phase: "
                         f"{[int(c) for c in counts]}); re-trace with more photons")


def check_map_for_sampling(pmap: PhotonMap, g_sampling: str) -> None:
    """Refuse, in one line, a map the g sampling cannot train from: an empty phase bin, or for ``"window"`` phase
    bins too sparse for a kernel in g (a map of a few phases: fit it with another g sampling)."""
    check_phase_bins(pmap)
    if g_sampling == "window":
        try:
            check_window(pmap.phases, PHASE_WINDOW)
            window_range(pmap.phases, PHASE_WINDOW)
        except InputError as exc:
            raise InputError(exc.what, f"{exc.problem}; or fit this map with --g-sampling discrete") from None


class TargetSampler:
    """Draws training batches and computes their targets (see the module docstring)."""

    def __init__(self, pmap: PhotonMap, medium: Medium, *, k: int = DEFAULT_K, psi: float, seed: int = 0,
                 sampling: str = "box", g_sampling: str = "discrete", per_set: int = TARGETS_PER_SET,
                 lights: int = 1, background: bool = False) -> None:
        if sampling not in SAMPLING_MODES:
            raise InputError("sampling", f"must be one of {SAMPLING_MODES}, got {sampling!r}")
        if g_sampling not in G_SAMPLING_MODES:
            raise InputError("g sampling", f"must be one of {G_SAMPLING_MODES}, got {g_sampling!r}")
        self.g_sampling = g_sampling
        check_map_for_sampling(pmap, g_sampling)
        t0 = time.perf_counter()
        self.pmap, self.medium, self.k, self.psi, self.sampling = pmap, medium, int(k), float(psi), sampling
        self.lights = int(lights)
        # The estimator owns the search structures (weights Phi / sigma_t): build every phase's (or the binned
        # index of every g) once, now.
        if g_sampling == "window":
            self.estimator = PhotonMapEstimator(pmap, medium, k=k, g_window=PHASE_WINDOW, lights=lights)
            self.phases = np.array(window_range(pmap.phases, PHASE_WINDOW))  # the g range: its ends
            self.indices = [self.estimator.binned_index()]
        else:
            self.estimator = PhotonMapEstimator(pmap, medium, k=k, lights=lights)
            self.phases = np.asarray(pmap.phases, dtype=np.float64)
            self.indices = [self.estimator.index(p) for p in range(len(pmap.phases))]
        self._occupied = np.flatnonzero(medium.majorant.ravel() > 0.0)
        if self._occupied.size == 0:
            raise InputError("scene", "the medium is empty (zero extinction everywhere)")
        self._pattern = ball_pattern()
        self.rng = np.random.default_rng([int(seed) & (2**64 - 1), 0])
        self._val_rng = np.random.default_rng([int(seed) & (2**64 - 1), 1])
        self.build_seconds = time.perf_counter() - t0
        self.seconds = 0.0
        self.queries = 0
        self.estimated = 0
        self.per_set = max(1, int(per_set))
        #: Sets of ``per_set`` targets per pool: one per search structure, or BINNED_POOL_SETS of the binned index.
        self.sets = BINNED_POOL_SETS if g_sampling == "window" else len(self.indices)
        self._pool: tuple[np.ndarray, ...] = ()
        self._pool_radius = -1.0
        self._pool_next = 0
        self.background_seconds = 0.0
        #: The worker's numba threads (0: no worker): all but one of the caller's.
        self._worker_threads = numba.get_num_threads() - 1 if background else 0
        self._executor: ThreadPoolExecutor | None = None
        self._ahead: Future | None = None

    def field_phases(self, nodes: int) -> tuple[float, ...]:
        """The phase set the field records (the nodes of its phase features,
        :class:`photon_fields.models_spec.encoding.FieldConfig`): the map's phases, or with windows ``nodes`` g
        evenly spread over the window range (:attr:`photon_fields.train.fit.presets.Preset.phase_nodes`)."""
        if self.g_sampling != "window":
            return tuple(float(g) for g in self.pmap.phases)
        return tuple(round(float(g), 6) for g in np.linspace(self.phases[0], self.phases[-1], max(2, int(nodes))))

    # --- sampling -------------------------------------------------------------------------------------

    def _positions(self, rng: np.random.Generator, n: int, mode: str) -> np.ndarray:
        m = self.medium
        if mode == "box":
            return m.bmin + rng.random((n, 3)) * m.bsize
        # Uniform over the support by rejection, drawing candidates only in macrocells whose majorant is > 0
        # (the majorant bounds sigma_t, so the support lies inside them; all macrocells have the same
        # size): a uniform cell, then a uniform point in it, kept if sigma_t > 0. On vortex this accepts
        # ~1 in 4 candidates instead of 1 in 50 from the whole box.
        cells = np.asarray(m.majorant.shape)
        parts: list[np.ndarray] = []
        have = drawn = 0
        rate = 0.25
        while have < n:
            chunk = int(min(max(1.2 * (n - have) / rate, 1024), 1 << 22))
            c = np.stack(np.unravel_index(self._occupied[rng.integers(0, self._occupied.size, chunk)], cells), 1)
            cand = m.bmin + (c + rng.random((chunk, 3))) / cells * m.bsize
            keep = cand[in_support(m, cand)]
            parts.append(keep)
            have += keep.shape[0]
            drawn += chunk
            rate = max(have / drawn, 1e-3)
            if have < n and drawn >= _MAX_REJECTION_DRAWS:
                raise InputError("scene", f"the medium's support (sigma_t > 0) is too small to sample: {have} "
                                 f"hits in {drawn} points")
        return np.concatenate(parts)[:n]

    def draw(self, rng: np.random.Generator, n: int,
             mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """World positions (n, 3), unit travel directions (n, 3), g (n,) and the indices (n,) of the search
        structures (phases, or the one binned index) whose photons estimate each target."""
        if mode == "visible":
            seen = int(round(VISIBLE_SHARE * n))
            xv, dv = visible_points(self.medium, rng, -(-seen // VISIBLE_REUSE))
            # Copies a pool apart (np.tile, not np.repeat): they fall into different batches.
            x = np.concatenate([np.tile(xv, (VISIBLE_REUSE, 1))[:seen], self._positions(rng, n - seen, "support")])
            d = np.concatenate([np.tile(dv, (VISIBLE_REUSE, 1))[:seen], uniform_directions(rng, n - seen)])
        else:
            x = self._positions(rng, n, mode)
            d = uniform_directions(rng, n)
        if self.g_sampling == "discrete" or len(self.phases) == 1:
            ph = rng.integers(0, len(self.phases), n)
            return x, d, self.phases[ph], ph
        lo, hi = float(np.min(self.phases)), float(np.max(self.phases))
        u = rng.random(n)
        if self.g_sampling == "window":  # arcsine density: more samples towards the ends of the range
            u = 0.5 * (1.0 - np.cos(np.pi * u))
            return x, d, lo + u * (hi - lo), np.zeros(n, dtype=np.int64)  # one structure: g's own kernel
        g = lo + u * (hi - lo)
        if self.g_sampling == "mixed":  # half of the samples exactly at a phase
            at_phase = rng.random(n) < 0.5
            g[at_phase] = self.phases[rng.integers(0, len(self.phases), int(at_phase.sum()))]
        return x, d, g, self.sources(rng, g)

    def sources(self, rng: np.random.Generator, g: np.ndarray) -> np.ndarray:
        """The indices (n,) of the phases whose photons estimate the targets at g (n,) in the continuous and
        mixed modes: one of the two next to g, chosen with the tent weights (so the targets' mean is their
        interpolation)."""
        order = np.argsort(self.phases, kind="stable")
        sg = self.phases[order]
        i = np.clip(np.searchsorted(sg, g, side="right") - 1, 0, len(sg) - 2)
        t = (g - sg[i]) / (sg[i + 1] - sg[i])
        return order[np.where(rng.random(g.shape[0]) < t, i + 1, i)]

    # --- targets ------------------------------------------------------------------------------------

    def estimate(self, x: np.ndarray, d: np.ndarray, g: np.ndarray, ph: np.ndarray,
                 radius: float) -> tuple[np.ndarray, np.ndarray]:
        """Q (n, 3 lights) float64 (each light's part apart with ``lights`` > 1) and photons used (n,) at world points
        x (n, 3), directions d (n, 3), phase function coefficients g (n,), from the search structures ph (n,)
        (:meth:`draw`)."""
        n = x.shape[0]
        q = np.zeros((n, 3 * self.lights))
        found = np.zeros(n, dtype=np.int64)
        for p in range(len(self.indices)):
            sel = np.flatnonzero(ph == p)
            if sel.size == 0:
                continue
            xs = np.ascontiguousarray(x[sel])
            est, r, f = indexed_radiance(self.indices[p], xs, np.ascontiguousarray(d[sel]), g[sel], self.k,
                                         float(radius))
            hit = f > 0  # no photon: Q = 0 whatever the support fraction; skip its 64 lookups
            if hit.any():
                est[hit] /= support_fraction(self.medium, np.ascontiguousarray(xs[hit]), r[hit], self._pattern)[:, None]
            q[sel] = est
            found[sel] = f
        return q, found

    def make_batch(self, x: np.ndarray, d: np.ndarray, g: np.ndarray, q: np.ndarray, found: np.ndarray,
                   t0: float) -> TargetBatch:
        """The network's inputs and encoded targets for samples (x, d, g) with estimates q (n, 3), found (n,)."""
        m = self.medium
        return TargetBatch(pos=torch.from_numpy(normalize_position(x, m.bmin, m.bsize)),
                           dirs=torch.from_numpy(direction_input(d)),
                           g=torch.from_numpy(g.astype(np.float32).reshape(-1, 1)),
                           target=torch.from_numpy(encode_radiance(q, self.psi)), q=q, found=found,
                           seconds=time.perf_counter() - t0)

    def _draw_pool(self, size: int, radius: float) -> tuple[tuple[np.ndarray, ...], float, float]:
        """The next ``size`` samples of the training stream and their estimates at ``radius``: ((x, d, g, ph, q,
        found), radius, seconds)."""
        t0 = time.perf_counter()
        x, d, g, ph = self.draw(self.rng, size, self.sampling)
        q, found = self.estimate(x, d, g, ph, radius)
        return (x, d, g, ph, q, found), radius, time.perf_counter() - t0

    def _refill(self, n: int, radius: float) -> None:
        """Install the next pool: a whole number of batches of n, about ``per_set`` per search structure; the
        worker's when it runs (module docstring, "Targets beside the training"), which then starts the one
        after."""
        size = n * max(1, round(self.per_set * self.sets / n))
        if self._ahead is None:
            (x, d, g, ph, q, found), _, _ = self._draw_pool(size, radius)
        else:
            (x, d, g, ph, q, found), drawn_at, seconds = self._ahead.result()
            self._ahead = None
            self.background_seconds += seconds
            if drawn_at != radius:  # the schedule moved on: the same draws, estimated at the radius asked for
                q, found = self.estimate(x, d, g, ph, radius)
        self._pool, self._pool_radius, self._pool_next = (x, d, g, q, found), radius, 0
        self.estimated += x.shape[0]
        if self._worker_threads > 0:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(1, thread_name_prefix="pfn-targets",
                                                    initializer=numba.set_num_threads,
                                                    initargs=(self._worker_threads,))
            self._ahead = self._executor.submit(self._draw_pool, size, radius)

    def close(self) -> None:
        """Stop the worker (after the pool it is computing, which the next refill still takes: the stream stays
        the same); the sampler then computes its pools itself."""
        self._worker_threads = 0
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None
        if self._ahead is not None and self._ahead.cancelled():
            self._ahead = None

    def sample(self, n: int, radius: float) -> TargetBatch:
        """A training batch of n fresh samples with targets at r_max = ``radius`` (box units), from the pool
        (computed when it runs short or the radius changes: module docstring, "Targets ahead")."""
        t0 = time.perf_counter()
        if not self._pool or radius != self._pool_radius or self._pool_next + n > self._pool[0].shape[0]:
            self._refill(n, radius)
        take = slice(self._pool_next, self._pool_next + n)
        self._pool_next += n
        batch = self.make_batch(*(a[take] for a in self._pool), t0)
        self.seconds += batch.seconds
        self.queries += n
        return batch

    def validation_set(self, n: int, radius: float) -> TargetBatch:
        """n held-out samples inside the support (where the renderer queries the field), targets at
        ``radius``; drawn from the validation stream, so they never change the training batches."""
        t0 = time.perf_counter()
        x, d, g, ph = self.draw(self._val_rng, n, "support")
        return self.make_batch(x, d, g, *self.estimate(x, d, g, ph, radius), t0)
