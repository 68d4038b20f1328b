"""Compiled inner loops of the tracker (numba): the per-marker work that runs every frame.

A marker's window is ~20 x 20 px; at that size numpy and OpenCV spend their time entering and
leaving each call, not computing, and the tracker shares two cores with the video decoder. These
kernels do the same arithmetic in one call each. Compiled on first use, cached on disk (warmup.py
compiles them all at once).

- `luma_window`: BT.601 brightness of a BGR window, float32 (as cv2.transform with LUMA_BGR).
- `rest_reference` / `rest_shift`: the Lucas-Kanade shift test of rest.py (`*_luma`: on a frame's brightness
  plane).
- `edge_centre`: the luma silhouette circle of luma.py (cubic profiles along rays, sampled as
  OpenCV's remap does: Keys a = -0.75 weights, edges replicated).
- `colour_score`, `centroid`, `match_peak`: the template matcher's score image, colour centroid,
  and everything it does with the NCC surface (gated peak, sub-pixel vertex, PSR, centroid).
"""

from __future__ import annotations

import numpy as np

from ..jit import jit as _jit
from .chroma import LUMA_BGR

_LB, _LG, _LR = (np.float32(v) for v in LUMA_BGR)


@_jit
def _luma(win, i, j):
    """Brightness of pixel (i, j) of a BGR window, float32. (Pixels are read channel by channel:
    taking win[i, j] as a 3-vector first made the per-pixel loops up to twice as slow.)"""
    return _LB * np.float32(win[i, j, 0]) + _LG * np.float32(win[i, j, 1]) + _LR * np.float32(win[i, j, 2])


@_jit
def _score(win, i, j, w0, w1, w2, b, eps, den):
    """Marker score of pixel (i, j) of a BGR window, float32: (w . bgr) / (den (B + G + R) + eps) + b
    (den 1: a colour model on chromaticity; den 0, eps 1: a brightness model, linear in B, G, R)."""
    return _score_of(np.float32(win[i, j, 0]), np.float32(win[i, j, 1]), np.float32(win[i, j, 2]), w0, w1, w2, b,
                     eps, den)


@_jit
def _score_of(B, G, R, w0, w1, w2, b, eps, den):
    return (w0 * B + w1 * G + w2 * R) / (den * (B + G + R) + eps) + b


@_jit
def _coverage(score, lo, gain):
    """A pixel's weight in centroids and blob areas, ≈ its coverage by the marker:
    (score - lo) / (1 - lo) clipped to 0..1, with gain = 1 / (1 - lo) (AppearanceModel.weight_floor)."""
    return min(max((score - lo) * gain, 0.0), 1.0)


@_jit
def luma_window(win):
    h, w = win.shape[0], win.shape[1]
    out = np.empty((h, w), np.float32)
    for i in range(h):
        for j in range(w):
            out[i, j] = _luma(win, i, j)
    return out


@_jit
def rest_reference(win):
    """(ok, contrast, luma (n*n), gx, gy, inverse normal matrix (3,)) of a square window; gradients
    are Sobel 3 x 3 / 8 with reflected borders (as cv2.Sobel, scale 0.125)."""
    return _rest_reference_of(luma_window(win))


@_jit
def _rest_reference_of(ref):
    """rest_reference of a square brightness window (float32)."""
    n = ref.shape[0]
    gx = np.empty((n, n), np.float32)
    gy = np.empty((n, n), np.float32)
    for i in range(n):
        im, ip = (1 if i == 0 else i - 1), (n - 2 if i == n - 1 else i + 1)
        for j in range(n):
            jm, jp = (1 if j == 0 else j - 1), (n - 2 if j == n - 1 else j + 1)
            dx = (ref[im, jp] - ref[im, jm]) + 2 * (ref[i, jp] - ref[i, jm]) + (ref[ip, jp] - ref[ip, jm])
            dy = (ref[ip, jm] - ref[im, jm]) + 2 * (ref[ip, j] - ref[im, j]) + (ref[ip, jp] - ref[im, jp])
            gx[i, j] = np.float32(0.125) * dx
            gy[i, j] = np.float32(0.125) * dy
    a = b = c = 0.0
    lo, hi = ref[0, 0], ref[0, 0]
    for i in range(n):
        for j in range(n):
            u, v = float(gx[i, j]), float(gy[i, j])
            a += u * u
            b += u * v
            c += v * v
            lo, hi = min(lo, ref[i, j]), max(hi, ref[i, j])
    det = a * c - b * b
    contrast = float(hi - lo)
    ginv = np.zeros(3)
    ok = det > 1e-6 and contrast > 10.0
    if ok:
        ginv[0], ginv[1], ginv[2] = c / det, -b / det, a / det
    return ok, contrast, ref.ravel(), gx.ravel(), gy.ravel(), ginv


