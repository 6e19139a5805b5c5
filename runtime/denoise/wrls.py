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

Choices where the paper is silent, and one departure; figures are mean rel. L2 against the converged image on
the neural renderer's 1-spp orbits of ``bench/bench_denoise.py`` (256x256, 1 degree per frame, after 16 frames;
vortex / blobs / shell / head), bench/README.md:

- ``predictor = "history"`` (default): the model's predictor is the clamped reprojected history
  ``Psi[z_q(t-1)]``, not ``z_j(t)``. Eq. 8 read literally (``"feature"``) regresses ``I~_j(t)`` on a feature
  that contains ``(1 - alpha) I~_j(t)`` itself, so least squares learns to predict the frame's own noise (on a
  static pixel the slope tends to ``1 + alpha``, the output's variance to ``(1 + alpha)^2`` times the
  feature's); the history is independent of the new frame's noise. 0.148 / 0.064 / 0.139 / 0.105 against
  0.154 / 0.072 / 0.153 / 0.108 literally, with 10-30 % less flicker.
- The initial model (first frame, restarts): ``beta = [0, e_c]``, which predicts the feature (the output is the
  feature until the data says otherwise), and ``P(0) = prior I`` with ``prior = 0.01``. Radiance is divided by the
  first frame's mean (``scale``), so the prior and ``epsilon`` mean the same at any exposure. Zero coefficients
  with a large ``P(0)``, the textbook start, fit the first noisy frames exactly and stayed worse than the feature
  alone in development runs.
- ``Psi``: the per-channel min / max of the 3x3 neighbourhood of the reconstructed frame.
- The reconstruction filter's width: pbrt-v4's default; without it 0.198 / 0.086 / 0.257 / 0.117.
- Bilateral weight: ``W_ik = exp(-r^2 / (2 spatial_sigma^2)) K(d_ik^2 / spatial_bandwidth^2)`` with ``d_ik`` the
  distance of Eq. 13 between the features of ``i`` and ``k`` and ``K(x) = max(0, 1 - x / 3)^3``, the three-term
  approximation of ``exp(-x)`` (no exponential in the 25-neighbour loop, which then vectorizes); results were
  insensitive to ``spatial_sigma`` in [1, inf] and ``spatial_bandwidth`` in [0.25, 2].
