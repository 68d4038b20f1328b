"""Every marker in an image that looks like a given marker (its appearance model), touching ones split.

Pixels scoring at or above the model's threshold are grouped into blobs (8-connected). A blob's
marker area is its soft area (each pixel weighted by its coverage, as the tracker counts it);
divided by the model's marker area it says how many markers the blob holds. One: its coverage
centroid. Several (markers touching in a dense layer): the score is smoothed by a disc of the
marker's radius and the blob's strongest local peaks at least a marker radius apart are its
markers, each centred by the coverage centroid of its own share of the blob (the pixels nearer to
it than to the other peaks; kernels.centroid_split). Blobs far smaller than a marker, or of
clearly more markers than fit, are left out.
"""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd

from . import kernels

COLUMNS = ["x_px", "y_px", "w", "h", "area", "contrast"]
MIN_FRAC = 0.45  # a blob's marker area, in markers, to count as one
MAX_MARKERS = 12  # blobs of more markers than this are left alone (a large object of the marker's colour)


def detect_like(frame_bgr, model, min_frac: float = MIN_FRAC) -> pd.DataFrame:
    """DataFrame[x_px, y_px, w, h, area, contrast] of every marker like `model` in a BGR image
    (area: marker area found, in px²; contrast: the median score of the marker's pixels)."""
    if not model.has_blob or not frame_bgr.size:
        return pd.DataFrame([], columns=COLUMNS)
    score = model.score(frame_bgr)
    mask = (score >= model.threshold).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return pd.DataFrame([], columns=COLUMNS)
    r = model.radius
    floor = model.weight_floor
    weights = np.clip((score - floor) / (1.0 - floor), 0.0, 1.0)
    H, W = score.shape
    rows = []
    smooth = None
    empty = np.zeros(0)
    pad = int(np.ceil(r)) + 2
    for k in range(1, n):
        x, y, w, h, npx = stats[k]
        if npx < 2:
            continue
        xa, ya, xb, yb = max(x - 1, 0), max(y - 1, 0), min(x + w + 1, W), min(y + h + 1, H)
        grown = cv2.dilate((labels[ya:yb, xa:xb] == k).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        area = float(weights[ya:yb, xa:xb][grown].sum())
        count = area / model.disc_area
        if count < min_frac or count > MAX_MARKERS + 0.5:
            continue
        inside = score[y:y + h, x:x + w][labels[y:y + h, x:x + w] == k]
        contrast = float(np.median(inside))
        if count < 1.5:
            wts = weights[ya:yb, xa:xb] * grown
            yy, xx = np.mgrid[ya:yb, xa:xb]
            tot = float(wts.sum())
            cx, cy = float((wts * xx).sum() / tot), float((wts * yy).sum() / tot)
            rows.append((cx, cy, w + 4, h + 4, area, contrast))
            continue
        if smooth is None:
            kern = np.zeros((2 * pad + 1, 2 * pad + 1), np.float32)
            cv2.circle(kern, (pad, pad), max(int(round(r)), 1), 1.0, -1)
            smooth = cv2.filter2D(weights, cv2.CV_32F, kern / kern.sum(), borderType=cv2.BORDER_CONSTANT)
        peaks = _peaks(smooth, labels, k, x, y, w, h, int(round(count)), r)
        sub_x0, sub_y0 = max(x - pad, 0), max(y - pad, 0)
        sub = score[sub_y0:min(y + h + pad, H), sub_x0:min(x + w + pad, W)]
        px = np.array([p[0] - sub_x0 for p in peaks], np.float64)
        py = np.array([p[1] - sub_y0 for p in peaks], np.float64)
        for i in range(len(peaks)):
            others_x, others_y = (np.delete(px, i), np.delete(py, i)) if len(peaks) > 1 else (empty, empty)
            cx, cy, frac = kernels.centroid_split(sub, float(px[i]), float(py[i]), 3, r + 1.5, floor,
                                                  model.disc_area, others_x, others_y)
            if frac >= min_frac:
                side = 2 * np.ceil(r) + 5
                rows.append((cx + sub_x0, cy + sub_y0, side, side, frac * model.disc_area, contrast))
    return pd.DataFrame(rows, columns=COLUMNS)


def _peaks(smooth: np.ndarray, labels: np.ndarray, k: int, x: int, y: int, w: int, h: int, n: int,
           r: float) -> list[tuple[int, int]]:
    """Up to `n` strongest local maxima of `smooth` on component k, at least ~r apart."""
    box = smooth[y:y + h, x:x + w]
    on = labels[y:y + h, x:x + w] == k
    size = max(int(2 * round(0.8 * r)) + 1, 3)
    local = (box >= cv2.dilate(box, np.ones((size, size), np.uint8))) & on & (box > 0)
    ys, xs = np.nonzero(local)
    order = np.argsort(-box[ys, xs])
    chosen: list[tuple[int, int]] = []
    for i in order:
        px, py = int(xs[i]) + x, int(ys[i]) + y
        if all((px - qx) ** 2 + (py - qy) ** 2 >= (1.2 * r) ** 2 for qx, qy in chosen):
            chosen.append((px, py))
        if len(chosen) >= n:
            break
    return chosen
