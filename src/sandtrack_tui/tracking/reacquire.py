"""Re-acquisition: a marker-coloured blob that no track explains re-attaches a coasting track.

A coasting (occluded or lost) track looks for blobs of its marker's colour and size inside its
widened gate. A blob already explained by another track of the same camera is not a candidate.
Exactly one candidate re-attaches the track (after a template check); two or more, or one blob
wanted by two tracks, is ambiguous and left to the operator: the track keeps coasting.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import find_objects

from .appearance import AppearanceModel


@dataclass
class Blob:
    x: float
    y: float
    area: float  # soft marker area, px²


def find_blobs(frame_bgr: np.ndarray, model: AppearanceModel, cx: float, cy: float, hx: float, hy: float,
               min_frac: float = 0.4, max_frac: float = 2.5) -> list[Blob]:
    """Blobs of the model's colour and roughly its size whose centre lies within (hx, hy) of (cx, cy)."""
    H, W = frame_bgr.shape[:2]
    pad = int(np.ceil(model.radius)) + 2
    x0, x1 = max(int(np.floor(cx - hx)) - pad, 0), min(int(np.ceil(cx + hx)) + pad + 1, W)
    y0, y1 = max(int(np.floor(cy - hy)) - pad, 0), min(int(np.ceil(cy + hy)) + pad + 1, H)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return []
    mask, found, bx0, by0, bx1, by1 = model.mask_box(frame_bgr, x0, y0, x1, y1)
    if not found:  # most searches of a hidden marker: nothing of its colour in sight
        return []
    # Only the part of the window holding marker colour is labelled (plus 2 px: the moments look one
    # pixel around a component); the components and their order are those of the whole window.
    bx0, by0 = max(bx0 - 2, 0), max(by0 - 2, 0)
    bx1, by1 = min(bx1 + 2, mask.shape[1]), min(by1 + 2, mask.shape[0])
    mask = np.ascontiguousarray(mask[by0:by1, bx0:bx1])
    x0, y0 = x0 + bx0, y0 + by0
    win = frame_bgr[y0:y0 + mask.shape[0], x0:x0 + mask.shape[1]]
    # (connectedComponentsWithStats took ~5x as long as the labelling alone on these windows)
    n, labels = cv2.connectedComponents(mask, connectivity=8)
    if n <= 1:
        return []
    out = []
    for k, sl in enumerate(find_objects(labels), start=1):
        if sl is None:
            continue
        # Soft area and centroid over the component grown by one pixel (its anti-aliased rim).
        xa, ya = max(sl[1].start - 1, 0), max(sl[0].start - 1, 0)
        xb, yb = min(sl[1].stop + 1, mask.shape[1]), min(sl[0].stop + 1, mask.shape[0])
        area, m10, m01, pixels = model.blob_moments(win, labels, k, xa, ya, xb, yb)
        if pixels < 2 or not (min_frac * model.disc_area <= area <= max_frac * model.disc_area):
            continue
        bx_c, by_c = m10 / area + xa + x0, m01 / area + ya + y0
        if abs(bx_c - cx) <= hx and abs(by_c - cy) <= hy:
            out.append(Blob(bx_c, by_c, area))
    return out


def unexplained(blobs: list[Blob], explained_xy: np.ndarray, radius: float) -> list[Blob]:
    """Blobs farther than `radius` from every explained position."""
    if len(explained_xy) == 0:
        return blobs
    e = np.asarray(explained_xy, dtype=float).reshape(-1, 2)
    return [b for b in blobs if np.min(np.hypot(e[:, 0] - b.x, e[:, 1] - b.y)) > radius]
