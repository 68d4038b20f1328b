"""Marker motion from brightness (luma), to carry the colour centre across inter-coded frames.

H.264/H.265 video codes colour (chroma) at half resolution and, in predicted frames, mostly as a
copy of the reference frame: for a marker creeping along (0.01-1 px/frame, pushed by the sand
heap) the chroma residual is quantised away and the marker's colour trails its true position by
up to ~0.4 px, building up from each intra-coded frame to the next (measured on the rendered rig:
0.12 px at intra frames, 0.45 px 20-49 frames later). Brightness is coded at full resolution and
far more finely, and does not trail. Its edge, though, is biased by shading and by the contact
shadow (0.1-0.5 px, mostly towards the shadow), but that bias changes slowly. So the tracker
measures the marker's luma centre too; at intra-coded frames it records the offset between the
colour centre and the luma centre; in the frames between, luma centre + offset tells how far the
stale colour held the centre back, and the colour centre is moved forward by that much, along the
motion since the intra frame and by at most its length (a lag can do nothing else: this keeps a
shadow sliding over the sand, which shifts the luma edge sideways, from moving the marker).

The luma centre is a circle fitted to the marker's silhouette edge: along rays from the estimate,
the strongest rise of brightness from the (darker) marker to the sand, located to sub-pixel, then
an algebraic circle fit with robust weights (rays through a shadow or a neighbour count less).
"""

from __future__ import annotations

import cv2
import numpy as np

from .chroma import LUMA_BGR

N_RAYS = 32
_ANG = np.linspace(0, 2 * np.pi, N_RAYS, endpoint=False)
_COS, _SIN = np.cos(_ANG).astype(np.float32), np.sin(_ANG).astype(np.float32)
STEP = 0.25
MIN_RISE = 2.0  # luma levels per half pixel: a real edge, not noise on flat sand


