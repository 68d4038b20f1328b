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
from .appearance import BRIGHT, DARK
from .chroma import LUMA_BGR

COLUMNS = ["x_px", "y_px", "w", "h", "area", "contrast"]
MIN_FRAC = 0.45  # a blob's marker area, in markers, to count as one
MAX_MARKERS = 400  # blobs of more markers than this are left alone (a large object of the marker's colour)
CROWD_MATCH = 0.6  # correlation with a crowd marker's surroundings from which a place is a marker like it


def detect_like(frame_bgr, model, min_frac: float = MIN_FRAC) -> pd.DataFrame:
    """DataFrame[x_px, y_px, w, h, area, contrast] of every marker like `model` in a BGR image
    (area: marker area found, in px²; contrast: the median score of the marker's pixels)."""
    if not model.has_blob or not frame_bgr.size:
        return pd.DataFrame([], columns=COLUMNS)
    if model.crowd and model.kind in (DARK, BRIGHT) and _patterned(model):
        return _detect_crowd(frame_bgr, model)
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
    for k in range(1, n):
        x, y, w, h, npx = stats[k]
        if npx < 2 or x == 0 or y == 0 or x + w == W or y + h == H:
            continue  # (a blob cut by the image's edge: its centre is not the marker's)
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
        side = 2 * np.ceil(r) + 5
        # (one peak more than the area says: the area of a crowd's inner markers comes out short)
        for cx, cy, frac in split_blob(score, labels == k, model, int(round(count)) + 1, (x, y, w, h)):
            if frac >= min_frac:
                rows.append((cx, cy, side, side, frac * model.disc_area, contrast))
    return pd.DataFrame(rows, columns=COLUMNS)


def split_blob(score: np.ndarray, on: np.ndarray, model, count: int, box: tuple | None = None) -> list[tuple]:
    """A blob of `count` touching markers (pixels `on` of the score image) split into its markers:
    the strongest peaks of the score smoothed by a marker-sized disc, at least ~a radius apart, each
    centred by the coverage centroid of its own share (kernels.centroid_split). [(x, y, coverage /
    marker area)] in the score's coordinates. `box`: (x, y, w, h) of the blob, if known."""
    r = model.radius
    floor = model.weight_floor
    H, W = score.shape
    if box is None:
        ys, xs = np.nonzero(on)
        if not len(xs):
            return []
        box = (int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1))
    x, y, w, h = box
    pad = int(np.ceil(r)) + 2
    sx0, sy0 = max(x - pad, 0), max(y - pad, 0)
    sub = np.ascontiguousarray(score[sy0:min(y + h + pad, H), sx0:min(x + w + pad, W)])
    weights = np.clip((sub - floor) / (1.0 - floor), 0.0, 1.0)
    kern = np.zeros((2 * pad + 1, 2 * pad + 1), np.float32)
    cv2.circle(kern, (pad, pad), max(int(round(r)), 1), 1.0, -1)
    smooth = cv2.filter2D(weights, cv2.CV_32F, kern / kern.sum(), borderType=cv2.BORDER_CONSTANT)
    sub_on = np.zeros(sub.shape, bool)
    sub_on[y - sy0:y - sy0 + h, x - sx0:x - sx0 + w] = on[y:y + h, x:x + w]
    peaks = _peaks(smooth, sub_on, count, r)
    px = np.array([p[0] for p in peaks], np.float64)
    py = np.array([p[1] for p in peaks], np.float64)
    out = []
    for i in range(len(peaks)):
        cx, cy, frac = kernels.centroid_split(sub, float(px[i]), float(py[i]), 3, r + 1.5, floor, model.disc_area,
                                              np.delete(px, i), np.delete(py, i))
        out.append((cx + sx0, cy + sy0, frac))
    return out


