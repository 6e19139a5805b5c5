"""The photon-map radiance estimate (paper Eq. 5): the ground truth the neural field is trained on, and
(:mod:`photon_fields.runtime.renderers.photon_mapped`) the paper's photon-mapping baseline renderer.

Parameters
----------
k : int >= 2 (default 1024)
    Photons per estimate (the paper's K).
radius : float (default ``DEFAULT_RADIUS`` = 0.05)
    Maximum search radius r_max in world units, i.e. as a fraction of the volume box's longest side
    (the world box has longest side 1, see :mod:`photon_fields.runtime.scene.volume`). 0.05 is 5 % of the box, about
    5 voxels of a 96^3 volume.

What is estimated. Photons are stored at real collisions (density proportional to sigma_t times the
fluence) with the power they arrive with (``photon_fields.train.photons.tracing``). Weighting each photon by
``1 / sigma_t`` at its own position turns the collision density into the incident radiance (a map traced with a
record floor q also holds records at null collisions, and its density is max(sigma_t, q majorant) times the
fluence: that is then the divisor, :func:`photon_fields.runtime.photons.photon_path.record_densities`), so

    Q(x, d, g) = sum_n p_g(-omega_n . d) * (Phi_n / sigma_t(x_n)) / (4/3 pi r^3)

(the sum over the photons strictly inside the ball, whose radius is the K-th photon's distance: that photon
is left out, which makes the estimate unbiased at any K, :mod:`photon_fields.runtime.photons.knn_radiance`)
estimates the in-scattered radiance that has already scattered at least once, *before* the albedo at
x, which the renderer applies from the transfer function at full resolution
(:mod:`photon_fields.runtime.wavefront.first_interaction`).

Boundary correction. Photons only exist where sigma_t > 0, so near a surface of the medium (a cloud's
edge, the box's faces) part of the search ball is empty and the plain estimate is biased low: by ~6 %
over a whole image of a smooth thin medium at r = 0.05 (measured, see tests/runtime/photons/test_photon_estimate.py).
We divide instead by the volume of the ball's part inside the medium's support, f * 4/3 pi r^3, with
f the fraction of ``SUPPORT_SAMPLES`` fixed, evenly spread points of the ball (the query point is
one of them) where sigma_t > 0. The 1 / sigma_t weights make the photons an estimate of the
radiance integrated over the support, so this is the matching normalization; it costs a few dozen
volume lookups per query, small next to the K-photon search.

The search itself (grid, adaptive radius, r = r_max when fewer than K photons are found) is
:mod:`photon_fields.runtime.photons.knn`. The estimate is phase-selective: only photons traced with
the queried g are used, so g must be one of the map's phases; or, with ``g_window`` = h, a map traced in narrow
phase bins answers any g from the bins within h of it, weighted by a triangular kernel
(:mod:`photon_fields.runtime.photons.phase_window`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.photons.knn_radiance import indexed_radiance
from photon_fields.runtime.photons.phase_window import check_window, window_weights
from photon_fields.runtime.photons.photon_grid import TARGET_OCCUPANCY, PhotonIndex, build_photon_index
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.photons.photon_path import record_densities
from photon_fields.runtime.scene.light_rescale import rescale_note, scene_rescale
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.transport.medium import Medium, extinction_at

DEFAULT_K = 1024
DEFAULT_RADIUS = 0.05
SUPPORT_SAMPLES = 64
#: Photons of one kernel in g per cell of the binned index (:meth:`PhotonMapEstimator.binned_index`): 4x a plain
#: grid's :data:`photon_fields.runtime.photons.photon_grid.TARGET_OCCUPANCY`, since a search reads each cell's
#: kernel bins as a span of its own rather than a row of cells as one; 1x-8x measured within 10 % (bench/README.md).
KERNEL_OCCUPANCY = 4 * TARGET_OCCUPANCY
#: Photons per lookup of sigma_t at the photons (:meth:`PhotonMapEstimator._photon_sigma`): 24 MB of positions.
_SIGMA_CHUNK = 1 << 20


def ball_pattern(n: int = SUPPORT_SAMPLES) -> np.ndarray:
    """(n, 3) deterministic points evenly filling the unit ball: its centre, then an R3 low-discrepancy
    sequence (Roberts 2018) in the cube, kept where inside the ball."""
    phi = 1.2207440846057596  # plastic-number generalization of the golden ratio in 3-D
    alpha = np.array([1 / phi, 1 / phi**2, 1 / phi**3])
    pts = [np.zeros(3)]
    i = 0
    while len(pts) < n:
        i += 1
        p = 2.0 * ((0.5 + alpha * i) % 1.0) - 1.0
        if p @ p <= 1.0:
            pts.append(p)
    return np.array(pts)


@njit(cache=True, parallel=True, nogil=True)
def support_fraction(m: Medium, x: np.ndarray, r: np.ndarray, pattern: np.ndarray) -> np.ndarray:
    """Fraction of the ball (x_i, r_i) inside the medium's support (sigma_t > 0), x (n, 3)."""
    n = x.shape[0]
    out = np.empty(n)
    for i in prange(n):
        inside = 0
        for j in range(pattern.shape[0]):
            px = x[i, 0] + r[i] * pattern[j, 0]
            py = x[i, 1] + r[i] * pattern[j, 1]
            pz = x[i, 2] + r[i] * pattern[j, 2]
            lo = (px < m.bmin[0]) or (py < m.bmin[1]) or (pz < m.bmin[2])
            hi = (px > m.bmin[0] + m.bsize[0]) or (py > m.bmin[1] + m.bsize[1]) or (pz > m.bmin[2] + m.bsize[2])
            if not (lo or hi) and extinction_at(m, px, py, pz) > 0.0:
                inside += 1
        out[i] = max(inside, 1) / pattern.shape[0]
    return out