def edge_centre(frame_bgr, x: float, y: float, radius: float, iterations: int = 3, settle_px: float = 0.35):
    """Centre (x, y) of the marker's dark silhouette near (x, y) in frame coordinates, or None."""
    H, W = frame_bgr.shape[:2]
    R = int(np.ceil(1.8 * radius + 3))
    x0, y0 = int(round(x)) - R, int(round(y)) - R
    if x0 < 0 or y0 < 0 or x0 + 2 * R + 1 > W or y0 + 2 * R + 1 > H:
        return None
    win = frame_bgr[y0:y0 + 2 * R + 1, x0:x0 + 2 * R + 1]
    luma = cv2.transform(np.asarray(win, dtype=np.float32), _LUMA_ROW)
    steps = _steps(radius)
    n = len(steps)
    cx, cy = float(x - x0), float(y - y0)
    for _ in range(iterations):
        px = _COS_S[n] + np.float32(cx)
        py = _SIN_S[n] + np.float32(cy)
        prof = cv2.remap(luma, px, py, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        g = prof[:, 2:] - prof[:, :-2]  # outward rise of brightness (central difference)
        k = np.argmax(g, axis=1)
        np.maximum(k, 1, out=k)  # (np.clip's wrapper costs more than the clipping here)
        np.minimum(k, n - 4, out=k)
        a, b, c = np.take(g, _RAY_BASE[n] + k[:, None]).T  # g[ray, k - 1 .. k + 1]
        den = a - 2 * b + c
        ok = (b > MIN_RISE) & (den < 0)
        if np.count_nonzero(ok) < N_RAYS // 2:
            return None
        a, c, den, k = a[ok], c[ok], den[ok], k[ok]
        t = 0.5 * (a - c) / den
        np.maximum(t, -0.5, out=t)
        np.minimum(t, 0.5, out=t)
        d = steps[k + 1] + t * STEP
        sol = _robust_circle(_COS[ok] * d, _SIN[ok] * d)
        if sol is None:
            return None
        ox, oy, r = sol
        if ox * ox + oy * oy > 4.0 or abs(r - radius) > 0.5 * radius + 1:
            return None
        cx, cy = cx + ox, cy + oy
        if ox * ox + oy * oy < settle_px * settle_px:
            break  # rays from here cross the edge nearly square: another round changes little
    return cx + x0, cy + y0


_LUMA_ROW = LUMA_BGR.reshape(1, 3)
_ROWS = np.arange(N_RAYS)
_ABC = np.array([-1, 0, 1])
_STEPS: dict = {}
_COS_S: dict = {}
_RAY_BASE: dict = {}  # n -> flat index of g[ray, -1 .. 1] (g has n - 2 columns)
_SIN_S: dict = {}


def _steps(radius: float) -> np.ndarray:
    key = round(radius, 1)
    s = _STEPS.get(key)
    if s is None:
        s = np.arange(0.4 * key, 1.7 * key, STEP, dtype=np.float32)
        if len(s) < 6:
            s = np.arange(6, dtype=np.float32) * STEP + 0.4 * key
        _STEPS[key] = s
        n = len(s)
        if n not in _COS_S:
            _COS_S[n] = np.ascontiguousarray(_COS[:, None] * s[None, :])
            _SIN_S[n] = np.ascontiguousarray(_SIN[:, None] * s[None, :])
            _RAY_BASE[n] = (_ROWS * (n - 2))[:, None] + _ABC
    return s


def _robust_circle(x: np.ndarray, y: np.ndarray, rounds: int = 2):
    """Circle through edge points (relative to the current estimate): algebraic (Kasa) fit, then
    re-weighted (Cauchy) by each point's distance from the circle. Returns (cx, cy, r) or None."""
    x = x.astype(np.float64)
    y = y.astype(np.float64)
    z = x * x + y * y
    F = np.array([np.ones_like(x), x, y, z, x * x, x * y, y * y, x * z, y * z])
    w = np.ones(len(x))
    a1 = a2 = r = 0.0
    for k in range(rounds):
        s1, sx, sy, sz, sxx, sxy, syy, sxz, syz = (F @ w).tolist()
        # Normal equations of x^2 + y^2 = 2 a x + 2 b y + c (symmetric 3 x 3), by the adjugate.
        c00, c01, c02 = syy * s1 - sy * sy, sy * sx - sxy * s1, sxy * sy - syy * sx
        c11, c12, c22 = sxx * s1 - sx * sx, sxy * sx - sxx * sy, sxx * syy - sxy * sxy
        det = sxx * c00 + sxy * c01 + sx * c02
        if abs(det) < 1e-12:
            return None
        r0, r1, r2_ = 0.5 * sxz, 0.5 * syz, 0.5 * sz
        a1 = (c00 * r0 + c01 * r1 + c02 * r2_) / det
        a2 = (c01 * r0 + c11 * r1 + c12 * r2_) / det
        a3 = (c02 * r0 + c12 * r1 + c22 * r2_) / det
        r2 = 2 * a3 + a1 * a1 + a2 * a2
        if not r2 > 0:
            return None
        r = r2 ** 0.5
        if k == rounds - 1:
            break  # (the weights below would serve a next round only)
        res = np.hypot(x - a1, y - a2) - r
        scale = 1.4826 * float(np.sort(np.abs(res))[len(res) // 2]) + 0.05  # (np.median: 40 us)
        w = 1.0 / (1.0 + np.square(res / (2 * scale)))
    return a1, a2, r


def intra_frames(source) -> np.ndarray | None:
    """Boolean mask over the source's frames: True where the video frame is intra-coded (a key
    frame). None when the source is not a video file (image folders, in-memory clips)."""
    path = getattr(source, "path", None)
    times = getattr(source, "times_s", None)
    if path is None or times is None or getattr(source, "is_folder", True):
        return None
    known = getattr(source, "keyframes", None)  # FrameSource lists them when it opens the file
    if known is not None and len(known) == len(times):
        return np.asarray(known, dtype=bool)
    import av

    try:
        with av.open(str(path)) as c:
            st = c.streams.video[0]
            tb = float(st.time_base)
            key_t = [p.pts * tb for p in c.demux(st) if p.pts is not None and p.is_keyframe]
    except (av.error.FFmpegError, OSError, ValueError, IndexError):
        return None
    times = np.asarray(times, dtype=np.float64)
    mask = np.zeros(len(times), dtype=bool)
    if key_t and len(times):
        idx = np.clip(np.searchsorted(times, np.array(key_t) - 1e-6), 0, len(times) - 1)
        near = np.abs(times[idx] - np.array(key_t)) < 0.25 / max(float(getattr(source, "fps", 50.0)), 1.0)
        mask[idx[near]] = True
    return mask
