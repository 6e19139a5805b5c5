"""The WRLS kernels against a plain float64 reference of the same equations, written pixel by pixel in numpy
(the module docstring of runtime/denoise/wrls.py, stages 1-5): a moving camera over a box (reprojection, depth
test, restarts at the border), fireflies (Eq. 13's weight), a static frame at the end, with the default
parameters, with ``predictor="feature"`` and with a wider clamp window and reconstruction filter. The kernels
are compiled with fastmath and keep their state in float32, so the two agree to float32 rounding, not bit for
bit: the kernels' loops may be fused, reordered and vectorized freely, and this test is what says that they
still compute the paper's denoiser."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import constant_tf

from photon_fields.runtime.denoise.depth import DepthEstimator
from photon_fields.runtime.denoise.reprojection import pack_view, reproject_image
from photon_fields.runtime.denoise.wrls import WRLSDenoiser, WRLSParams
from photon_fields.runtime.denoise.wrls_kernels import P_MAX_TRACE
from photon_fields.runtime.scene.camera import Camera, orbit_camera
from photon_fields.runtime.scene.volume import make_volume
from photon_fields.runtime.transport.medium import build_medium

H, W = 18, 23


class Reference:
    """WRLS in float64, one pixel at a time (no fastmath, no float32 state)."""

    def __init__(self, p: WRLSParams, taps: np.ndarray, spatial_w: np.ndarray) -> None:
        self.p, self.taps, self.spatial_w = p, taps.astype(np.float64), spatial_w.astype(np.float64)
        self.state: np.ndarray | None = None  # (H, W, 3 + 12 + 16): z, beta (3 x 4), P (4 x 4)
        self.depth: np.ndarray | None = None
        self.view: np.ndarray | None = None
        self.scale = 1.0

    def prepare(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The filtered frame and Psi's bounds. At the borders, as the kernel does: the clamp window's rows
        beyond the image are the filter of the edge-extended input, its columns the edge-extended filter."""
        r, c = self.taps.shape[0] // 2, self.p.clamp_radius
        f = frame.astype(np.float64) / self.scale
        pad = np.pad(f, ((r + c, r + c), (r, r), (0, 0)), mode="edge")
        rows = sum(self.taps[k] * pad[:, k:k + W] for k in range(2 * r + 1))
        tall = sum(self.taps[k] * rows[k:k + H + 2 * c] for k in range(2 * r + 1))  # rows -c .. H - 1 + c
        fp = np.pad(tall, ((0, 0), (c, c), (0, 0)), mode="edge")
        wins = [fp[dy:dy + H, dx:dx + W] for dy in range(2 * c + 1) for dx in range(2 * c + 1)]
        return tall[c:c + H], np.min(wins, axis=0), np.max(wins, axis=0)

    def initial(self) -> np.ndarray:
        s = np.zeros(31)
        for c in range(3):
            s[3 + 4 * c + 1 + c] = 1.0
        s[15:31] = (self.p.prior * np.eye(4)).ravel()
        return s

    def gather(self, view: np.ndarray, x: int, y: int, xs: np.ndarray, ys: np.ndarray, ds: np.ndarray,
               front: np.ndarray) -> np.ndarray | None:
        assert self.state is not None and self.depth is not None
        qx, qy, dist = xs[y, x], ys[y, x], ds[y, x]
        if not front[y, x] or not (0.0 <= qx < W and 0.0 <= qy < H):
            return None
        sx, sy = qx - 0.5, qy - 0.5
        bx, by = math.floor(sx), math.floor(sy)
        fx, fy = sx - bx, sy - by
        acc, wsum = np.zeros(31), 0.0
        for tx, ty, w in ((bx, by, (1 - fx) * (1 - fy)), (bx + 1, by, fx * (1 - fy)), (bx, by + 1, (1 - fx) * fy),
                          (bx + 1, by + 1, fx * fy)):
            if not (0 <= tx < W and 0 <= ty < H):
                continue
            pd = self.depth[ty, tx]
            tol = self.p.depth_tolerance * dist
            ok = math.isinf(pd) if math.isinf(dist) else (not math.isinf(pd) and abs(pd - dist) <= tol)
            if ok and w > 0:
                acc += w * self.state[ty, tx]
                wsum += w
        return acc / wsum if wsum > 0 else None

    def denoise(self, frame: np.ndarray, cam: Camera, depth: np.ndarray) -> np.ndarray:
        p = self.p
        view = pack_view(cam)
        if self.state is None:
            self.scale = float(np.mean(frame, dtype=np.float64))
        filt, lo, hi = self.prepare(frame)
        moving = self.view is not None and not np.array_equal(view, self.view)
        if moving:
            xs, ys, ds, front = reproject_image(view, self.view, depth.astype(np.float64))
        new = np.zeros((H, W, 31))
        feat = np.zeros((H, W, 3))
        pred = np.zeros((H, W, 3))
        for y in range(H):
            for x in range(W):
                i = filt[y, x]
                hist = None
                if self.state is not None:
                    hist = self.gather(view, x, y, xs, ys, ds, front) if moving else self.state[y, x]
                if hist is None:
                    s, c, z = self.initial(), i.copy(), i.copy()
                else:
                    s = hist.copy()
                    c = np.minimum(np.maximum(hist[:3], lo[y, x]), hi[y, x])
                    z = p.alpha * c + (1 - p.alpha) * i
                pv = np.concatenate([[1.0], c if p.predictor == "history" else z])
                d2 = np.sum((i - z) ** 2) / (min(np.linalg.norm(i), np.linalg.norm(z)) + p.epsilon) ** 2
                w = math.exp(-d2 / p.bandwidth**2)
                P = s[15:31].reshape(4, 4)
                v = P @ pv
                q = w * v / (p.forgetting + w * max(pv @ v, 0.0))
                beta = s[3:15].reshape(3, 4)
                e = i - beta @ pv
                beta = beta + e[:, None] * q[None, :]
                Pn = (P - np.outer(q, v)) / p.forgetting
                tr = np.trace(Pn)
                if tr > P_MAX_TRACE:
                    Pn *= P_MAX_TRACE / tr
                new[y, x, :3], new[y, x, 3:15], new[y, x, 15:] = z, beta.ravel(), Pn.ravel()
                feat[y, x], pred[y, x] = z, pv[1:]
        self.state, self.depth, self.view = new, depth.astype(np.float64), view
        out = np.zeros((H, W, 3))
        r = p.window_radius
        for y in range(H):
            for x in range(W):
                num, den = np.zeros((3, 4)), 0.0
                for yy in range(max(0, y - r), min(H, y + r + 1)):
                    for xx in range(max(0, x - r), min(W, x + r + 1)):
                        dd = np.sum((feat[y, x] - feat[yy, xx]) ** 2) / (
                            min(np.linalg.norm(feat[y, x]), np.linalg.norm(feat[yy, xx])) + p.epsilon) ** 2
                        k = max(0.0, 1.0 - dd / (3.0 * p.spatial_bandwidth**2)) ** 3
                        wgt = self.spatial_w[yy - y + r, xx - x + r] * k
                        num += wgt * new[yy, xx, 3:15].reshape(3, 4)
                        den += wgt
                out[y, x] = (num / den) @ np.concatenate([[1.0], pred[y, x]]) * self.scale
        return out