@_jit
def rest_shift(win, ref, gx, gy, ginv, max_shift_px, max_residual):
    """(ok, dx, dy): the least-squares brightness shift of the window since `ref`, ok when it is at
    most max_shift_px and leaves at most max_residual rms unexplained."""
    return _rest_shift_of(luma_window(win), ref, gx, gy, ginv, max_shift_px, max_residual)


@_jit
def _rest_shift_of(luma, ref, gx, gy, ginv, max_shift_px, max_residual):
    """rest_shift of a square brightness window (float32)."""
    n = luma.shape[0]
    bx = by = dd = 0.0
    k = 0
    for i in range(n):
        for j in range(n):
            d = float(ref[k] - luma[i, j])
            bx += float(gx[k]) * d
            by += float(gy[k]) * d
            dd += d * d
            k += 1
    dx = ginv[0] * bx + ginv[1] * by
    dy = ginv[1] * bx + ginv[2] * by
    if dx * dx + dy * dy > max_shift_px * max_shift_px:
        return False, dx, dy
    if dd - dx * bx - dy * by > max_residual * max_residual * (n * n):
        return False, dx, dy
    return True, dx, dy


@_jit
def _cubic_weights(t, w):
    a = -0.75
    x = t + 1.0
    w[0] = ((a * x - 5 * a) * x + 8 * a) * x - 4 * a
    w[1] = ((a + 2) * t - (a + 3)) * t * t + 1
    x = 1.0 - t
    w[2] = ((a + 2) * x - (a + 3)) * x * x + 1
    w[3] = 1.0 - w[0] - w[1] - w[2]


@_jit
def _cubic_sample(img, x, y, wx, wy):
    h, w = img.shape
    fx, fy = np.floor(x), np.floor(y)
    ix, iy = int(fx), int(fy)
    _cubic_weights(x - fx, wx)
    _cubic_weights(y - fy, wy)
    s = 0.0
    if 1 <= ix < w - 2 and 1 <= iy < h - 2:  # (most samples: no edge to replicate)
        for r in range(4):
            yy = iy - 1 + r
            row = 0.0
            for c in range(4):
                row += wx[c] * img[yy, ix - 1 + c]
            s += wy[r] * row
        return s
    for r in range(4):
        yy = min(max(iy - 1 + r, 0), h - 1)
        row = 0.0
        for c in range(4):
            xx = min(max(ix - 1 + c, 0), w - 1)
            row += wx[c] * img[yy, xx]
        s += wy[r] * row
    return s


@_jit
def _robust_circle(x, y, rounds, outward):
    """Kasa circle fit, then Cauchy re-weighting by the distance from the circle: (ok, cx, cy, r).
    `outward`: only points outside the circle are suspects (a dark marker's outline can be pushed
    outward by its contact shadow or a dark neighbour beside it, never inward: inside is the marker)."""
    m = x.shape[0]
    w = np.ones(m)
    a1 = a2 = r = 0.0
    for k in range(rounds):
        s1 = sx = sy = sz = sxx = sxy = syy = sxz = syz = 0.0
        for i in range(m):
            xi, yi, wi = x[i], y[i], w[i]
            zi = xi * xi + yi * yi
            s1 += wi
            sx += wi * xi
            sy += wi * yi
            sz += wi * zi
            sxx += wi * xi * xi
            sxy += wi * xi * yi
            syy += wi * yi * yi
            sxz += wi * xi * zi
            syz += wi * yi * zi
        c00, c01, c02 = syy * s1 - sy * sy, sy * sx - sxy * s1, sxy * sy - syy * sx
        c11, c12, c22 = sxx * s1 - sx * sx, sxy * sx - sxx * sy, sxx * syy - sxy * sxy
        det = sxx * c00 + sxy * c01 + sx * c02
        if abs(det) < 1e-12:
            return False, 0.0, 0.0, 0.0
        r0, r1, r2_ = 0.5 * sxz, 0.5 * syz, 0.5 * sz
        a1 = (c00 * r0 + c01 * r1 + c02 * r2_) / det
        a2 = (c01 * r0 + c11 * r1 + c12 * r2_) / det
        a3 = (c02 * r0 + c12 * r1 + c22 * r2_) / det
        r2 = 2 * a3 + a1 * a1 + a2 * a2
        if not r2 > 0:
            return False, 0.0, 0.0, 0.0
        r = r2 ** 0.5
        if k == rounds - 1:
            break
        _cauchy_weights(x, y, a1, a2, r, outward, w)
    return True, a1, a2, r


