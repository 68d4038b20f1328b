"""Global image motion: how far the whole view moved between two frames (a panning or shaking camera).

When most markers of a camera leave their gates in the same frame, either they were all pushed at
once or the camera moved. The shift of the whole image between the previous frame and this one
(phase correlation of the brightness, a quarter of the resolution, refined to sub-pixel by OpenCV)
tells which: when the view moved, every track of that camera is moved by the shift and searched
again. Nothing is computed while the markers stay in their gates.
"""

from __future__ import annotations

import cv2
import numpy as np

SCALE = 4  # brightness downscaled this much: a 1080p frame becomes 480 x 270
MIN_RESPONSE = 0.08  # phase-correlation peak strength below which no shift is trusted
MIN_SHIFT_PX = 1.0  # shifts smaller than this (full-resolution px) change nothing


def _thumb(frame) -> np.ndarray | None:
    """The frame's brightness at 1/SCALE resolution, float32 (also from a frame in its 4:2:0 planes)."""
    yuv = getattr(frame, "yuv", None)
    if yuv is not None:
        h, w = frame.shape[:2]
        luma = yuv[0][:h, :w]
    else:
        img = np.asarray(frame)
        luma = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
    h, w = luma.shape[:2]
    if min(h, w) < 8 * SCALE:
        return None
    return cv2.resize(luma, (w // SCALE, h // SCALE), interpolation=cv2.INTER_AREA).astype(np.float32)


def image_shift(prev, cur) -> tuple[float, float] | None:
    """(dx, dy) px that the content of `prev` moved to be at in `cur`, or None when the shift is not
    clear or smaller than MIN_SHIFT_PX."""
    a, b = _thumb(prev), _thumb(cur)
    if a is None or b is None or a.shape != b.shape:
        return None
    win = cv2.createHanningWindow(a.shape[::-1], cv2.CV_32F)
    (dx, dy), response = cv2.phaseCorrelate(a, b, win)
    if response < MIN_RESPONSE:
        return None
    dx, dy = dx * SCALE, dy * SCALE
    if np.hypot(dx, dy) < MIN_SHIFT_PX:
        return None
    return float(dx), float(dy)