def _peaks(smooth: np.ndarray, on: np.ndarray, n: int, r: float) -> list[tuple[int, int]]:
    """Up to `n` strongest local maxima of `smooth` on the pixels `on`, at least ~r apart."""
    size = max(int(2 * round(0.8 * r)) + 1, 3)
    local = (smooth >= cv2.dilate(smooth, np.ones((size, size), np.uint8))) & on & (smooth > 0)
    ys, xs = np.nonzero(local)
    order = np.argsort(-smooth[ys, xs])
    chosen: list[tuple[int, int]] = []
    for i in order:
        px, py = int(xs[i]), int(ys[i])
        if all((px - qx) ** 2 + (py - qy) ** 2 >= (1.2 * r) ** 2 for qx, qy in chosen):
            chosen.append((px, py))
        if len(chosen) >= n:
            break
    return chosen


def _patterned(model) -> bool:
    """A crowd marker with a brightness pattern of its own (a shading, a highlight: what tells touching
    beads apart in their mass), not a plain disc (those are split at the peaks of their blob)."""
    p = model.pattern
    if p is None or not model.levels:
        return False
    half = p.shape[0] // 2
    yy, xx = np.mgrid[0:p.shape[0], 0:p.shape[1]]
    disc = np.hypot(xx - half, yy - half) <= 0.9 * model.radius
    return float(np.std(p[disc])) >= 0.05 * abs(model.levels[0] - model.levels[1])


def _detect_crowd(frame_bgr, model) -> pd.DataFrame:
    """Markers like one learned among touching markers (a dense layer of identical beads): where the
    brightness of the learned one (its shading, its highlight; a disc of 0.9 radii) is found again
    (normalised cross-correlation of at least CROWD_MATCH, local peaks a radius apart); each is then
    centred on its outline where it borders the gaps (luma.edge_circle; the contacts with its
    neighbours show none) and kept when that outline has the marker's radius and is seen all around
    it, both as a free circle and as one of the marker's own radius (a bead half hidden behind another
    is not centred across that side). Peaks that end on the same marker are one."""
    from .luma import edge_circle

    r = model.radius
    if model.pattern is None:
        return pd.DataFrame([], columns=COLUMNS)
    luma = (frame_bgr.astype(np.float32) @ LUMA_BGR).astype(np.float32)
    half = model.pattern.shape[0] // 2
    disc = np.zeros(model.pattern.shape, np.float32)
    cv2.circle(disc, (half, half), max(int(round(0.9 * r)), 1), 1.0, -1)  # the marker itself, not its neighbours
    res = cv2.matchTemplate(luma, model.pattern, cv2.TM_CCOEFF_NORMED, mask=disc)
    cv2.patchNaNs(res, -1.0)
    size = max(int(2 * round(0.8 * r)) + 1, 3)
    peaks = (res >= cv2.dilate(res, np.ones((size, size), np.uint8))) & (res >= CROWD_MATCH)
    ys, xs = np.nonzero(peaks)
    H, W = frame_bgr.shape[:2]
    rows: list[tuple] = []
    polarity = 1.0 if model.kind == DARK else -1.0
    for i in np.argsort(-res[ys, xs], kind="stable"):
        x, y = float(xs[i] + half), float(ys[i] + half)
        c = edge_circle(frame_bgr, x, y, r, iterations=5, polarity=polarity, outward=model.kind == DARK)
        if c is None or abs(c[2] - r) > 0.3 * r or np.hypot(c[0] - x, c[1] - y) > 0.6 * r or c[3] < 4:
            continue
        # (a bead half hidden behind another may show an outline all round it of about its radius, drawn
        # over the other's: a circle of its own radius leaves a quadrant with no outline on it)
        known = edge_circle(frame_bgr, x, y, r, iterations=5, polarity=polarity, outward=model.kind == DARK,
                            known_radius=True)
        if known is None or known[3] < 4:
            continue
        if not (r + 1 <= c[0] <= W - 2 - r and r + 1 <= c[1] <= H - 2 - r):
            continue  # (cut by the image's edge)
        if any(np.hypot(c[0] - q[0], c[1] - q[1]) < r for q in rows):
            continue
        side = 2 * np.ceil(r) + 5
        rows.append((float(c[0]), float(c[1]), side, side, model.disc_area, float(res[ys[i], xs[i]])))
    return pd.DataFrame(rows, columns=COLUMNS)
