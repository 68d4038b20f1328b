"""Finding markers: auto-seeding a frame, snapping a click to a marker, a marker's box.

With an appearance model (appearance.py; learned from a seeded marker, or from the box around a
click), "markers" are every blob that looks like that marker: pixels scoring at or above its
threshold, grouped into blobs, kept when their marker area (soft, as the tracker counts it) is
that of the model; a blob of several touching markers is split at the peaks of the marker-sized
disc filter, and each centre is the coverage centroid of its own share of the blob (detection.py).

With no model, blue markers on sand are found by a generic blueness measure, B - (G + R) / 2,
thresholded relative to the frame's own sand (median + several robust deviations), kept if their
blobs have a marker's size and roundness and are blue; a click on anything else learns a model
from the box around the click. Across two cameras, detections are paired by epipolar distance
with the Hungarian method (naive pairing by position swapped markers).
"""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from ..errors import SandtrackError
from ..video import to_bgr8
from .appearance import AppearanceModel
from .colour import blueness, chroma_blueness
from .detection import detect_like
from .learning import learn

DETECT_COLUMNS = ["x_px", "y_px", "w", "h", "area", "contrast"]
PAIR_MARGIN_PX = 1.0  # a pair's rivals must lie this much farther from the epipolar line than it


def detect_markers(frame_bgr: np.ndarray, min_diameter_px: float = 4.0, max_diameter_px: float = 40.0,
                   k_sigma: float = 6.0, model: AppearanceModel | None = None) -> pd.DataFrame:
    """All markers in a frame: DataFrame[x_px, y_px, w, h, area, contrast]. With `model`, every blob
    that looks like the marker it was learned from (touching markers split); without, blue blobs of
    a marker's size."""
    frame_bgr = to_bgr8(frame_bgr)
    if model is not None:
        return detect_like(frame_bgr, model)
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
        if not _is_blue(frame_bgr[y:y + h, x:x + w][labels[y:y + h, x:x + w] == k]):
            continue  # bluer than the sand, but not blue: a white or grey object
        peak = float(f[labels == k].max())
        wts = _chroma_weights(frame_bgr[ya:yb, xa:xb], (labels[ya:yb, xa:xb] == k))
        tot = float(wts.sum())
        yy, xx = np.mgrid[ya:yb, xa:xb]
        rows.append(((wts * xx).sum() / tot, (wts * yy).sum() / tot, w + 4, h + 4, tot, peak - med))
    return pd.DataFrame(rows, columns=DETECT_COLUMNS)


def _is_blue(pixels: np.ndarray) -> bool:
    """The mean colour of a blob's pixels is blue: blue above both green and red."""
    if not len(pixels):
        return False
    b, g, r = pixels.reshape(-1, 3).astype(np.float64).mean(axis=0)
    return bool(b > g and b > r)


def snap_to_marker(frame_bgr: np.ndarray, x: float, y: float, radius: float = 12,
                   model: AppearanceModel | None = None) -> tuple[float, float] | None:
    """Centre of the marker nearest to (x, y) within `radius` px, or None if there is none. With
    `model`: a blob that looks like its marker; without: a blue marker, or else whatever stands
    out from the sand around the click (a model learned from the box around it; a texture is not
    snapped: the click is its place)."""
    frame_bgr = _window_source(frame_bgr)
    H, W = frame_bgr.shape[:2]
    if not (np.isfinite(x) and np.isfinite(y)) or not (0 <= x < W and 0 <= y < H):
        return None
    if model is not None:
        return _nearest_like(frame_bgr, model, x, y, radius)
    blue = _snap_blue(frame_bgr, x, y, radius)
    if blue is not None:
        return blue
    model = _learn_near(frame_bgr, x, y, radius)
    if model is None:
        return None
    if not model.has_blob:
        return float(x), float(y)
    return _nearest_like(frame_bgr, model, x, y, radius)