- Reprojection reads the state bilinearly; nearest-pixel reads (the paper's ``q`` as an index) drift.

What the weighting buys here: on these scenes the paper's ``h = 0.75`` is 1-10 % *worse* than plain RLS
(``bandwidth`` -> inf, w = 1: 0.142 / 0.062 / 0.126 / 0.104), on path-traced input too: with the small prior the
models stay close to the feature and Eq. 13 mostly drops samples far from it, zero samples included (a 1-spp
sample of 0 is infinitely far in Eq. 13's relative distance), which biases upwards. What it does do is keep an
outlier frame out of the models (``tests/runtime/denoise/test_wrls.py``: a 50x firefly moves the output 4x less
than plain RLS and 20x less than a moving average). The default stays the paper's.

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
float32 states, the (29, H, W) planes the spatial filter reads, the (9, H, W) reconstructed frame and clamp
bounds, depth and history weight: ~360 bytes per pixel, 94 MB at 512x512. Three parallel regions per frame
(prepare, temporal, spatial); the kernels are compiled with fastmath. Milliseconds: bench/README.md.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numba import njit, prange

from photon_fields.runtime.denoise.depth import DepthEstimator
from photon_fields.runtime.denoise.reprojection import VIEW_SIZE, pack_view, reproject_pixel
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.camera import Camera
from photon_fields.runtime.transport.medium import Medium

PREDICTORS = ("history", "feature")

# Per-pixel state (float32, (H, W, STATE), the last axis contiguous for the bilinear reads of the reprojection):
# the feature z (3), the coefficients beta (3 channels x 4: intercept, slopes on the predictor's three colours)
# and the upper triangle of the symmetric 4x4 P, row by row (10). The spatial filter reads planes ((PLANES, H, W):
# its loops over x vectorize): z and beta at the same indices, |z| and the predictor's colours.
_Z, _B, _P = 0, 3, 15
STATE = 25
_N, _F = 25, 26
PLANES = 29
# The kernels are compiled with fastmath (no NaN, no infinity: min / max become single instructions, loops
# vectorize); so frames are checked finite first, and background depths are -1 inside the kernels, not inf.
_FAST = True
P_MAX_TRACE = 1e6  # the cap on trace(P) against covariance wind-up (in _temporal)


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


# --- kernels -------------------------------------------------------------------------------------------


@njit(cache=True, parallel=True, fastmath=_FAST)
def _prepare(frame: np.ndarray, taps: np.ndarray, inv_scale: np.float32, clamp_r: int, prep: np.ndarray) -> None:
    """Stage 1 and Psi's bounds, as planes: ``prep[c]`` the frame through the separable Gaussian pixel
    reconstruction filter (weights ``taps``, summing to 1, the image extended by its edge pixels) in units of
    the first frame's mean radiance, ``prep[3 + c]`` / ``prep[6 + c]`` the min / max of ``prep[c]`` over the
    ``(2 clamp_r + 1)^2`` neighbourhood. One output row at a time: the rows it needs are deinterleaved into
    padded buffers, after which every loop runs over contiguous x and vectorizes."""
    height, width, _ = frame.shape
    r = taps.shape[0] // 2
    nrow = 2 * (clamp_r + r) + 1
    for y in prange(height):
        rows = np.empty((nrow, width + 2 * r), dtype=np.float32)  # input rows y - clamp_r - r ..., padded
        filt = np.empty((2 * clamp_r + 1, width + 2 * clamp_r), dtype=np.float32)  # filtered rows, padded
        hrow = np.empty((nrow, width), dtype=np.float32)
        hmin = np.empty((2 * clamp_r + 1, width), dtype=np.float32)
        hmax = np.empty((2 * clamp_r + 1, width), dtype=np.float32)
        tmp = np.empty(width, dtype=np.float32)
        for c in range(3):
            for j in range(nrow):
                yi = min(max(y - clamp_r - r + j, 0), height - 1)
                row = rows[j]
                for x in range(width):
                    row[r + x] = frame[yi, x, c] * inv_scale
                for k in range(r):
                    row[k] = row[r]
                    row[r + width + k] = row[r + width - 1]
                h = hrow[j]
                for x in range(width):
                    h[x] = 0.0
                for k in range(2 * r + 1):
                    tk = taps[k]
                    src = row[k:k + width]
                    for x in range(width):
                        h[x] += tk * src[x]
            for j in range(2 * clamp_r + 1):
                f = filt[j, clamp_r:clamp_r + width]
                for x in range(width):
                    f[x] = 0.0
                for k in range(2 * r + 1):
                    tk = taps[k]
                    src = hrow[j + k]
                    for x in range(width):
                        f[x] += tk * src[x]
                fr = filt[j]
                for k in range(clamp_r):
                    fr[k] = fr[clamp_r]
                    fr[clamp_r + width + k] = fr[clamp_r + width - 1]
            centre = filt[clamp_r, clamp_r:clamp_r + width]
            out = prep[c, y]
            for x in range(width):
                out[x] = centre[x]
            # Psi's bounds, separably: per filtered row the min / max over the horizontal window, then over the
            # rows. Every loop writes one array from two others (a form LLVM vectorizes: an in-place
            # lo[x] = min(lo[x], v) does not), ping-ponging between buffers.
            for j in range(2 * clamp_r + 1):
                _window_extreme(filt[j], clamp_r, width, hmin[j], tmp, True)
                _window_extreme(filt[j], clamp_r, width, hmax[j], tmp, False)
            _rows_extreme(hmin, prep[3 + c, y], tmp, True)
            _rows_extreme(hmax, prep[6 + c, y], tmp, False)


@njit(cache=True, inline="always")
def _extreme2(out: np.ndarray, a: np.ndarray, b: np.ndarray, lowest: bool) -> None:
    """out = elementwise min (``lowest``) or max of a and b."""
    if lowest:
        for x in range(out.shape[0]):
            out[x] = min(a[x], b[x])
    else:
        for x in range(out.shape[0]):
            out[x] = max(a[x], b[x])


@njit(cache=True, inline="always")
def _window_extreme(row: np.ndarray, c: int, width: int, out: np.ndarray, tmp: np.ndarray, lowest: bool) -> None:
    """out[x] = min / max of row[x : x + 2c + 1] (row padded by c on both sides)."""
    out[:] = row[0:width]
    for k in range(1, 2 * c + 1):
        tmp[:] = out
        _extreme2(out, tmp, row[k:k + width], lowest)


@njit(cache=True, inline="always")
def _rows_extreme(rows: np.ndarray, out: np.ndarray, tmp: np.ndarray, lowest: bool) -> None:
    """out[x] = min / max over the rows of ``rows``."""
    out[:] = rows[0]
    for j in range(1, rows.shape[0]):
        tmp[:] = out
        _extreme2(out, tmp, rows[j], lowest)


@njit(cache=True, inline="always")
def _tap_ok(prev_depth: np.ndarray, tx: int, ty: int, dist: float, tol: float) -> bool:
    """Pixel ``(tx, ty)`` of the previous frame is on-screen and saw the reprojected point: both background
    (depth <= 0, the kernels' code for infinity), or both finite within ``tol * dist``."""
    height, width = prev_depth.shape
    if tx < 0 or tx >= width or ty < 0 or ty >= height:
        return False
    pd = prev_depth[ty, tx]
    if dist <= 0.0:
        return pd <= 0.0
    return pd > 0.0 and abs(pd - dist) <= tol * dist


@njit(cache=True, inline="always")
def _gather(prev: np.ndarray, prev_depth: np.ndarray, qx: float, qy: float, dist: float, tol: float,
            hist: np.ndarray) -> float:
    """Bilinear read of the previous state at image-plane point ``(qx, qy)`` over the pixels whose depth
    matches ``dist`` (:func:`_tap_ok`) into ``hist``, renormalized; returns the weight found (0: no history)."""
    sx = qx - 0.5
    sy = qy - 0.5
    bx = int(math.floor(sx))
    by = int(math.floor(sy))
    fx = sx - bx
    fy = sy - by
    w00 = (1.0 - fx) * (1.0 - fy) if _tap_ok(prev_depth, bx, by, dist, tol) else 0.0
    w10 = fx * (1.0 - fy) if _tap_ok(prev_depth, bx + 1, by, dist, tol) else 0.0
    w01 = (1.0 - fx) * fy if _tap_ok(prev_depth, bx, by + 1, dist, tol) else 0.0
    w11 = fx * fy if _tap_ok(prev_depth, bx + 1, by + 1, dist, tol) else 0.0
    wsum = w00 + w10 + w01 + w11
    if wsum <= 0.0:
        return 0.0
    inv = 1.0 / wsum
    w00 *= inv
    w10 *= inv
    w01 *= inv
    w11 *= inv
    # Taps without weight are read at a valid neighbour's index (never out of bounds), times 0.
    x0 = bx if w00 > 0.0 or w01 > 0.0 else bx + 1
    x1 = bx + 1 if w10 > 0.0 or w11 > 0.0 else bx
    y0 = by if w00 > 0.0 or w10 > 0.0 else by + 1
    y1 = by + 1 if w01 > 0.0 or w11 > 0.0 else by
    for k in range(STATE):
        hist[k] = (w00 * prev[y0, x0, k] + w10 * prev[y0, x1, k]) + (w01 * prev[y1, x0, k] + w11 * prev[y1, x1, k])
    return wsum


@njit(cache=True, parallel=True, fastmath=_FAST)
def _temporal(prep: np.ndarray, prev: np.ndarray, cur: np.ndarray, planes: np.ndarray, found_out: np.ndarray,
              have_prev: bool, moving: bool, view_cur: np.ndarray, view_prev: np.ndarray, depth: np.ndarray,
              prev_depth: np.ndarray, alpha: float, lam: float, h: float, eps: float, prior: float,
              history_pred: bool, depth_tol: float) -> None:
    """Stages 2-4 for every pixel: reproject, Eq. 12, Eq. 13, Eq. 14 / 8 / 9 / 11; writes the new state
    ``cur``, the spatial filter's ``planes`` and the history weight found (0: restarted) into ``found_out``."""
    _, height, width = prep.shape
    inv_h2 = 1.0 / (h * h)
    inv_lam = 1.0 / lam
    for y in prange(height):
        hist = np.empty(STATE)
        for x in range(width):
            i0 = prep[0, y, x]
            i1 = prep[1, y, x]
            i2 = prep[2, y, x]
            # Stage 2: reprojection, q = pi(v_j).
            found = 0.0
            if have_prev:
                if moving:
                    qx, qy, dist, front = reproject_pixel(view_cur, view_prev, x, y, float(depth[y, x]))
                    if front and 0.0 <= qx < width and 0.0 <= qy < height:
                        found = _gather(prev, prev_depth, qx, qy, dist, depth_tol, hist)
                else:
                    for k in range(STATE):
                        hist[k] = prev[y, x, k]
                    found = 1.0
            found_out[y, x] = found
            # Stage 3: the temporal feature, Eq. 12, with the clamped history Psi[z_q(t-1), I~_j(t)].
            if found > 0.0:
                c0 = min(max(hist[_Z], prep[3, y, x]), prep[6, y, x])
                c1 = min(max(hist[_Z + 1], prep[4, y, x]), prep[7, y, x])
                c2 = min(max(hist[_Z + 2], prep[5, y, x]), prep[8, y, x])
                z0 = alpha * c0 + (1.0 - alpha) * i0
                z1 = alpha * c1 + (1.0 - alpha) * i1
                z2 = alpha * c2 + (1.0 - alpha) * i2
            else:  # restart: no history, the initial model beta = [0, e_c], P(0) = prior I
                c0, c1, c2 = i0, i1, i2
                z0, z1, z2 = i0, i1, i2
                for k in range(_B, STATE):
                    hist[k] = 0.0
                hist[_B + 1] = 1.0
                hist[_B + 6] = 1.0
                hist[_B + 11] = 1.0
                hist[_P] = prior
                hist[_P + 4] = prior
                hist[_P + 7] = prior
                hist[_P + 9] = prior
            # Stage 4: wRLS. Predictor p = [1, p1, p2, p3] (Eq. 5): the clamped history ("history") or z_j(t).
            if history_pred:
                p1, p2, p3 = c0, c1, c2
            else:
                p1, p2, p3 = z0, z1, z2
            # Eq. 13.
            ni = math.sqrt(i0 * i0 + i1 * i1 + i2 * i2)
            nz = math.sqrt(z0 * z0 + z1 * z1 + z2 * z2)
            den = min(ni, nz) + eps
            w = math.exp(-((i0 - z0) ** 2 + (i1 - z1) ** 2 + (i2 - z2) ** 2) / (den * den) * inv_h2)
            # P p^T with P's upper triangle [00 01 02 03 11 12 13 22 23 33].
            s00, s01, s02, s03 = hist[_P], hist[_P + 1], hist[_P + 2], hist[_P + 3]
            s11, s12, s13 = hist[_P + 4], hist[_P + 5], hist[_P + 6]
            s22, s23, s33 = hist[_P + 7], hist[_P + 8], hist[_P + 9]
            v0 = s00 + s01 * p1 + s02 * p2 + s03 * p3
            v1 = s01 + s11 * p1 + s12 * p2 + s13 * p3
            v2 = s02 + s12 * p1 + s22 * p2 + s23 * p3
            v3 = s03 + s13 * p1 + s23 * p2 + s33 * p3
            # Eq. 14 times w / w: q = w P p^T / (lambda + w p P p^T); p P p^T >= 0 for the positive definite P,
            # also after float32 rounding.
            g = w / (lam + w * max(v0 + p1 * v1 + p2 * v2 + p3 * v3, 0.0))
            q0, q1, q2, q3 = g * v0, g * v1, g * v2, g * v3
            # Eq. 8 (a priori error) and Eq. 9, per channel.
            for c in range(3):
                b = _B + 4 * c
                ic = i0 if c == 0 else (i1 if c == 1 else i2)
                e = ic - (hist[b] + hist[b + 1] * p1 + hist[b + 2] * p2 + hist[b + 3] * p3)
                b0 = hist[b] + q0 * e
                b1 = hist[b + 1] + q1 * e
                b2 = hist[b + 2] + q2 * e
                b3 = hist[b + 3] + q3 * e
                cur[y, x, b] = b0
                cur[y, x, b + 1] = b1
                cur[y, x, b + 2] = b2
                cur[y, x, b + 3] = b3
                planes[_B + 4 * c, y, x] = b0
                planes[_B + 4 * c + 1, y, x] = b1
                planes[_B + 4 * c + 2, y, x] = b2
                planes[_B + 4 * c + 3, y, x] = b3
            # Eq. 11: P(t) = (P - q p P) / lambda; q p P = q v^T is symmetric. A pixel whose samples all get w ~ 0
            # would see P grow as lambda^-t without bound (RLS "covariance wind-up", float32 overflow after ~40k
            # frames): P is scaled back to a trace of P_MAX_TRACE, which keeps it positive definite.
            t00 = s00 - q0 * v0
            t11 = s11 - q1 * v1
            t22 = s22 - q2 * v2
            t33 = s33 - q3 * v3
            k = inv_lam
            trace = (t00 + t11 + t22 + t33) * inv_lam
            if trace > P_MAX_TRACE:
                k *= P_MAX_TRACE / trace
            cur[y, x, _P] = t00 * k
            cur[y, x, _P + 1] = (s01 - q0 * v1) * k
            cur[y, x, _P + 2] = (s02 - q0 * v2) * k
            cur[y, x, _P + 3] = (s03 - q0 * v3) * k
            cur[y, x, _P + 4] = t11 * k
            cur[y, x, _P + 5] = (s12 - q1 * v2) * k
            cur[y, x, _P + 6] = (s13 - q1 * v3) * k
            cur[y, x, _P + 7] = t22 * k
            cur[y, x, _P + 8] = (s23 - q2 * v3) * k
            cur[y, x, _P + 9] = t33 * k
            cur[y, x, _Z] = z0
            cur[y, x, _Z + 1] = z1
            cur[y, x, _Z + 2] = z2
            planes[_Z, y, x] = z0
            planes[_Z + 1, y, x] = z1
            planes[_Z + 2, y, x] = z2
            planes[_N, y, x] = nz
            planes[_F, y, x] = p1
            planes[_F + 1, y, x] = p2
            planes[_F + 2, y, x] = p3


@njit(cache=True, parallel=True, fastmath=_FAST)
def _spatial(state: np.ndarray, spatial_w: np.ndarray, inv_3hs2: np.float32, eps: np.float32, scale: float,
             out: np.ndarray) -> None:
    """Stage 5: ``I^_i = sum_k W_ik p_i beta_k^T / sum_k W_ik`` over the window, computed as
    ``p_i (sum_k W_ik beta_k^T) / sum_k W_ik``; one row at a time, window offset by window offset, so that
    every inner loop runs over contiguous x and vectorizes."""
    _, height, width = state.shape
    r = spatial_w.shape[0] // 2
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for y in prange(height):
        acc = np.zeros((13, width), dtype=np.float32)
        wrow = np.empty(width, dtype=np.float32)
        a0 = state[_Z, y]
        a1 = state[_Z + 1, y]
        a2 = state[_Z + 2, y]
        an = state[_N, y]
        for dy in range(-r, r + 1):
            yy = y + dy
            if yy < 0 or yy >= height:
                continue
            b0 = state[_Z, yy]
            b1 = state[_Z + 1, yy]
            b2 = state[_Z + 2, yy]
            bn = state[_N, yy]
            for dx in range(-r, r + 1):
                ws = spatial_w[dy + r, dx + r]
                x0 = max(0, -dx)
                n = min(width, width - dx) - x0
                # Views aligned so that element i is pixel x0 + i and its neighbour x0 + i + dx: the loops
                # index from 0, which lets numba drop its negative-index checks and LLVM vectorize.
                c0, c1, c2, cn = a0[x0:x0 + n], a1[x0:x0 + n], a2[x0:x0 + n], an[x0:x0 + n]
                e0, e1, e2 = b0[x0 + dx:x0 + dx + n], b1[x0 + dx:x0 + dx + n], b2[x0 + dx:x0 + dx + n]
                en = bn[x0 + dx:x0 + dx + n]
                wv = wrow[:n]
                for i in range(n):
                    d0 = c0[i] - e0[i]
                    d1 = c1[i] - e1[i]
                    d2 = c2[i] - e2[i]
                    den = (cn[i] if cn[i] < en[i] else en[i]) + eps
                    t = one - (d0 * d0 + d1 * d1 + d2 * d2) * inv_3hs2 / (den * den)
                    t = t if t > zero else zero
                    wv[i] = ws * t * t * t
                dst = acc[0, x0:x0 + n]
                for i in range(n):
                    dst[i] += wv[i]
                for k in range(12):
                    dst = acc[1 + k, x0:x0 + n]
                    src = state[_B + k, yy, x0 + dx:x0 + dx + n]
                    for i in range(n):
                        dst[i] += wv[i] * src[i]
        f0 = state[_F, y]
        f1 = state[_F + 1, y]
        f2 = state[_F + 2, y]
        for x in range(width):
            s = scale / acc[0, x]
            for c in range(3):
                k = 1 + 4 * c
                out[y, x, c] = (acc[k, x] + acc[k + 1, x] * f0[x] + acc[k + 2, x] * f1[x] + acc[k + 3, x] * f2[x]) * s


# --- the denoiser ----------------------------------------------------------------------------------------


class WRLSDenoiser:
    """The WRLS denoiser for one ``width`` x ``height`` frame sequence (module docstring).

    ``params`` (default :class:`WRLSParams`), overridden by keyword (``WRLSDenoiser(w, h, alpha=0.8)``).
    ``medium``: the scene's medium (``scene.medium()``), from which depth maps are computed when a moving
    camera comes without one. :meth:`denoise` keeps the per-pixel state between calls; :meth:`reset` forgets
    it (a cut). ``timings_ms`` holds the last call's stage times (depth, reconstruct, temporal, spatial)."""

    def __init__(self, width: int, height: int, params: WRLSParams | None = None, *, medium: Medium | None = None,
                 **overrides: Any) -> None:
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
        self.depth_estimator = DepthEstimator(medium) if medium is not None else None
        shape = (self.height, self.width)
        self._prev = np.zeros((*shape, STATE), np.float32)
        self._cur = np.zeros((*shape, STATE), np.float32)
        self._planes = np.zeros((PLANES, *shape), np.float32)
        self._prep = np.zeros((9, *shape), np.float32)
        #: (H, W) float32 after each frame: the bilinear weight of the history each pixel found (1: all four
        #: pixels around q; 0: it restarted: first frame, off-screen, disoccluded).
        self.history_weight = np.zeros(shape, np.float32)
        self._prev_depth = np.full(shape, -1.0, np.float32)  # kernel format: -1 is background
        p = self.params
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
        _prepare(frame, self._taps, np.float32(1.0 / self.scale), p.clamp_radius, self._prep)
        timings["prepare"] = (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        blank = np.zeros(VIEW_SIZE)
        _temporal(self._prep, self._prev, self._cur, self._planes, self.history_weight, self.frames > 0, moving,
                  view if view is not None else blank, self._view if self._view is not None else blank, kdepth,
                  self._prev_depth, p.alpha, p.forgetting, p.bandwidth, p.epsilon, p.prior,
                  p.predictor == "history", p.depth_tolerance)
        timings["temporal"] = (time.perf_counter() - t) * 1e3
        t = time.perf_counter()
        out = np.empty((self.height, self.width, 3), np.float32)
        _spatial(self._planes, self._spatial_w, np.float32(1.0 / (3.0 * p.spatial_bandwidth**2)),
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
