"""Finding markers with no model yet: auto-seeding a frame and snapping a click to a marker.

Blue markers on sand are found by a generic blueness measure, B - (G + R) / 2, thresholded
relative to the frame's own sand (median + several robust deviations), then kept if their blobs
have a marker's size and roundness. Across two cameras, detections are paired by epipolar
distance with the Hungarian method (naive pairing by position swapped markers).
"""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from .colour import blueness, chroma_blueness

DETECT_COLUMNS = ["x_px", "y_px", "w", "h", "area", "contrast"]


def detect_markers(frame_bgr: np.ndarray, min_diameter_px: float = 4.0, max_diameter_px: float = 40.0,
                   k_sigma: float = 6.0) -> pd.DataFrame:
    """All blue blobs of a marker's size in a frame: DataFrame[x_px, y_px, w, h, area, contrast]."""
    f = blueness(frame_bgr)
    small = f[::4, ::4]
    med = float(np.median(small))
    mad = 1.4826 * float(np.median(np.abs(small - med))) + 1.0
    thr = med + max(k_sigma * mad, 25.0)
    mask = (f >= thr).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    min_a, max_a = np.pi * (min_diameter_px / 2) ** 2 * 0.5, np.pi * (max_diameter_px / 2) ** 2
    rows = []
    H, W = f.shape
    for k in range(1, n):
        x, y, w, h, area = stats[k]
        if not (min_a <= area <= max_a):
            continue
        if max(w, h) > 2.2 * min(w, h) + 1 or area < 0.45 * w * h:
            continue  # not round: streaks, edges of larger blue things
        xa, ya, xb, yb = max(x - 2, 0), max(y - 2, 0), min(x + w + 2, W), min(y + h + 2, H)
        peak = float(f[labels == k].max())
        wts = _chroma_weights(frame_bgr[ya:yb, xa:xb], (labels[ya:yb, xa:xb] == k))
        tot = float(wts.sum())
        yy, xx = np.mgrid[ya:yb, xa:xb]
        rows.append(((wts * xx).sum() / tot, (wts * yy).sum() / tot, w + 4, h + 4, tot, peak - med))
    return pd.DataFrame(rows, columns=DETECT_COLUMNS)


def snap_to_marker(frame_bgr: np.ndarray, x: float, y: float, radius: float = 12) -> tuple[float, float] | None:
    """Centroid of the blue marker nearest to (x, y) within `radius` px, or None if there is none."""
    H, W = frame_bgr.shape[:2]
    if not (np.isfinite(x) and np.isfinite(y)) or not (0 <= x < W and 0 <= y < H):
        return None
    R = int(np.ceil(radius)) + 12
    x0, y0 = max(int(round(x)) - R, 0), max(int(round(y)) - R, 0)
    x1, y1 = min(int(round(x)) + R + 1, W), min(int(round(y)) + R + 1, H)
    f = blueness(frame_bgr[y0:y1, x0:x1])
    bg = float(np.median(f))
    mad = 1.4826 * float(np.median(np.abs(f - bg))) + 1.0
    peak = float(cv2.GaussianBlur(f, (3, 3), 0).max())
    if peak - bg < max(6 * mad, 20.0):
        return None
    thr = bg + 0.5 * (peak - bg)
    mask = (f >= thr).astype(np.uint8)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    best, best_d = None, np.inf
    for k in range(1, n):
        if stats[k, 4] < 3:
            continue
        d = np.hypot(cents[k, 0] + x0 - x, cents[k, 1] + y0 - y)
        if d < best_d:
            best, best_d = k, d
    if best is None or best_d > radius:
        return None
    wts = _chroma_weights(frame_bgr[y0:y1, x0:x1], labels == best)
    tot = float(wts.sum())
    yy, xx = np.mgrid[0:f.shape[0], 0:f.shape[1]]
    return float((wts * xx).sum() / tot + x0), float((wts * yy).sum() / tot + y0)


def _chroma_weights(bgr: np.ndarray, comp: np.ndarray) -> np.ndarray:
    """Marker coverage weights on a blob (grown by one pixel), from chromaticity: shading and the
    marker's contact shadow do not move the centroid."""
    c = chroma_blueness(bgr)
    grown = cv2.dilate(comp.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    ring = cv2.dilate(grown.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    ring &= ~grown
    bg = float(np.median(c[ring])) if ring.any() else float(np.median(c))
    inner = c[comp]
    peak = float(np.percentile(inner, 75)) if inner.size else bg + 1e-3
    return np.clip((c - bg) / max(peak - bg, 1e-3), 0, 1) * grown


def marker_box(frame_bgr: np.ndarray, x: float, y: float, radius: float = 12) -> tuple[float, float] | None:
    """Size (w, h) of a box around the marker at (x, y) with a little sand around it, or None."""
    H, W = frame_bgr.shape[:2]
    R = int(np.ceil(radius)) + 12
    x0, y0 = max(int(round(x)) - R, 0), max(int(round(y)) - R, 0)
    det = detect_markers(frame_bgr[y0:min(int(round(y)) + R + 1, H), x0:min(int(round(x)) + R + 1, W)])
    if det.empty:
        return None
    d = np.hypot(det.x_px + x0 - x, det.y_px + y0 - y)
    k = int(np.argmin(d.to_numpy()))
    if d.iloc[k] > radius:
        return None
    return float(det.w.iloc[k]), float(det.h.iloc[k])


def pair_by_epipolar(stereo, det_a: pd.DataFrame, det_b: pd.DataFrame, max_px: float = 5.0):
    """Pair detections of camera a and b (Hungarian on the symmetric epipolar distance).

    Returns a list of (index_a, index_b, epipolar_px); pairs farther than max_px are dropped.
    """
    if det_a.empty or det_b.empty:
        return []
    a, b = stereo.cams
    pa = det_a[["x_px", "y_px"]].to_numpy(float)
    pb = det_b[["x_px", "y_px"]].to_numpy(float)
    ia, ib = np.meshgrid(np.arange(len(pa)), np.arange(len(pb)), indexing="ij")
    d_ab = stereo.distance(a, pa[ia.ravel()], b, pb[ib.ravel()]).reshape(len(pa), len(pb))
    d_ba = stereo.distance(b, pb[ib.ravel()], a, pa[ia.ravel()]).reshape(len(pa), len(pb))
    cost = 0.5 * (d_ab + d_ba)
    big = 1e6
    rows, cols = linear_sum_assignment(np.where(cost <= max_px, cost, big))
    return [(int(r), int(c), float(cost[r, c])) for r, c in zip(rows, cols, strict=True) if cost[r, c] <= max_px]