def marker_look(frame_bgr: np.ndarray, x: float, y: float, radius: float = 12) -> AppearanceModel | None:
    """The appearance model of the marker at (x, y) (a snapped seed), for showing markers like it;
    None when nothing there stands out as a blob."""
    frame_bgr = _window_source(frame_bgr)
    H, W = frame_bgr.shape[:2]
    if not (np.isfinite(x) and np.isfinite(y)) or not (0 <= x < W and 0 <= y < H):
        return None
    box = 2 * float(radius) + 8
    try:
        model = learn(frame_bgr, x, y, box, box)
    except SandtrackError:
        return None
    return model if model.has_blob else None


def _window_source(frame):
    """A frame as the seeding functions read it: 8-bit BGR (grey and 16-bit images converted)."""
    if isinstance(frame, np.ndarray) and (frame.ndim != 3 or frame.dtype != np.uint8 or frame.shape[2] != 3):
        return to_bgr8(frame)
    return frame


def _learn_near(frame_bgr, x: float, y: float, radius: float) -> AppearanceModel | None:
    """A model learned from a box of the click's uncertainty (plus room for the marker) around it."""
    box = 2 * float(radius) + 8
    try:
        return learn(frame_bgr, x, y, box, box, centred=False)
    except SandtrackError:
        return None


def _nearest_like(frame_bgr, model: AppearanceModel, x: float, y: float, radius: float):
    H, W = frame_bgr.shape[:2]
    R = int(np.ceil(radius + 3 * model.radius + 4))
    x0, y0 = max(int(round(x)) - R, 0), max(int(round(y)) - R, 0)
    x1, y1 = min(int(round(x)) + R + 1, W), min(int(round(y)) + R + 1, H)
    det = detect_like(np.ascontiguousarray(frame_bgr[y0:y1, x0:x1]), model)
    if det.empty:
        return None
    d = np.hypot(det.x_px + x0 - x, det.y_px + y0 - y).to_numpy()
    k = int(np.argmin(d))
    if d[k] > radius:
        return None
    return float(det.x_px.iloc[k] + x0), float(det.y_px.iloc[k] + y0)


def _snap_blue(frame_bgr, x: float, y: float, radius: float) -> tuple[float, float] | None:
    H, W = frame_bgr.shape[:2]
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
    if not _is_blue(frame_bgr[y0:y1, x0:x1][labels == best]):
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
    frame_bgr = _window_source(frame_bgr)
    H, W = frame_bgr.shape[:2]
    R = int(np.ceil(radius)) + 12
    x0, y0 = max(int(round(x)) - R, 0), max(int(round(y)) - R, 0)
    det = detect_markers(frame_bgr[y0:min(int(round(y)) + R + 1, H), x0:min(int(round(x)) + R + 1, W)])
    if not det.empty:
        d = np.hypot(det.x_px + x0 - x, det.y_px + y0 - y)
        k = int(np.argmin(d.to_numpy()))
        if d.iloc[k] <= radius:
            return float(det.w.iloc[k]), float(det.h.iloc[k])
    model = _learn_near(frame_bgr, x, y, radius)
    if model is None or not model.has_blob:
        return None
    side = 2 * np.ceil(model.radius) + 5  # the marker and ~2 px of sand each side, as for blue markers
    return float(side), float(side)


def pair_by_epipolar(stereo, det_a: pd.DataFrame, det_b: pd.DataFrame, max_px: float = 5.0):
    """Pair detections of camera a and b (Hungarian on the symmetric epipolar distance).

    Returns a list of (index_a, index_b, epipolar_px); pairs farther than max_px are dropped, and so
    are pairs with a rival (another detection of either camera) within PAIR_MARGIN_PX of their own
    distance: those stay unpaired, for the operator.
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
    out = []
    for r, c in zip(rows, cols, strict=True):
        if cost[r, c] > max_px:
            continue
        # Another blob about as near the line (a crowd of beads along it): which is the pair is not known.
        rivals = np.concatenate([np.delete(cost[r], c), np.delete(cost[:, c], r)])
        if len(rivals) and rivals.min() <= cost[r, c] + PAIR_MARGIN_PX:
            continue
        out.append((int(r), int(c), float(cost[r, c])))
    return out