@njit(cache=True)
def _gather_bins(in_bins: np.ndarray, scale: np.ndarray, phase: np.ndarray, position: np.ndarray,
                 direction: np.ndarray, power: np.ndarray, sigma: np.ndarray,
                 light: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The photons whose phase bin is in ``in_bins``, in the map's order: positions (float64), directions,
    weights (power * scale[bin]) / sigma (the record density: sigma_t, or max(sigma_t, q majorant) with a record
    floor), in that order of operations (with scale 1, bit for bit the single-phase weights), and their lights
    (``light`` of the map, or an empty array for none). One pass instead of a boolean-mask gather per array (0.7 s of
    a 1M map's 17 window indices). Photons sit where sigma_t > 0; the 1e-12 floor only guards a map traced with
    another transfer function, which the fingerprint check normally refuses."""
    n = 0
    for i in range(phase.shape[0]):
        n += in_bins[phase[i]]
    pos = np.empty((n, 3))
    dirs = np.empty((n, 3), dtype=direction.dtype)
    weights = np.empty((n, 3))
    lights = np.empty(n if light.shape[0] else 0, dtype=np.uint8)
    j = 0
    for i in range(phase.shape[0]):
        b = phase[i]
        if not in_bins[b]:
            continue
        inv = max(sigma[i], 1e-12)
        for c in range(3):
            pos[j, c] = position[i, c]
            dirs[j, c] = direction[i, c]
            weights[j, c] = (np.float64(power[i, c]) * scale[b]) / inv
        if light.shape[0]:
            lights[j] = light[i]
        j += 1
    return pos, dirs, weights, lights


@njit(cache=True)
def _photon_weights(power: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Phi / sigma (the record density) per photon, float32 (n, 3): :func:`_gather_bins`' weights with scale 1, in
    its order of operations, without its float64 copies of the whole map."""
    out = np.empty(power.shape, dtype=np.float32)
    for i in range(power.shape[0]):
        inv = max(sigma[i], 1e-12)
        for c in range(3):
            out[i, c] = np.float64(power[i, c]) / inv
    return out


class PhotonMapEstimator:
    """Q(x, d, g) from a photon map: an :class:`photon_fields.runtime.wavefront.first_interaction.IndirectEstimator`.

    ``g_window`` None: g must be one of the map's phases (the paper). A half-width h: any g with a phase bin
    within h, from the triangular kernel in g over the map's bins (module docstring). ``lights`` 1: Q (3, n); or,
    for a map that records each photon's light (``pmap.light_count`` of them), each light's part apart
    (3 lights, n): light l's RGB in rows 3 l .. 3 l + 2, summing to the estimate with ``lights`` 1 (the training
    targets of a field with one output per light)."""

    def __init__(self, pmap: PhotonMap, medium: Medium, *, k: int = DEFAULT_K, radius: float = DEFAULT_RADIUS,
                 g_window: float | None = None, lights: int = 1):
        if k < 2:
            raise InputError("k", f"must be >= 2 (the K-th photon only sets the radius), got {k}")
        if not (radius > 0 and np.isfinite(radius)):
            raise InputError("radius", f"must be a positive number (world units), got {radius}")
        if g_window is not None:
            check_window(pmap.phases, g_window)
        if lights != 1 and (pmap.light is None or lights != pmap.light_count):
            raise InputError(str(pmap.path or "photon map"), f"does not record which of {lights} lights each photon "
                             "came from (traced before maps recorded it, or for other lights): re-trace it")
        self.pmap, self.medium, self.k, self.radius, self.g_window = pmap, medium, int(k), float(radius), g_window
        self.lights = int(lights)
        self._indices: dict[int, PhotonIndex] = {}
        self._binned: PhotonIndex | None = None
        self._sigma: np.ndarray | None = None  # the record density at every photon (_photon_sigma)
        self._pattern = ball_pattern()
        self.found: list[np.ndarray] = []  # photons used per query, for statistics

    def _photon_sigma(self) -> np.ndarray:
        """The record density per unit fluence at every photon of the map (n,): sigma_t, or with the map's record
        floor max(sigma_t, floor majorant) (:func:`photon_fields.runtime.photons.photon_path.record_densities`),
        looked up once for all the search structures (a photon is in the kernel of ~7 windows), in chunks of
        :data:`_SIGMA_CHUNK` photons (bounded memory)."""
        if self._sigma is None:
            pos, floor = self.pmap.position, self.pmap.record_floor
            self._sigma = np.concatenate([
                record_densities(self.medium, np.ascontiguousarray(pos[i:i + _SIGMA_CHUNK].astype(np.float64).T),
                                 floor)
                for i in range(0, len(pos), _SIGMA_CHUNK)] or [np.zeros(0)])
        return self._sigma

    def _weighted(self, bins: np.ndarray, bin_weights: np.ndarray) -> PhotonIndex:
        """Search structure of the photons of ``bins``, each bin's weighted by ``bin_weights``, with weights
        w_b Phi / sigma_t(x_n)."""
        scale = np.zeros(len(self.pmap.phases))
        scale[bins] = bin_weights
        in_bins = np.zeros(len(self.pmap.phases), dtype=np.bool_)
        in_bins[bins] = True
        light = self.pmap.light if self.lights > 1 else None
        pos, direction, weights, lights = _gather_bins(in_bins, scale, self.pmap.phase, self.pmap.position,
                                                       self.pmap.direction, self.pmap.power, self._photon_sigma(),
                                                       np.zeros(0, np.uint8) if light is None else light)
        return build_photon_index(pos, direction, weights, light=lights, lights=self.lights)

    def index(self, phase: int) -> PhotonIndex:
        """Search structure of one phase's photons, with weights Phi / sigma_t(x_n) (built once)."""
        if phase not in self._indices:
            self._indices[phase] = self._weighted(np.array([phase]), np.ones(1))
        return self._indices[phase]

    def binned_index(self) -> PhotonIndex:
        """The search structure of every photon of the map, sorted by cell and phase bin, with weights
        Phi / sigma_t(x_n): the estimate at any g reads the bins of its own kernel in g, each bin's photons weighted
        by its kernel weight (:func:`photon_fields.runtime.photons.knn_radiance.indexed_radiance`), which is the
        estimate over the union of those bins (module docstring) with the kernel centred at g itself. Needs
        ``g_window``; built once, and holds each photon once (a structure per window held each ~2.2 times)."""
        if self.g_window is None:
            raise ValueError("binned_index needs an estimator with a g_window")
        if self._binned is None:
            phases = np.asarray(self.pmap.phases, dtype=np.float64)
            order = np.argsort(phases, kind="stable")
            rank_of_bin = np.empty(len(phases), dtype=np.uint8)  # a map has at most 256 bins (uint8 phase)
            rank_of_bin[order] = np.arange(len(phases), dtype=np.uint8)
            # Cells sized by the photons of one kernel (bins_per_kernel of the map's), not the whole map's.
            per_kernel = len(window_weights(phases, float(np.median(phases)), self.g_window)[0])
            self._binned = build_photon_index(
                self.pmap.position, self.pmap.direction, _photon_weights(self.pmap.power, self._photon_sigma()),
                light=self.pmap.light if self.lights > 1 else None, lights=self.lights,
                bin_rank=rank_of_bin[self.pmap.phase], bin_g=phases[order], half_width=self.g_window,
                occupancy=KERNEL_OCCUPANCY * len(phases) / max(1, per_kernel))
            self._sigma = None  # in the index now (a single phase's index would look it up again)
        return self._binned

    def window_index(self, g: float) -> PhotonIndex:
        """A plain search structure of g's kernel bins alone, each bin's photons weighted by its kernel weight
        (built on every call, not kept): for tools that look at the photons themselves (a plain KNN query over
        it finds the kernel's neighbours); the estimate reads :meth:`binned_index`. Needs ``g_window``."""
        if self.g_window is None:
            raise ValueError("window_index needs an estimator with a g_window")
        return self._weighted(*window_weights(self.pmap.phases, g, self.g_window))

    def index_for(self, g: float) -> PhotonIndex:
        """The search structure that answers ``g``: the binned index with ``g_window`` (InputError when no bin
        lies within the window), else g's own phase's."""
        if self.g_window is not None:
            window_weights(self.pmap.phases, g, self.g_window)
            return self.binned_index()
        return self.index(self.pmap.phase_index(g, "g"))

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        index = self.index_for(g)
        xq = np.ascontiguousarray(x.T)
        est, r, found = indexed_radiance(index, xq, np.ascontiguousarray(d.T), g, self.k, self.radius)
        self.found.append(found)
        est /= support_fraction(self.medium, xq, np.where(np.isfinite(r), r, 0.0), self._pattern)[:, None]
        return np.ascontiguousarray(est.T)


def map_for_scene(pmap: PhotonMap, scene: Scene, force: bool = False) -> tuple[PhotonMap, str | None, str | None]:
    """``pmap`` for rendering ``scene``: (map, warning, note). A map traced for the scene's lights with another flux
    (a power or colour edit, :mod:`photon_fields.runtime.scene.light_rescale`; the map records its lights; one
    light's among several when it records each photon's light) is rescaled, exactly, and ``note`` says so; any
    other mismatch as :func:`check_map_matches_scene` (refused, or with ``force`` the map as it is and the
    warning)."""
    if pmap.scene_fingerprint != scene.fingerprint():
        scale = scene_rescale(pmap.scene_parts, pmap.lights, scene.fingerprint_parts(), scene.light_identities(),
                              pmap.light_count)
        if scale is not None:
            return pmap.rescaled(scale, scene), None, rescale_note(scale, "photon map")
    return pmap, check_map_matches_scene(pmap, scene, force), None


def check_map_matches_scene(pmap: PhotonMap, scene: Scene, force: bool = False) -> str | None:
    """Refuse a map traced for another scene, naming what differs (volume, transfer function, lights); with
    ``force``, return that as a one-line warning instead (the caller shows it: L_i will be wrong). None
    when the map was traced for ``scene``."""
    if pmap.scene_fingerprint == scene.fingerprint():
        return None
    name = str(pmap.path) if pmap.path is not None else "photon map"
    other = pmap.mismatch(scene.fingerprint_parts())
    if not force:
        raise InputError(name, f"was traced for {other}; re-trace it, or force to use it anyway")
    return f"{name} was traced for {other}; L_i will be wrong"
