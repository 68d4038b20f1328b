"""Re-acquisition: a marker-coloured blob that no track explains re-attaches a coasting track.

A coasting (occluded or lost) track looks for blobs of its marker's colour and size inside its
widened gate; a blob of several touching markers counts as one blob per marker (detection.py).
A blob already explained by another track of the same camera is not a candidate.
Exactly one candidate re-attaches the track (after a template check); two or more, or one blob
wanted by two tracks, is ambiguous and left to the operator: the track keeps coasting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import find_objects

from .appearance import BRIGHT, DARK, AppearanceModel
from .detection import split_blob

SPLIT_FROM = 1.6  # a blob of this many markers' area or more is split into touching markers
MAX_SPLIT = 12


@dataclass
class Blob:
    x: float
    y: float
    area: float  # soft marker area, px²


def find_blobs(frame_bgr: np.ndarray, model: AppearanceModel, cx: float, cy: float, hx: float, hy: float,
               min_frac: float = 0.4, max_frac: float = 2.5, threshold: float | None = None) -> list[Blob]:
    """Blobs of the model's colour and roughly its size whose centre lies within (hx, hy) of (cx, cy);
    pixels count from `threshold` (default: the model's; lower for a streak, whose coverage is spread)."""
    x0, y0, x1, y1 = search_window(frame_bgr.shape, model, cx, cy, hx, hy)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return []
    if model.kind in (DARK, BRIGHT):
        score = model.prepared(model.score_window(frame_bgr, x0, y0, x1, y1))
        return _blobs_in_score(model, score, x0, y0, cx, cy, hx, hy, min_frac, max_frac, threshold)
    mask, found, bx0, by0, bx1, by1 = model.mask_box(frame_bgr, x0, y0, x1, y1, threshold)
    if not found:  # most searches of a hidden marker: nothing of its colour in sight
        return []
    # Only the part of the window holding marker colour is labelled (plus 2 px: the moments look one
    # pixel around a component); the components and their order are those of the whole window.
    bx0, by0 = max(bx0 - 2, 0), max(by0 - 2, 0)
    bx1, by1 = min(bx1 + 2, mask.shape[1]), min(by1 + 2, mask.shape[0])
    mask = np.ascontiguousarray(mask[by0:by1, bx0:bx1])
    x0, y0 = x0 + bx0, y0 + by0
    # (connectedComponentsWithStats took ~5x as long as the labelling alone on these windows)
    n, labels = cv2.connectedComponents(mask, connectivity=8)
    if n <= 1:
        return []
    out = []
    for k, sl in enumerate(find_objects(labels), start=1):
        if sl is None:
            continue
        # Soft area and centroid over the component grown by one pixel (its anti-aliased rim). Only the
        # component's box is read from the frame (a frame in its 4:2:0 planes converts what is read: the
        # marker-coloured pixels of a hidden marker's wide window may lie far apart).
        xa, ya = max(sl[1].start - 1, 0), max(sl[0].start - 1, 0)
        xb, yb = min(sl[1].stop + 1, mask.shape[1]), min(sl[0].stop + 1, mask.shape[0])
        win = np.ascontiguousarray(frame_bgr[y0 + ya:y0 + yb, x0 + xa:x0 + xb])
        area, m10, m01, pixels = model.blob_moments(win, np.ascontiguousarray(labels[ya:yb, xa:xb]), k, 0, 0,
                                                    xb - xa, yb - ya)
        if pixels < 2 or area < min_frac * model.disc_area:
            continue
        if area >= SPLIT_FROM * model.disc_area:  # touching markers: one blob each
            score = model.score(win)
            parts = _split(model, score, labels[ya:yb, xa:xb] == k, area, xa + x0, ya + y0)
        elif area <= max_frac * model.disc_area:
            parts = [Blob(m10 / area + xa + x0, m01 / area + ya + y0, area)]
        else:
            continue
        out += [b for b in parts if abs(b.x - cx) <= hx and abs(b.y - cy) <= hy]
    return out


def search_window(shape: tuple, model: AppearanceModel, cx: float, cy: float, hx: float, hy: float) -> tuple:
    """(x0, y0, x1, y1): the pixels find_blobs reads for centres within (hx, hy) of (cx, cy)."""
    H, W = shape[:2]
    pad = int(math.ceil(model.radius)) + 2
    return (max(math.floor(cx - hx) - pad, 0), max(math.floor(cy - hy) - pad, 0),
            min(math.ceil(cx + hx) + pad + 1, W), min(math.ceil(cy + hy) + pad + 1, H))


def search_windows(shape: tuple, model: AppearanceModel, cx: np.ndarray, cy: np.ndarray, hx: float, hy: float
                   ) -> np.ndarray:
    """search_window of each centre (cx, cy) (float arrays): (n, 4) int64, in one array operation."""
    H, W = shape[:2]
    pad = int(math.ceil(model.radius)) + 2
    return np.stack([np.maximum(np.floor(cx - hx).astype(np.int64) - pad, 0),
                     np.maximum(np.floor(cy - hy).astype(np.int64) - pad, 0),
                     np.minimum(np.ceil(cx + hx).astype(np.int64) + pad + 1, W),
                     np.minimum(np.ceil(cy + hy).astype(np.int64) + pad + 1, H)], axis=1)


def _split(model: AppearanceModel, score: np.ndarray, on: np.ndarray, area: float, x0: int, y0: int) -> list[Blob]:
    """A blob of several touching markers as one Blob per marker (detection.split_blob)."""
    count = int(round(area / model.disc_area))
    if count > MAX_SPLIT:
        return []
    return [Blob(x + x0, y + y0, frac * model.disc_area)
            for x, y, frac in split_blob(score, on, model, count) if frac >= 0.5]


def _blobs_in_score(model: AppearanceModel, score: np.ndarray, x0: int, y0: int, cx: float, cy: float,
                    hx: float, hy: float, min_frac: float, max_frac: float, threshold: float | None) -> list[Blob]:
    """find_blobs on a prepared score window (brightness models: the sand level is the window's)."""
    t = model.threshold if threshold is None else threshold
    mask = (score >= t).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return []
    floor = model.weight_floor
    weights = np.clip((score - floor) / (1.0 - floor), 0.0, 1.0)
    # Most components of a brightness window are sand grains past the threshold: a bound on each
    # one's soft area (its own weights, plus its box's rim at most as heavy as a pixel just below the
    # threshold) leaves only those that may be a marker to look at one by one.
    own = np.bincount(labels.ravel(), weights=weights.ravel(), minlength=n)
    rim = (stats[:, cv2.CC_STAT_WIDTH] + 2) * (stats[:, cv2.CC_STAT_HEIGHT] + 2) - stats[:, cv2.CC_STAT_AREA]
    may = (stats[:, cv2.CC_STAT_AREA] >= 2) & (own + rim * min(max((t - floor) / (1.0 - floor), 0.0), 1.0)
                                               >= min_frac * model.disc_area)
    out = []
    objects = find_objects(labels)
    for k in (np.flatnonzero(may[1:len(objects) + 1]) + 1).tolist():  # (most are grains: not looped over)
        sl = objects[k - 1]
        if sl is None:
            continue
        ya, yb = max(sl[0].start - 1, 0), min(sl[0].stop + 1, mask.shape[0])
        xa, xb = max(sl[1].start - 1, 0), min(sl[1].stop + 1, mask.shape[1])
        grown = cv2.dilate((labels[ya:yb, xa:xb] == k).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        w = weights[ya:yb, xa:xb] * grown
        area = float(w.sum())
        if np.count_nonzero(labels[ya:yb, xa:xb] == k) < 2 or area < min_frac * model.disc_area:
            continue
        if area >= SPLIT_FROM * model.disc_area:  # touching markers: one blob each
            parts = _split(model, np.ascontiguousarray(score[ya:yb, xa:xb]), labels[ya:yb, xa:xb] == k, area,
                           xa + x0, ya + y0)
        elif area <= max_frac * model.disc_area:
            yy, xx = np.mgrid[ya:yb, xa:xb]
            parts = [Blob(float((w * xx).sum()) / area + x0, float((w * yy).sum()) / area + y0, area)]
        else:
            continue
        out += [b for b in parts if abs(b.x - cx) <= hx and abs(b.y - cy) <= hy]
    return out


def unexplained(blobs: list[Blob], explained_xy: np.ndarray, radius: float) -> list[Blob]:
    """Blobs farther than `radius` from every explained position."""
    if len(explained_xy) == 0:
        return blobs
    e = np.asarray(explained_xy, dtype=float).reshape(-1, 2)
    return [b for b in blobs if np.min(np.hypot(e[:, 0] - b.x, e[:, 1] - b.y)) > radius]