@_jit
def _cauchy_weights(x, y, cx, cy, r, outward, w):
    """Weights (into `w`) of the points (x, y) by their distance from the circle (cx, cy, r), on the
    scale of the median distance (Cauchy); `outward`: points inside the circle keep weight 1."""
    m = x.shape[0]
    res = np.empty(m)
    for i in range(m):
        res[i] = np.hypot(x[i] - cx, y[i] - cy) - r
    scale = 1.4826 * np.sort(np.abs(res))[m // 2] + 0.05
    for i in range(m):
        q = max(res[i], 0.0) / scale if outward else res[i] / (2 * scale)
        w[i] = 1.0 / (1.0 + q * q)


@_jit
def _robust_centre(x, y, radius, rounds, outward):
    """The centre of a circle of the given radius through the points (x, y) (Gauss-Newton on the
    distances, from the origin), with the Cauchy re-weighting of _robust_circle: (ok, cx, cy, radius).
    Beads of one size touching each other: a free circle is drawn off by the outlines of the neighbours
    pressed against a bead, a circle of its known radius leaves them outside, where they are suspects."""
    m = x.shape[0]
    w = np.ones(m)
    a1 = a2 = 0.0
    for k in range(rounds):
        for _ in range(8):
            j00 = j01 = j11 = g0 = g1 = 0.0
            for i in range(m):
                dx, dy = x[i] - a1, y[i] - a2
                d = max(np.hypot(dx, dy), 1e-6)
                ux, uy = -dx / d, -dy / d  # derivative of the distance by the centre
                e = d - radius
                j00 += w[i] * ux * ux
                j01 += w[i] * ux * uy
                j11 += w[i] * uy * uy
                g0 += w[i] * ux * e
                g1 += w[i] * uy * e
            det = j00 * j11 - j01 * j01
            if abs(det) < 1e-9:
                return False, 0.0, 0.0, 0.0
            s0 = -(j11 * g0 - j01 * g1) / det
            s1 = -(j00 * g1 - j01 * g0) / det
            a1 += s0
            a2 += s1
            if s0 * s0 + s1 * s1 < 1e-6:
                break
        if k == rounds - 1:
            break
        _cauchy_weights(x, y, a1, a2, radius, outward, w)
    return True, a1, a2, radius


@_jit
def edge_centre(win, cx, cy, radius, steps, cos, sin, min_rise, step_px, iterations, settle_px, sign, outward,
                known_radius=False):
    """(ok, x, y, r, quadrants): centre and radius of the marker's dark silhouette (sign 1; a bright one:
    sign -1) near (cx, cy) in the BGR window `win`, in the window's coordinates, and how many of the
    four quadrants around it hold the outline (see luma.edge_centre; `outward`: _robust_circle;
    `known_radius`: the circle keeps `radius`, only its centre is fitted: _robust_centre)."""
    return _edge_centre_of(luma_window(win), cx, cy, radius, steps, cos, sin, min_rise, step_px, iterations, settle_px,
                           sign, outward, known_radius)


@_jit
def _edge_centre_of(luma, cx, cy, radius, steps, cos, sin, min_rise, step_px, iterations, settle_px, sign, outward,
                    known_radius):
    """edge_centre of a brightness window (float32)."""
    n = steps.shape[0]
    n_rays = cos.shape[0]
    wx = np.empty(4)
    wy = np.empty(4)
    prof = np.empty(n)
    ex = np.empty(n_rays)
    ey = np.empty(n_rays)
    for _ in range(iterations):
        good = 0
        fx, fy = np.float32(cx), np.float32(cy)
        for ray in range(n_rays):
            for s in range(n):
                px = float(cos[ray] * steps[s] + fx)
                py = float(sin[ray] * steps[s] + fy)
                prof[s] = sign * _cubic_sample(luma, px, py, wx, wy)
            best, k = -np.inf, 0
            for s in range(n - 2):  # outward rise of brightness (central difference)
                g = prof[s + 2] - prof[s]
                if g > best:
                    best, k = g, s
            k = min(max(k, 1), n - 4)
            a = prof[k + 1] - prof[k - 1]
            b = prof[k + 2] - prof[k]
            c = prof[k + 3] - prof[k + 1]
            den = a - 2 * b + c
            if not (b > min_rise and den < 0):
                continue
            t = min(max(0.5 * (a - c) / den, -0.5), 0.5)
            d = steps[k + 1] + t * step_px
            ex[good] = cos[ray] * d
            ey[good] = sin[ray] * d
            good += 1
        if good < n_rays // 2:
            return False, cx, cy, 0.0, 0
        if known_radius:
            ok, ox, oy, r = _robust_centre(ex[:good], ey[:good], radius, 6 if outward else 2, outward)
        else:
            ok, ox, oy, r = _robust_circle(ex[:good], ey[:good], 6 if outward else 2, outward)
        if not ok or ox * ox + oy * oy > 4.0 or abs(r - radius) > 0.5 * radius + 1:
            return False, cx, cy, 0.0, 0
        cx, cy = cx + ox, cy + oy
        if ox * ox + oy * oy < settle_px * settle_px:
            break
    # Quadrants around the centre holding at least two edge points on the circle (within a pixel):
    # an outline seen on two sides only does not fix the centre across them.
    counts = np.zeros(4, np.int64)
    for i in range(good):
        qx, qy = ex[i] - ox, ey[i] - oy
        if abs(np.hypot(qx, qy) - r) <= 1.0:
            counts[(0 if qx >= 0 else 1) + (0 if qy >= 0 else 2)] += 1
    quadrants = 0
    for q in range(4):
        quadrants += counts[q] >= 2
    return True, cx, cy, r, quadrants


@_jit
def colour_score(win, w0, w1, w2, b, eps, den):
    """Marker score of a BGR window, float32: (w . bgr) / (den (B + G + R) + eps) + b (colour.py)."""
    h, w = win.shape[0], win.shape[1]
    out = np.empty((h, w), np.float32)
    for i in range(h):
        for j in range(w):
            out[i, j] = _score(win, i, j, w0, w1, w2, b, eps, den)
    return out


@_jit
def centroid(score, x, y, iterations, rad, lo, disc_area):
    """Coverage-weighted centroid in a disc of radius `rad` around the rounded (x, y) of `score`
    (weights: (score - lo) / (1 - lo) clipped to 0..1); (x, y, coverage / disc_area). Where the
    disc leaves the image, one pass over the part inside."""
    R = int(np.ceil(rad))
    h, w = score.shape
    gain = 1.0 / (1.0 - lo)
    frac = 0.0
    for _ in range(iterations):
        ix, iy = int(np.rint(x)), int(np.rint(y))
        clipped = ix - R < 0 or iy - R < 0 or ix + R + 1 > w or iy + R + 1 > h
        m00 = m10 = m01 = 0.0
        for yy in range(max(iy - R, 0), min(iy + R + 1, h)):
            for xx in range(max(ix - R, 0), min(ix + R + 1, w)):
                if (xx - ix) * (xx - ix) + (yy - iy) * (yy - iy) > rad * rad:
                    continue
                v = _coverage(score[yy, xx], lo, gain)
                m00 += v
                m10 += v * xx
                m01 += v * yy
        frac = m00 / disc_area
        if m00 < 1e-6:
            return x, y, 0.0
        x, y = m10 / m00, m01 / m00
        if clipped or (int(np.rint(x)) == ix and int(np.rint(y)) == iy):
            break  # the window would not move
    return x, y, frac


@_jit
def centroid_split(score, x, y, iterations, rad, lo, disc_area, nbx, nby):
    """As `centroid`, for a marker touching others: a pixel counts only when it lies nearer to the
    current estimate than to every neighbour centre (nbx[k], nby[k]; score coordinates), so the
    discs of touching markers are split at their contact instead of pulling each other's centres."""
    R = int(np.ceil(rad))
    h, w = score.shape
    gain = 1.0 / (1.0 - lo)
    frac = 0.0
    nn = nbx.shape[0]
    for _ in range(iterations):
        ix, iy = int(np.rint(x)), int(np.rint(y))
        m00 = m10 = m01 = 0.0
        for yy in range(max(iy - R, 0), min(iy + R + 1, h)):
            for xx in range(max(ix - R, 0), min(ix + R + 1, w)):
                d0 = (xx - x) * (xx - x) + (yy - y) * (yy - y)
                if (xx - ix) * (xx - ix) + (yy - iy) * (yy - iy) > rad * rad:
                    continue
                mine = True
                for k in range(nn):
                    if (xx - nbx[k]) * (xx - nbx[k]) + (yy - nby[k]) * (yy - nby[k]) < d0:
                        mine = False
                        break
                if not mine:
                    continue
                v = _coverage(score[yy, xx], lo, gain)
                m00 += v
                m10 += v * xx
                m01 += v * yy
        frac = m00 / disc_area
        if m00 < 1e-6:
            return x, y, 0.0
        nx, ny = m10 / m00, m01 / m00
        moved = abs(nx - x) + abs(ny - y)
        x, y = nx, ny
        if moved < 1e-3:
            break
    return x, y, frac


@_jit
def _parabola(a, b, c):
    den = a - 2 * b + c
    if den >= 0:
        return 0.0
    return min(max(0.5 * (a - c) / den, -0.5), 0.5)


@_jit
def _touching_peaks(res, br, bc, peak, radius):
    """Other markers touching the matched one: local maxima of the NCC surface `res` (3 x 3) at
    1.6-2.7 marker radii from the peak (row br, column bc), of at least max(0.5, 0.6 x peak); their
    (columns, rows) in `res` coordinates. (Touching markers' centres are ~2 radii apart.)"""
    nr, nc = res.shape
    reach = int(np.ceil(2.7 * radius))
    lo2, hi2 = (1.6 * radius) ** 2, (2.7 * radius) ** 2
    level = max(0.5, 0.6 * peak)
    xs = np.empty(16)
    ys = np.empty(16)
    n = 0
    for r in range(max(br - reach, 1), min(br + reach + 1, nr - 1)):
        for c in range(max(bc - reach, 1), min(bc + reach + 1, nc - 1)):
            d2 = (r - br) * (r - br) + (c - bc) * (c - bc)
            v = res[r, c]
            if d2 < lo2 or d2 > hi2 or v < level:
                continue
            if (v < res[r - 1, c - 1] or v < res[r - 1, c] or v < res[r - 1, c + 1] or v < res[r, c - 1]
                    or v < res[r, c + 1] or v < res[r + 1, c - 1] or v < res[r + 1, c] or v < res[r + 1, c + 1]):
                continue
            if n < 16:
                xs[n] = c
                ys[n] = r
                n += 1
    return xs[:n], ys[:n]


@_jit
def match_peak(res, score, c_lo, c_hi, r_lo, r_hi, ox, oy, s00, s01, s11, gate, half, excl,
               rad, lo, disc_area, radius):
    """Best NCC peak of `res` in the box rows r_lo..r_hi, columns c_lo..c_hi (and, when gate > 0,
    inside the gate ellipse d2 <= gate of the offsets (c + ox, r + oy) with the inverse innovation
    covariance s), refined to sub-pixel by parabolas, its peak-to-sidelobe ratio, then the colour
    centroid of `score` around it (split from touching markers' shares). Returns (found, x, y, peak, psr,
    coverage, used_centroid, touching) with x, y in `score` coordinates."""
    best, br, bc = -np.inf, -1, -1
    for r in range(r_lo, r_hi + 1):
        for c in range(c_lo, c_hi + 1):
            if res[r, c] > best:
                best, br, bc = res[r, c], r, c
    if gate > 0:
        dx, dy = bc + ox, br + oy
        if s00 * dx * dx + 2 * s01 * dx * dy + s11 * dy * dy > gate:
            best, br, bc = -np.inf, -1, -1  # the best peak lies outside the gate: search inside it only
            for r in range(r_lo, r_hi + 1):
                dy = r + oy
                for c in range(c_lo, c_hi + 1):
                    dx = c + ox
                    if s00 * dx * dx + 2 * s01 * dx * dy + s11 * dy * dy <= gate and res[r, c] > best:
                        best, br, bc = res[r, c], r, c
            if br < 0:
                return False, 0.0, 0.0, 0.0, 0.0, 0.0, False, False
    nr, nc = res.shape
    peak = float(res[br, bc])
    sx = _parabola(float(res[br, bc - 1]), peak, float(res[br, bc + 1])) if 0 < bc < nc - 1 else 0.0
    sy = _parabola(float(res[br - 1, bc]), peak, float(res[br + 1, bc])) if 0 < br < nr - 1 else 0.0
    nbx, nby = _touching_peaks(res, br, bc, peak, radius)
    # Peak-to-sidelobe ratio: (peak - mean) / std of the correlation outside a window around the peak
    # (and around the peaks of touching markers: a neighbour is another marker, not a sidelobe).
    n_in = s1 = s2 = 0.0
    for r in range(nr):
        inside_r = br - excl <= r <= br + excl
        for c in range(nc):
            if inside_r and bc - excl <= c <= bc + excl:
                n_in += 1
                continue
            skip = False
            for k in range(nbx.shape[0]):
                if abs(r - nby[k]) <= excl and abs(c - nbx[k]) <= excl:
                    skip = True
                    break
            if skip:
                n_in += 1
                continue
            v = float(res[r, c])
            s1 += v
            s2 += v * v
    n = nr * nc - n_in
    if n < 16:
        psr = np.nan
    else:
        mean = s1 / n
        sd = max(s2 / n - mean * mean, 0.0) ** 0.5
        psr = (peak - mean) / max(sd, 1e-3)
    ncc_x, ncc_y = bc + half + sx, br + half + sy
    split = nbx.shape[0] > 0
    if split:
        cx, cy, frac = centroid_split(score, ncc_x, ncc_y, 3, rad, lo, disc_area, nbx + half, nby + half)
    else:
        cx, cy, frac = centroid(score, ncc_x, ncc_y, 2, rad, lo, disc_area)
    used = frac >= 0.75 and np.hypot(cx - ncc_x, cy - ncc_y) <= 0.5 * radius
    if used:
        return True, cx, cy, peak, psr, frac, True, split
    return True, ncc_x, ncc_y, peak, psr, frac, False, split


@_jit
def colour_mask(win, m0, m1, m2, m3):
    """uint8 0/1 per pixel: m0 B + m1 G + m2 R + m3 >= 0 (the linear form of score >= threshold); and
    the box of its ones, (found, x0, y0, x1, y1)."""
    h, w = win.shape[0], win.shape[1]
    out = np.zeros((h, w), np.uint8)
    bx0, by0, bx1, by1 = 1 << 30, 1 << 30, -1, -1
    for i in range(h):
        for j in range(w):
            v = m0 * np.float32(win[i, j, 0]) + m1 * np.float32(win[i, j, 1]) + m2 * np.float32(win[i, j, 2]) + m3
            if v >= 0:
                out[i, j] = 1
                bx0, bx1 = min(bx0, j), max(bx1, j)
                by0, by1 = min(by0, i), max(by1, i)
    if bx1 < 0:
        return out, False, 0, 0, 0, 0
    return out, True, bx0, by0, bx1 + 1, by1 + 1


@_jit
def blob_moments(win, labels, k, xa, ya, xb, yb, w0, w1, w2, b, eps, den, lo):
    """Soft moments (m00, m10, m01; x, y from (xa, ya)) of component `k` of `labels` grown by one
    pixel (3 x 3), within rows ya..yb-1 and columns xa..xb-1, weighted by the colour coverage; and
    the component's pixel count there."""
    gain = 1.0 / (1.0 - lo)
    m00 = m10 = m01 = 0.0
    n = 0
    for i in range(ya, yb):
        for j in range(xa, xb):
            if labels[i, j] == k:
                n += 1
            hit = False
            for ii in range(max(i - 1, ya), min(i + 2, yb)):
                for jj in range(max(j - 1, xa), min(j + 2, xb)):
                    if labels[ii, jj] == k:
                        hit = True
            if not hit:
                continue
            v = _coverage(_score(win, i, j, w0, w1, w2, b, eps, den), lo, gain)
            m00 += v
            m10 += v * (j - xa)
            m01 += v * (i - ya)
    return m00, m10, m01, n


@_jit
def _undistort(u, v, fx, fy, cx, cy, k1, k2, p1, p2, k3):
    """A distorted pixel (u, v) undistorted, in pixels of the same camera matrix: OpenCV's pinhole
    model (k1 k2 p1 p2 k3) inverted as cv2.undistortPoints does, iterating until the point
    reprojects within 1e-10 px (at most 50 rounds)."""
    x0, y0 = (u - cx) / fx, (v - cy) / fy
    x, y = x0, y0
    for _ in range(50):
        r2 = x * x + y * y
        icdist = 1.0 / (1.0 + ((k3 * r2 + k2) * r2 + k1) * r2)
        if icdist < 0:
            x, y = x0, y0
            break
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (x0 - dx) * icdist, (y0 - dy) * icdist
        r2 = x * x + y * y
        cdist = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2
        xd = x * cdist + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * cdist + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        if np.hypot(xd * fx + cx - u, yd * fy + cy - v) < 1e-10:
            break
    return x * fx + cx, y * fy + cy


@_jit
def epipolar_distances(pa, pb, cam_a, cam_b, F):
    """Distance (px, undistorted pixels of camera b) of each pb[i] from the epipolar line of pa[i];
    cam_a, cam_b: (fx, fy, cx, cy, k1, k2, p1, p2, k3); F maps a's undistorted pixels to lines in b."""
    n = pa.shape[0]
    out = np.empty(n)
    for i in range(n):
        ax, ay = _undistort(pa[i, 0], pa[i, 1], *cam_a)
        bx, by = _undistort(pb[i, 0], pb[i, 1], *cam_b)
        l0 = F[0, 0] * ax + F[0, 1] * ay + F[0, 2]
        l1 = F[1, 0] * ax + F[1, 1] * ay + F[1, 2]
        l2 = F[2, 0] * ax + F[2, 1] * ay + F[2, 2]
        out[i] = abs(l0 * bx + l1 * by + l2) / max(np.hypot(l0, l1), 1e-12)
    return out


# Above this many values numpy's own selection (introselect) outruns the compiled one by more than its
# call costs (measured: 4000 values 12 against 19 us, 12000 46 against 35 us).
MEDIAN_COMPILED_MAX = 6000


@_jit
def _median_of(a):
    """np.median of a 1-D float array: NaN if it holds one; else the middle value, or the mean of the
    two middle values computed as numpy does (their sum in the array's precision, halved)."""
    n = a.shape[0]
    for i in range(n):
        if np.isnan(a[i]):
            return np.nan
    k = n // 2
    p = np.partition(a, k)
    hi = p[k]
    if n % 2:
        return float(hi)
    lo = p[0]
    for i in range(1, k):  # (the largest of the lower half: the other middle value)
        lo = max(lo, p[i])
    return float(lo + hi) / 2.0


def median(a) -> float:
    """np.median(a) of a float array, the same value, in one compiled call: a brightness model takes
    a few medians of each window it reads (its sand level), where numpy's own median spent ~15 us
    per call in entering and leaving its Python layers."""
    a = np.asarray(a)
    if a.size == 0:
        return float("nan")  # (as numpy's, without its warning)
    if a.dtype not in (np.float32, np.float64) or a.size > MEDIAN_COMPILED_MAX:
        return float(np.median(a))
    return _median_of(np.ascontiguousarray(a).ravel())


# The same kernels on a window of a frame still in its 4:2:0 planes (yuv.Yuv420Frame.yuv: planes y, u, v
# and the conversion tables t): the window is converted inside the call, as the frame's slicing would.
# The edge circle and the score window convert each pixel straight into the brightness or score they
# read, with no BGR window in between (which took longer to fill than the kernels took to read it).
@_jit
def _bgr_at(yp, up, vp, t, yy, xx):
    """(B, G, R) of frame pixel (yy, xx) as float32, the values yuv._window_bgr gives it."""
    u, v = up[yy >> 1, xx >> 1], vp[yy >> 1, xx >> 1]
    y = t[0][yp[yy, xx]]
    b = min(max(y + t[1][u], 0), 255)
    g = min(max(y + (t[2][u] + t[3][v]), 0), 255)
    r = min(max(y + t[4][v], 0), 255)
    return np.float32(b), np.float32(g), np.float32(r)


@_jit
def _luma_window_yuv(yp, up, vp, t, x0, y0, n):
    """luma_window of the n x n BGR window at (x0, y0), from the planes."""
    out = np.empty((n, n), np.float32)
    for i in range(n):
        for j in range(n):
            b, g, r = _bgr_at(yp, up, vp, t, y0 + i, x0 + j)
            out[i, j] = _LB * b + _LG * g + _LR * r
    return out


@_jit
def _brightness_window(yp, yt, x0, y0, n):
    """The n x n window at (x0, y0) of a frame's brightness plane in the levels of its BGR conversion (yt: the
    converter's brightness table, yuv.py), float32: the brightness the video codes, at full resolution."""
    out = np.empty((n, n), np.float32)
    for i in range(n):
        for j in range(n):
            out[i, j] = yt[yp[y0 + i, x0 + j]]
    return out


@_jit
def rest_reference_luma(yp, yt, x0, y0, n):
    """rest_reference of the n x n window at (x0, y0) of a frame's brightness plane (_brightness_window)."""
    return _rest_reference_of(_brightness_window(yp, yt, x0, y0, n))


@_jit
def rest_shift_luma(yp, yt, x0, y0, ref, gx, gy, ginv, max_shift_px, max_residual):
    """rest_shift of the window at (x0, y0) of a frame's brightness plane (_brightness_window)."""
    n = int(np.sqrt(ref.shape[0]))
    return _rest_shift_of(_brightness_window(yp, yt, x0, y0, n), ref, gx, gy, ginv, max_shift_px, max_residual)


@_jit
def edge_centre_yuv(yp, up, vp, t, x0, y0, n, cx, cy, radius, steps, cos, sin, min_rise, step_px, iterations,
                    settle_px, sign, outward, known_radius=False):
    return _edge_centre_of(_luma_window_yuv(yp, up, vp, t, x0, y0, n), cx, cy, radius, steps, cos, sin, min_rise,
                           step_px, iterations, settle_px, sign, outward, known_radius)


@_jit
def colour_score_yuv(yp, up, vp, t, x0, y0, x1, y1, w0, w1, w2, b, eps, den):
    h, w = y1 - y0, x1 - x0
    out = np.empty((h, w), np.float32)
    for i in range(h):
        for j in range(w):
            B, G, R = _bgr_at(yp, up, vp, t, y0 + i, x0 + j)
            out[i, j] = _score_of(B, G, R, w0, w1, w2, b, eps, den)
    return out


@_jit
def colour_score_yuv_interpolated(yp, up, vp, t, x0, y0, x1, y1, w0, w1, w2, b, eps, den):
    """colour_score_yuv with the chroma interpolated bilinearly between its samples instead of held over
    each sample's 2 x 2 block: sample (i, j) at pixel (2 j + 0.5, 2 i + 0.5), the block's middle (the
    replicated chroma's phase too), as chroma.reinterpolate does with CENTRE_SITING. Interpolated are
    the conversion's chroma terms, linear in U and V; the planes' edge samples are held."""
    h, w = y1 - y0, x1 - x0
    ch, cw = up.shape[0], up.shape[1]
    i_lo, j_lo = max((y0 >> 1) - 1, 0), max((x0 >> 1) - 1, 0)  # the samples around the window
    i_hi, j_hi = min(((y1 - 1) >> 1) + 1, ch - 1), min(((x1 - 1) >> 1) + 1, cw - 1)
    terms = np.empty((3, i_hi - i_lo + 1, j_hi - j_lo + 1), np.float32)
    for i in range(i_hi - i_lo + 1):
        for j in range(j_hi - j_lo + 1):
            u, v = up[i_lo + i, j_lo + j], vp[i_lo + i, j_lo + j]
            terms[0, i, j] = t[1][u]
            terms[1, i, j] = t[2][u] + t[3][v]
            terms[2, i, j] = t[4][v]
    out = np.empty((h, w), np.float32)
    c = np.empty(3, np.float32)
    for i in range(h):
        sy = 0.5 * (y0 + i) - 0.25  # the pixel's place in sample units
        ia = int(np.floor(sy))
        fy = np.float32(sy - ia)
        ra, rb = min(max(ia, i_lo), i_hi) - i_lo, min(max(ia + 1, i_lo), i_hi) - i_lo
        for j in range(w):
            sx = 0.5 * (x0 + j) - 0.25
            ja = int(np.floor(sx))
            fx = np.float32(sx - ja)
            ca, cb = min(max(ja, j_lo), j_hi) - j_lo, min(max(ja + 1, j_lo), j_hi) - j_lo
            y = np.float32(t[0][yp[y0 + i, x0 + j]])
            for k in range(3):
                top = terms[k, ra, ca] + fx * (terms[k, ra, cb] - terms[k, ra, ca])
                bottom = terms[k, rb, ca] + fx * (terms[k, rb, cb] - terms[k, rb, ca])
                c[k] = min(max(y + top + fy * (bottom - top), np.float32(0.0)), np.float32(255.0))
            out[i, j] = _score_of(c[0], c[1], c[2], w0, w1, w2, b, eps, den)
    return out
