"""The WRLS denoiser's numba kernels, two parallel regions per frame (:mod:`photon_fields.runtime.denoise.wrls`
says what each stage computes and why, with the paper's equation numbers): :func:`temporal` (per block of rows, the
pixel reconstruction filter and Psi's bounds of :func:`_prepare_rows`, then, in passes over each row, reprojection,
Eq. 12 feature, Eq. 13 weight, wRLS update Eq. 8-11 / 14) and :func:`spatial` (the 5x5 blend of the neighbours'
models). The state layout they share is defined here.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from photon_fields.runtime.denoise.reprojection import reproject_pixel
from photon_fields.runtime.numba_inlining import install

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)

# Per-pixel state (float32, (H, W, STATE), the last axis contiguous for the bilinear reads of the reprojection):
# the feature z (3), the coefficients beta (3 channels x 4: intercept, slopes on the predictor's three colours)
# and the upper triangle of the symmetric 4x4 P, row by row (10). The spatial filter reads planes ((PLANES, H,
# W + 2 pad), padded by ``pad`` >= the window radius zero columns on each side: its loops over x vectorize, with no
# edge cases): z and beta at the same indices, |z| and the predictor's colours.
_Z, _B, _P = 0, 3, 15
STATE = 25
_N, _F = 25, 26
PLANES = 29
# The kernels are compiled with fastmath (no NaN, no infinity: min / max become single instructions, loops
# vectorize); so frames are checked finite first, and background depths are -1 inside the kernels, not inf.
_FAST = True
P_MAX_TRACE = 1e6  # the cap on trace(P) against covariance wind-up (in temporal)
#: Rows per task of :func:`temporal`: the reconstruction filter and Psi's bounds filter each row of a task once,
#: plus a margin of ``2 (clamp_radius + r)`` rows shared with the neighbouring tasks.
ROWS_PER_TASK = 8



# --- kernels -------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _prepare_rows(frame: np.ndarray, taps: np.ndarray, inv_scale: np.float32, clamp_r: int, y0: int, y1: int,
                  row: np.ndarray, hrow: np.ndarray, filt: np.ndarray, hmin: np.ndarray, hmax: np.ndarray,
                  tmp: np.ndarray, prep: np.ndarray) -> None:
    """Stage 1 and Psi's bounds for rows ``y0 .. y1 - 1``, as planes: ``prep[y - y0, c]`` the frame through the
    separable Gaussian pixel reconstruction filter (weights ``taps``, summing to 1, the image extended by its edge
    pixels) in units of the first frame's mean radiance, ``prep[y - y0, 3 + c]`` / ``prep[y - y0, 6 + c]`` the
    min / max of it over the ``(2 clamp_r + 1)^2`` neighbourhood (rows beyond the image: the filter of the
    edge-extended frame; columns: the edge-extended filter). Each row of the block and its margins is filtered
    once (a block shares all but its margins with its neighbours' rows): ``hrow`` (n + 2 (clamp_r + r), W) the
    horizontally filtered rows, ``filt`` (n + 2 clamp_r, W + 2 clamp_r) the filtered rows, ``hmin`` / ``hmax``
    (n + 2 clamp_r, W) their horizontal window extremes, ``row`` (W + 2 r) and ``tmp`` (W): scratch of the
    caller's thread. Every loop runs over contiguous x and vectorizes."""
    height, width, _ = frame.shape
    r = taps.shape[0] // 2
    n = y1 - y0
    nh = n + 2 * (clamp_r + r)
    nf = n + 2 * clamp_r
    for c in range(3):
        for j in range(nh):  # virtual row y0 - clamp_r - r + j, read from the edge-extended frame
            yi = min(max(y0 - clamp_r - r + j, 0), height - 1)
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
        for j in range(nf):  # filtered virtual row y0 - clamp_r + j
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
            # Psi's bounds, separably: per filtered row the min / max over the horizontal window, then over the
            # rows. Every loop writes one array from two others (a form LLVM vectorizes: an in-place
            # lo[x] = min(lo[x], v) does not), ping-ponging between buffers.
            _window_extreme(fr, clamp_r, width, hmin[j], tmp, True)
            _window_extreme(fr, clamp_r, width, hmax[j], tmp, False)
        for i in range(n):
            out = prep[i, c]
            centre = filt[i + clamp_r, clamp_r:clamp_r + width]
            for x in range(width):
                out[x] = centre[x]
            _rows_extreme(hmin[i:i + 2 * clamp_r + 1], prep[i, 3 + c], tmp, True)
            _rows_extreme(hmax[i:i + 2 * clamp_r + 1], prep[i, 6 + c], tmp, False)


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


@njit(cache=True, inline="always")
def _update_row(prep: np.ndarray, y: int, width: int, pad: int, prev: np.ndarray, cur: np.ndarray,
                planes: np.ndarray, found_out: np.ndarray, have_prev: bool, moving: bool, view_cur: np.ndarray,
                view_prev: np.ndarray, depth: np.ndarray, prev_depth: np.ndarray, alpha: float, lam: float,
                inv_h2: float, inv_lam: float, eps: float, prior: float, history_pred: bool, depth_tol: float,
                histories: np.ndarray, prow: np.ndarray, wrow: np.ndarray) -> None:
    """Stages 2-4 for the pixels of row ``y``, from its prepared planes ``prep`` (:func:`_prepare_rows`), as passes
    over the row: the reprojection, the histories' reads (into ``histories[x]``), stage 3 with Eq. 13's weight (the
    predictor into ``prow``, the weight into ``wrow``), stage 4. A pass's pixels are independent and its body short,
    so the core overlaps the latencies of several pixels (square roots, divisions, the exponential) that one pass
    doing all four per pixel kept in one chain: the same arithmetic, 0.65-0.75x the time (bench/README.md, "WRLS in
    passes")."""
    height = depth.shape[0]
    # Stage 2: reprojection, q = pi(v_j) (into prow and, whether q is on-screen in front, wrow: scratch until stage 3
    # writes them), and the history there (its weight found into wrow).
    if have_prev and moving:
        for x in range(width):
            qx, qy, dist, front = reproject_pixel(view_cur, view_prev, x, y, float(depth[y, x]))
            prow[0, x] = qx
            prow[1, x] = qy
            prow[2, x] = dist
            wrow[x] = 1.0 if front and 0.0 <= qx < width and 0.0 <= qy < height else 0.0
        for x in range(width):
            wrow[x] = _gather(prev, prev_depth, prow[0, x], prow[1, x], prow[2, x], depth_tol,
                              histories[x]) if wrow[x] > 0.0 else 0.0
    elif have_prev:
        for x in range(width):
            hist = histories[x]
            for k in range(STATE):
                hist[k] = prev[y, x, k]
            wrow[x] = 1.0
    else:
        for x in range(width):
            wrow[x] = 0.0
    for x in range(width):
        hist = histories[x]
        i0 = prep[0, x]
        i1 = prep[1, x]
        i2 = prep[2, x]
        found = wrow[x]  # the history's weight (stage 2); wrow[x] takes Eq. 13's weight below
        found_out[y, x] = found
        # Stage 3: the temporal feature, Eq. 12, with the clamped history Psi[z_q(t-1), I~_j(t)].
        if found > 0.0:
            c0 = min(max(hist[_Z], prep[3, x]), prep[6, x])
            c1 = min(max(hist[_Z + 1], prep[4, x]), prep[7, x])
            c2 = min(max(hist[_Z + 2], prep[5, x]), prep[8, x])
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
        # Predictor p = [1, p1, p2, p3] (Eq. 5): the clamped history ("history") or z_j(t).
        if history_pred:
            p1, p2, p3 = c0, c1, c2
        else:
            p1, p2, p3 = z0, z1, z2
        # Eq. 13.
        ni = math.sqrt(i0 * i0 + i1 * i1 + i2 * i2)
        nz = math.sqrt(z0 * z0 + z1 * z1 + z2 * z2)
        den = min(ni, nz) + eps
        wrow[x] = math.exp(-((i0 - z0) ** 2 + (i1 - z1) ** 2 + (i2 - z2) ** 2) / (den * den) * inv_h2)
        prow[0, x] = p1
        prow[1, x] = p2
        prow[2, x] = p3
        cur[y, x, _Z] = z0
        cur[y, x, _Z + 1] = z1
        cur[y, x, _Z + 2] = z2
        planes[_Z, y, pad + x] = z0
        planes[_Z + 1, y, pad + x] = z1
        planes[_Z + 2, y, pad + x] = z2
        planes[_N, y, pad + x] = nz
        planes[_F, y, pad + x] = p1
        planes[_F + 1, y, pad + x] = p2
        planes[_F + 2, y, pad + x] = p3
    # Stage 4: wRLS.
    for x in range(width):
        hist = histories[x]
        i0 = prep[0, x]
        i1 = prep[1, x]
        i2 = prep[2, x]
        p1 = prow[0, x]
        p2 = prow[1, x]
        p3 = prow[2, x]
        w = wrow[x]
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
            planes[_B + 4 * c, y, pad + x] = b0
            planes[_B + 4 * c + 1, y, pad + x] = b1
            planes[_B + 4 * c + 2, y, pad + x] = b2
            planes[_B + 4 * c + 3, y, pad + x] = b3
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


@njit(cache=True, parallel=True, fastmath=_FAST)
def temporal(frame: np.ndarray, taps: np.ndarray, inv_scale: np.float32, clamp_r: int, prev: np.ndarray,
             cur: np.ndarray, planes: np.ndarray, found_out: np.ndarray, have_prev: bool, moving: bool,
             view_cur: np.ndarray, view_prev: np.ndarray, depth: np.ndarray, prev_depth: np.ndarray, alpha: float,
             lam: float, h: float, eps: float, prior: float, history_pred: bool, depth_tol: float) -> None:
    """Stages 1-4 for every pixel, in tasks of :data:`ROWS_PER_TASK` rows: the rows' reconstructed frame and Psi's
    bounds (:func:`_prepare_rows`), then per pixel reproject, Eq. 12, Eq. 13, Eq. 14 / 8 / 9 / 11
    (:func:`_update_row`); writes the new state ``cur``,
    the spatial filter's ``planes`` (columns offset by their padding, which stays 0) and the history weight
    found (0: restarted) into ``found_out``. One parallel region: the reconstructed frame never goes to
    memory."""
    height, width, _ = frame.shape
    pad = (planes.shape[2] - width) // 2
    r = taps.shape[0] // 2
    inv_h2 = 1.0 / (h * h)
    inv_lam = 1.0 / lam
    for block in prange((height + ROWS_PER_TASK - 1) // ROWS_PER_TASK):
        y0 = block * ROWS_PER_TASK
        y1 = min(height, y0 + ROWS_PER_TASK)
        histories = np.empty((width, STATE))
        prow = np.empty((3, width))
        wrow = np.empty(width)
        row = np.empty(width + 2 * r, dtype=np.float32)
        hrow = np.empty((ROWS_PER_TASK + 2 * (clamp_r + r), width), dtype=np.float32)
        filt = np.empty((ROWS_PER_TASK + 2 * clamp_r, width + 2 * clamp_r), dtype=np.float32)
        hmin = np.empty((ROWS_PER_TASK + 2 * clamp_r, width), dtype=np.float32)
        hmax = np.empty((ROWS_PER_TASK + 2 * clamp_r, width), dtype=np.float32)
        tmp = np.empty(width, dtype=np.float32)
        prep_rows = np.empty((ROWS_PER_TASK, 9, width), dtype=np.float32)
        _prepare_rows(frame, taps, inv_scale, clamp_r, y0, y1, row, hrow, filt, hmin, hmax, tmp, prep_rows)
        for y in range(y0, y1):
            _update_row(prep_rows[y - y0], y, width, pad, prev, cur, planes, found_out, have_prev, moving, view_cur,
                        view_prev, depth, prev_depth, alpha, lam, inv_h2, inv_lam, eps, prior, history_pred,
                        depth_tol, histories, prow, wrow)


@njit(cache=True, parallel=True, fastmath=_FAST)
def spatial(planes: np.ndarray, spatial_w: np.ndarray, inv_3hs2: np.float32, eps: np.float32, scale: float,
            out: np.ndarray) -> None:
    """Stage 5: ``I^_i = sum_k W_ik p_i beta_k^T / sum_k W_ik`` over the window, computed as
    ``p_i (sum_k W_ik beta_k^T) / sum_k W_ik``; one row at a time. Per window row, the weights of its
    ``2 r + 1`` offsets are computed first (a weight row each, 0 where the neighbour is off the image); then each
    of the 13 sums takes that window row's offsets in one pass over x (for the default r = 2: five products per
    load and store of the sum). The planes are padded by at least r columns on each side (zeros), so that
    every neighbour's view is in bounds and every inner loop runs over contiguous x and vectorizes."""
    _, height, padded = planes.shape
    width = out.shape[1]
    pad = (padded - width) // 2
    r = spatial_w.shape[0] // 2
    nw = 2 * r + 1
    one = np.float32(1.0)
    zero = np.float32(0.0)
    for y in prange(height):
        acc = np.zeros((13, width), dtype=np.float32)
        wts = np.empty((nw, width), dtype=np.float32)
        a0 = planes[_Z, y, pad:pad + width]
        a1 = planes[_Z + 1, y, pad:pad + width]
        a2 = planes[_Z + 2, y, pad:pad + width]
        an = planes[_N, y, pad:pad + width]
        for dy in range(-r, r + 1):
            yy = y + dy
            if yy < 0 or yy >= height:
                continue
            for j in range(nw):
                dx = j - r
                ws = spatial_w[dy + r, j]
                # Views aligned so that element i is pixel i and its neighbour i + dx (in the padding off the
                # image): the loops index from 0, which lets numba drop its negative-index checks and LLVM
                # vectorize.
                e0 = planes[_Z, yy, pad + dx:pad + dx + width]
                e1 = planes[_Z + 1, yy, pad + dx:pad + dx + width]
                e2 = planes[_Z + 2, yy, pad + dx:pad + dx + width]
                en = planes[_N, yy, pad + dx:pad + dx + width]
                wv = wts[j]
                for i in range(width):
                    d0 = a0[i] - e0[i]
                    d1 = a1[i] - e1[i]
                    d2 = a2[i] - e2[i]
                    den = (an[i] if an[i] < en[i] else en[i]) + eps
                    t = one - (d0 * d0 + d1 * d1 + d2 * d2) * inv_3hs2 / (den * den)
                    t = t if t > zero else zero
                    wv[i] = ws * t * t * t
                for i in range(max(0, -dx)):  # neighbours off the image's left or right edge weigh nothing
                    wv[i] = zero
                for i in range(width - max(0, dx), width):
                    wv[i] = zero
            if r == 2:
                w0, w1, w2, w3, w4 = wts[0], wts[1], wts[2], wts[3], wts[4]
                dst = acc[0]
                for i in range(width):
                    dst[i] += (w0[i] + w1[i]) + (w2[i] + w3[i]) + w4[i]
                for k in range(12):
                    row = planes[_B + k, yy]
                    s0 = row[pad - 2:pad - 2 + width]
                    s1 = row[pad - 1:pad - 1 + width]
                    s2 = row[pad:pad + width]
                    s3 = row[pad + 1:pad + 1 + width]
                    s4 = row[pad + 2:pad + 2 + width]
                    dst = acc[1 + k]
                    for i in range(width):
                        dst[i] += (w0[i] * s0[i] + w1[i] * s1[i]) + (w2[i] * s2[i] + w3[i] * s3[i]) + w4[i] * s4[i]
            else:
                for j in range(nw):
                    dx = j - r
                    wv = wts[j]
                    dst = acc[0]
                    for i in range(width):
                        dst[i] += wv[i]
                    for k in range(12):
                        src = planes[_B + k, yy, pad + dx:pad + dx + width]
                        dst = acc[1 + k]
                        for i in range(width):
                            dst[i] += wv[i] * src[i]
        f0 = planes[_F, y, pad:pad + width]
        f1 = planes[_F + 1, y, pad:pad + width]
        f2 = planes[_F + 2, y, pad:pad + width]
        for x in range(width):
            s = scale / acc[0, x]
            for c in range(3):
                k = 1 + 4 * c
                out[y, x, c] = (acc[k, x] + acc[k + 1, x] * f0[x] + acc[k + 2, x] * f1[x] + acc[k + 3, x] * f2[x]) * s