@pytest.fixture(scope="module")
def sequence():  # noqa: ANN201
    """Six frames of a camera orbiting a box, with two fireflies, and a last frame from the same view."""
    box = build_medium(make_volume(np.ones((6, 6, 6)), window=(0.0, 1.0)), constant_tf(3.0))
    cam0 = Camera([0.5, 0.4, 2.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 40.0, W, H)
    cams = [orbit_camera(cam0, 2.5 * i) for i in range(6)]
    cams.append(cams[-1])
    depths = [DepthEstimator(box, block=1, stride=1).depth(c) for c in cams]
    rng = np.random.default_rng(11)
    frames = [rng.gamma(2.0, 0.5, (H, W, 3)).astype(np.float32) for _ in cams]
    frames[2][5, 7] *= 60.0
    frames[4][11, 15] *= 40.0
    return frames, cams, depths


@pytest.mark.parametrize(("predictor", "wide"), [("history", False), ("feature", False), ("history", True)])
def test_kernels_match_a_float64_reference(sequence, predictor: str, wide: bool) -> None:  # noqa: ANN001
    """``wide``: a 5x5 clamp window and a 7-tap reconstruction filter, whose margins reach beyond the kernel's
    blocks of rows (and the image's 18 rows are two blocks and a part)."""
    frames, cams, depths = sequence
    dn = WRLSDenoiser(W, H, predictor=predictor, **({"clamp_radius": 2, "reconstruction_sigma": 1.0} if wide else {}))
    assert dn._taps.shape[0] == (7 if wide else 3)
    ref = Reference(dn.params, dn._taps, dn._spatial_w)
    restarted = 0
    for f, c, d in zip(frames, cams, depths, strict=True):
        got = dn.denoise(f, camera=c, depth=d)
        want = ref.denoise(f, c, d)
        restarted += int(np.sum(dn.history_weight == 0.0))
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * float(np.mean(want)))
    assert restarted > H * W + 10  # the first frame, and pixels that came into view
