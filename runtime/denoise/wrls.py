"""WRLS: the real-time temporal denoiser of Iglesias-Guitian, Mane and Moon, "Real-Time Denoising of
Volumetric Path Tracing for Direct Volume Rendering", IEEE TVCG 28(7), 2022
(``../shared/papers/vpt_realtime_denoising_wrls.txt``), for any renderer's frame sequence: 1-spp neural or
path-traced orbits, progressive renders, the viewer.

What it does, per frame and per pixel ``j`` (numbers are the paper's equations and sections):

1. **Pixel reconstruction filter** (Sec. 4, Fig. 5; Sec. 6: "a separable Gaussian kernel"): the renderer's
   box-filtered pixels are blurred by a Gaussian of ``reconstruction_sigma`` pixels (pbrt-v4's default Gaussian
   filter, sigma 0.5, radius 1.5: taps at -1, 0, 1; the image extended by its edge pixels), giving the frame
   estimate ``I~_j(t)`` the rest works on; ``Psi``'s bounds (3.) are computed in the same pass.
2. **Reprojection** (Sec. 5.3, "Temporal Coherence of Linear Models"; Sec. 6, "Optical Flow Estimation"): the
   world point pixel ``j`` sees (its depth from :mod:`photon_fields.runtime.denoise.depth`) is projected into the
   previous view, ``q = pi(v_j)`` (:mod:`photon_fields.runtime.denoise.reprojection`); the previous frame's
   state (feature, linear model) is read there, bilinearly over the four pixels around ``q`` that pass the
   depth test. A pixel whose ``q`` is off-screen or behind the previous camera, or whose four pixels all saw a
   different depth (a disocclusion: relative mismatch above ``depth_tolerance``, or one depth finite and the
   other not), restarts: its feature becomes ``I~_j(t)`` and its model the initial one. A static camera
   (``camera=None``, or the previous frame's camera) reads pixel ``j`` itself and needs no depth.
3. **Temporal feature**, Eq. 12: ``z_j(t) = alpha Psi[z_q(t-1), I~_j(t)] + (1 - alpha) I~_j(t)``, where
   ``Psi`` clamps the reprojected history per channel to the min / max of the current frame's
   ``(2 clamp_radius + 1)^2`` neighbourhood (Karis 2014, the paper's [56]); alpha = 0.75 (Sec. 6).
4. **wRLS** (Sec. 5.2-5.3): per pixel a linear model ``I_j = p_j beta_j^T`` (Eq. 5-7) per colour channel with
   predictor ``p = [1, z]`` (d = 4), updated with the a priori error ``e = I~ - p beta^T(t-1)`` (Eq. 8) by
   ``beta(t) = beta(t-1) + q^w e`` (Eq. 9), ``q^w = P p^T / (lambda / w + p P p^T)`` (Eq. 14, the weighted
   form of Eq. 10) and ``P(t) = (P - q^w p P) / lambda`` (Eq. 11), forgetting factor lambda = 0.998. The weight
   of Eq. 13, ``w = exp(-d^2 / h^2)``, ``d = |I~ - z| / (min(|I~|, |z|) + epsilon)`` (RGB norms, h = 0.75),
   gives outliers (fireflies) almost no say. ``P`` depends only on the predictors and ``w``, which all channels
   share, so one ``P`` per pixel serves the three ``beta``. Eq. 14 is evaluated multiplied through by ``w``,
   ``q^w = w P p^T / (lambda + w p P p^T)``: the same vector, and 0 rather than 0/0 when ``w`` underflows. A pixel
   whose samples all get ``w ~ 0`` would grow ``P`` as ``lambda^-t`` ("covariance wind-up"): its trace is capped
   at ``P_MAX_TRACE`` by scaling, which keeps it positive definite.
5. **Spatial filter** (Sec. 5.3, "Spatio-Temporal Denoising Using wRLS"): the output at pixel ``i`` blends the
   predictions of the linear models of its ``(2 window_radius + 1)^2 = 5x5`` neighbours ``k`` at its own
   predictor, ``I^_i = sum_k W_ik p_i beta_k^T / sum_k W_ik``, with a bilateral weight ``W_ik``.

Choices where the paper is silent, and one departure (each measured by ``bench/bench_denoise.py``; the figures are in
docs/rendering.md, "Denoising frame sequences"):

- ``predictor = "history"`` (default): the model's predictor is the clamped reprojected history
  ``Psi[z_q(t-1)]``, not ``z_j(t)``. Eq. 8 read literally (``"feature"``) regresses ``I~_j(t)`` on a feature
  that contains ``(1 - alpha) I~_j(t)`` itself, so least squares learns to predict the frame's own noise (on a
  static pixel the slope tends to ``1 + alpha``, the output's variance to ``(1 + alpha)^2`` times the
  feature's); the history is independent of the new frame's noise: lower error and less flicker.
- The initial model (first frame, restarts): ``beta = [0, e_c]``, which predicts the feature (the output is the
  feature until the data says otherwise), and ``P(0) = prior I`` with ``prior = 0.01``. Radiance is divided by the
  first frame's mean (``scale``), so the prior and ``epsilon`` mean the same at any exposure. Zero coefficients
  with a large ``P(0)``, the textbook start, fit the first noisy frames exactly and stayed worse than the feature
  alone in development runs.
- ``Psi``: the per-channel min / max of the 3x3 neighbourhood of the reconstructed frame.
- The reconstruction filter's width: pbrt-v4's default (without it the error is much higher).
- Bilateral weight: ``W_ik = exp(-r^2 / (2 spatial_sigma^2)) K(d_ik^2 / spatial_bandwidth^2)`` with ``d_ik`` the
  distance of Eq. 13 between the features of ``i`` and ``k`` and ``K(x) = max(0, 1 - x / 3)^3``, the three-term
  approximation of ``exp(-x)`` (no exponential in the 25-neighbour loop, which then vectorizes); results were
  insensitive to ``spatial_sigma`` in [1, inf] and ``spatial_bandwidth`` in [0.25, 2].
- Reprojection reads the state bilinearly; nearest-pixel reads (the paper's ``q`` as an index) drift.

What the weighting buys here: on these scenes the paper's ``h = 0.75`` is a little *worse* than plain RLS
(``bandwidth`` -> inf, w = 1), on path-traced input too: with the small prior the
models stay close to the feature and Eq. 13 mostly drops samples far from it, zero samples included (a 1-spp
sample of 0 is infinitely far in Eq. 13's relative distance), which biases upwards. What it does do is keep an
outlier frame out of the models (``tests/runtime/denoise/test_wrls.py``: a 50x firefly moves the output far less
than under plain RLS or a moving average). The default stays the paper's.

Use:

- Orbits and the viewer: ``denoise(frame, camera=cam)`` with the frame's camera (and its depth, or a ``medium``
  given at construction to compute it, :class:`photon_fields.runtime.denoise.depth.DepthEstimator`); every
  frame must have fresh samples (its own seed), or the noise it averages is the same.
  :func:`photon_fields.runtime.renderers.orbit.render_orbit` takes a ``denoiser``.
- Static camera, e.g. :class:`photon_fields.runtime.renderers.neural.ProgressiveRender`: ``denoise(frame)`` with
  the *accumulated* image ``frame().layers["L"]``: its noise falls as 1 / samples and the output converges with
  it. Fed each frame's new samples instead, the output settles at the feature's noise floor (the feature
  averages about ``(1 + alpha) / (1 - alpha) = 7`` frames; ``bench_denoise.py``'s static-camera rows). The
  reconstruction filter's slight blur stays, so once the accumulation has converged (some tens of frames) show
  it undenoised.

Any renderer's (H, W, 3) float layer works; the depth map is the renderer-independent scene depth.
Deterministic (no random numbers; each pixel is computed by one thread from the previous frame's state, so
thread counts do not change results, which the tests check). Bounded memory, allocated once: two (H, W, 25)
float32 states, the (29, H, W) planes the spatial filter reads (padded by a few columns), depth and history
weight: ~320 bytes per pixel. Two parallel regions per frame (the kernels of
:mod:`photon_fields.runtime.denoise.wrls_kernels`; the reconstructed frame and Psi's bounds are computed row by row
inside the first, never stored), compiled with fastmath; ``tests/runtime/denoise/test_wrls_reference.py`` holds
them to a float64 reference of the equations. Milliseconds: bench/README.md.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from photon_fields.runtime.denoise.depth import DepthEstimator
from photon_fields.runtime.denoise.reprojection import VIEW_SIZE, pack_view
from photon_fields.runtime.denoise.wrls_kernels import PLANES, STATE, spatial, temporal
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.transport.medium import Medium

if TYPE_CHECKING:
    from photon_fields.runtime.scene.scene import Scene

PREDICTORS = ("history", "feature")


@dataclass(frozen=True)
class WRLSParams:
    """The denoiser's parameters, with the paper's values where it gives them (module docstring)."""

    alpha: float = 0.75  #: Eq. 12's weight of the history (Sec. 6)
    forgetting: float = 0.998  #: lambda of Eq. 10-11, 14 (Sec. 5.2)
    bandwidth: float = 0.75  #: h of Eq. 13 (Sec. 5.3)
    epsilon: float = 1e-4  #: Eq. 13's guard, in units of the first frame's mean radiance
    clamp_radius: int = 1  #: Psi's neighbourhood is (2 r + 1)^2 pixels of the current frame
    window_radius: int = 2  #: the spatial filter's window is (2 r + 1)^2 = 5x5 (Sec. 5.3)
    spatial_sigma: float = 2.0  #: the bilateral weight's spatial Gaussian, pixels
    spatial_bandwidth: float = 0.75  #: the bilateral weight's range bandwidth (on Eq. 13's distance)
    reconstruction_sigma: float = 0.5  #: the pixel reconstruction filter's Gaussian, pixels (0: none)
    prior: float = 0.01  #: P(0) = prior * I for a new model
    predictor: str = "history"  #: "history" (Psi[z_q(t-1)]) or "feature" (z_j(t), Eq. 8 literally)
    depth_tolerance: float = 0.05  #: relative depth mismatch that marks a disocclusion

    def __post_init__(self) -> None:
        checks = {"alpha": (0.0, 1.0, False), "forgetting": (0.0, 1.0, True), "bandwidth": (0.0, math.inf, False),
                  "epsilon": (0.0, math.inf, False), "spatial_sigma": (0.0, math.inf, False),
                  "spatial_bandwidth": (0.0, math.inf, False), "prior": (0.0, math.inf, False),
                  "depth_tolerance": (0.0, math.inf, False)}
        for name, (lo, hi, hi_closed) in checks.items():
            v = getattr(self, name)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and lo < v and (v <= hi if hi_closed
                                                                                        else v < hi)
            if not ok:
                raise InputError(f"WRLS {name}", f"must be a number in ({lo:g}, {hi:g}{']' if hi_closed else ')'}, "
                                 f"got {v!r}")
        v = self.reconstruction_sigma
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 8.0:
            raise InputError("WRLS reconstruction_sigma", f"must be a number of pixels in [0, 8], got {v!r}")
        for name, hi in (("clamp_radius", 8), ("window_radius", 8)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= hi:
                raise InputError(f"WRLS {name}", f"must be an integer in [0, {hi}], got {v!r}")
        if self.predictor not in PREDICTORS:
            raise InputError("WRLS predictor", f"must be one of {', '.join(PREDICTORS)}, got {self.predictor!r}")


# --- the denoiser ----------------------------------------------------------------------------------------


class WRLSDenoiser:
    """The WRLS denoiser for one ``width`` x ``height`` frame sequence (module docstring).

    ``params`` (default :class:`WRLSParams`), overridden by keyword (``WRLSDenoiser(w, h, alpha=0.8)``).
    ``medium``: the scene's medium (``scene.medium()``), from which depth maps are computed when a moving
    camera comes without one; or ``depth_estimator``, one already made for it (depth maps do not depend on the
    frame size, so denoisers of several sizes can share one). :meth:`denoise` keeps the per-pixel state between
    calls; :meth:`reset` forgets it (a cut). ``timings_ms`` holds the last call's stage times (depth,
    temporal: stages 1-4, spatial)."""

    def __init__(self, width: int, height: int, params: WRLSParams | None = None, *, medium: Medium | None = None,
                 depth_estimator: DepthEstimator | None = None, **overrides: Any) -> None:
        for label, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 16384:
                raise InputError(f"WRLS denoiser {label}", f"must be an integer in [1, 16384], got {v!r}")
        known = {f.name for f in fields(WRLSParams)}
        unknown = sorted(set(overrides) - known)
        if unknown:
            raise InputError("WRLS denoiser", f"unknown parameter(s) {', '.join(unknown)}; "
                             f"known: {', '.join(sorted(known))}")
        self.width, self.height = int(width), int(height)
        self.params = replace(params or WRLSParams(), **overrides)
        if depth_estimator is None and medium is not None:
            depth_estimator = DepthEstimator(medium)
        self.depth_estimator = depth_estimator
        shape = (self.height, self.width)
        self._prev = np.zeros((*shape, STATE), np.float32)
        self._cur = np.zeros((*shape, STATE), np.float32)
        p = self.params
        # Padded by the window radius (at least 2 columns: the spatial kernel's default path reads 2 each side).
        pad = max(p.window_radius, 2)
        self._planes = np.zeros((PLANES, self.height, self.width + 2 * pad), np.float32)
        #: (H, W) float32 after each frame: the bilinear weight of the history each pixel found (1: all four
        #: pixels around q; 0: it restarted: first frame, off-screen, disoccluded).
        self.history_weight = np.zeros(shape, np.float32)
        self._prev_depth = np.full(shape, -1.0, np.float32)  # kernel format: -1 is background
        r = max(1, math.floor(3.0 * p.reconstruction_sigma)) if p.reconstruction_sigma > 0 else 0
        taps = np.exp(-0.5 * (np.arange(-r, r + 1) / p.reconstruction_sigma) ** 2) if r else np.ones(1)
        self._taps = (taps / taps.sum()).astype(np.float32)
        rr = np.arange(-p.window_radius, p.window_radius + 1) ** 2
        self._spatial_w = np.exp(-(rr[:, None] + rr[None, :]) / (2.0 * p.spatial_sigma**2)).astype(np.float32)
        self.timings_ms: dict[str, float] = {}
        self.reset()

    def reset(self) -> None:
        """Forget the history: the next frame starts every pixel's feature and model afresh."""
        self.frames = 0
        self.scale = 1.0
        self._view: np.ndarray | None = None
        self._depth_view: np.ndarray | None = None  # the view self._prev_depth belongs to

    def denoise(self, frame: np.ndarray, *, camera: Camera | None = None,
                depth: np.ndarray | None = None) -> np.ndarray:
        """The denoised (H, W, 3) float32 image of ``frame`` (H, W, 3), the next frame of the sequence.

        ``camera``: the frame's camera (None: the same view as before). When it differs from the previous
        frame's, the history is reprojected with ``depth`` ((H, W) distances along the pixels' centre rays, inf
        for background, :meth:`photon_fields.runtime.denoise.depth.DepthEstimator.depth`), computed from the
        ``medium`` given at construction when omitted."""
        t0 = time.perf_counter()
        frame = self._check_frame(frame)
        view = self._check_camera(camera)
        moving = self.frames > 0 and view is not None and self._view is not None and not np.array_equal(view,
                                                                                                         self._view)
        t_depth = 0.0
        if depth is not None:
            kdepth = self._check_depth(depth)
        elif not moving and (view is None or (self._depth_view is not None
                                              and np.array_equal(view, self._depth_view))):
            kdepth = self._prev_depth  # the view of the last depth map: nothing to recompute
        elif self.depth_estimator is not None and view is not None:
            td = time.perf_counter()
            kdepth = self._kernel_depth(self.depth_estimator.depth(camera))
            t_depth = time.perf_counter() - td
        elif moving:
            raise InputError("WRLS denoiser depth", "a moving camera needs a depth map: pass depth= or make the "
                             "denoiser with medium=scene.medium()")
        else:
            kdepth = np.full((self.height, self.width), -1.0, np.float32)  # nothing known: all background
        if self.frames == 0:
            mean = float(np.mean(frame, dtype=np.float64))
            self.scale = mean if mean > 0.0 else 1.0
        p = self.params
        timings = {"depth": t_depth * 1e3}
        t = time.perf_counter()
        blank = np.zeros(VIEW_SIZE)
        temporal(frame, self._taps, np.float32(1.0 / self.scale), p.clamp_radius, self._prev, self._cur,
                 self._planes, self.history_weight, self.frames > 0, moving, view if view is not None else blank,
                 self._view if self._view is not None else blank, kdepth, self._prev_depth, p.alpha, p.forgetting,
                 p.bandwidth, p.epsilon, p.prior, p.predictor == "history", p.depth_tolerance)
        timings["temporal"] = (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        out = np.empty((self.height, self.width, 3), np.float32)
        spatial(self._planes, self._spatial_w, np.float32(1.0 / (3.0 * p.spatial_bandwidth**2)),
                np.float32(p.epsilon), self.scale, out)
        timings["spatial"] = (time.perf_counter() - t) * 1e3
        self._prev, self._cur = self._cur, self._prev
        if kdepth is not self._prev_depth:
            self._prev_depth[...] = kdepth
            self._depth_view = view
        if view is not None:
            self._view = view
        self.frames += 1
        timings["total"] = (time.perf_counter() - t0) * 1e3
        self.timings_ms = timings
        return out

    # --- input checks: one line naming the input and the problem ---

    def _size(self) -> str:
        return f"{self.width}x{self.height}"

    def _check_frame(self, frame: Any) -> np.ndarray:
        a = np.asarray(frame)
        if a.ndim != 3 or a.shape[2] != 3 or not np.issubdtype(a.dtype, np.number):
            raise InputError("WRLS denoiser frame", f"must be an (H, W, 3) RGB array, got shape {a.shape}")
        if a.shape[:2] != (self.height, self.width):
            raise InputError("WRLS denoiser frame", f"is {a.shape[1]}x{a.shape[0]} but the denoiser was made for "
                             f"{self._size()} frames (make a new WRLSDenoiser for another size)")
        a = np.ascontiguousarray(a, dtype=np.float32)
        if not np.isfinite(a).all():
            raise InputError("WRLS denoiser frame", "has NaN or infinite values")
        return a

    def _check_camera(self, camera: Camera | None) -> np.ndarray | None:
        if camera is None:
            return None
        if not isinstance(camera, Camera):
            raise InputError("WRLS denoiser camera", f"must be a Camera, got {type(camera).__name__}")
        if (camera.width, camera.height) != (self.width, self.height):
            raise InputError("WRLS denoiser camera", f"is {camera.width}x{camera.height} but the frames are "
                             f"{self._size()}")
        return pack_view(camera)

    def _check_depth(self, depth: Any) -> np.ndarray:
        a = np.asarray(depth)
        if a.shape != (self.height, self.width) or not np.issubdtype(a.dtype, np.number):
            raise InputError("WRLS denoiser depth", f"must be an (H, W) = ({self.height}, {self.width}) array of "
                             f"distances, got shape {a.shape}")
        a = np.asarray(a, dtype=np.float32)
        if np.isnan(a).any() or (a <= 0).any():
            raise InputError("WRLS denoiser depth", "must be positive distances (inf for background), "
                             "found NaN or values <= 0")
        return self._kernel_depth(a)

    @staticmethod
    def _kernel_depth(depth: np.ndarray) -> np.ndarray:
        """The kernels' depth format: infinity (background) as -1 (they are compiled with fastmath)."""
        return np.where(np.isinf(depth), np.float32(-1.0), depth).astype(np.float32)


def for_scene(scene: Scene, **overrides: Any) -> WRLSDenoiser:
    """A denoiser for frame sequences of ``scene``: its camera's size, depth maps from its medium (the
    ``sequence`` factory of ``pfn-render --denoise wrls``, :mod:`photon_fields.runtime.denoise.registry`)."""
    return WRLSDenoiser(scene.camera.width, scene.camera.height, medium=scene.medium(), **overrides)
