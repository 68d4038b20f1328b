"""Markers at rest or creeping: most markers lie still most of the time (before the tool reaches
them, after it has passed), and many creep a few hundredths of a pixel per frame, pushed by the
sand heap. While the pixels around a marker are those of its last full measurement moved by a
small shift, that measurement moved by the shift holds, and the matching, centroid and edge fits
need not run again.

The shift is one Lucas-Kanade step on brightness: the displacement d that best explains the change
since the reference, d = G^-1 sum(grad I * (I_ref - I)), whose noise is far below a pixel (all the
window's edge pixels vote), plus the residual change that no shift explains (a shadow, the tool,
sand arriving). Only when the shift is small (the step is linear within a fraction of a pixel) and
the residual too is the reference followed; otherwise the marker is measured in full, which
becomes the new reference. Brightness is coded at full resolution and does not trail the motion
in predicted frames as the half-resolution colour does (luma.py), so following it is no loss.
"""

from __future__ import annotations

import cv2
import numpy as np

from .chroma import LUMA_BGR

_LUMA_ROW = LUMA_BGR.reshape(1, 3)


def _luma(frame_bgr, x0: int, y0: int, n: int) -> np.ndarray:
    return cv2.transform(np.asarray(frame_bgr[y0:y0 + n, x0:x0 + n], dtype=np.float32), _LUMA_ROW)


class RestReference:
    """Brightness window of a marker at its last full measurement, ready for the shift test."""

    def __init__(self, frame_bgr, x: float, y: float, radius: float, match):
        self.n = 2 * int(np.ceil(radius + 3)) + 1
        self.x0, self.y0 = int(round(x)) - self.n // 2, int(round(y)) - self.n // 2
        self.match = match
        H, W = frame_bgr.shape[:2]
        self.ok = self.x0 >= 0 and self.y0 >= 0 and self.x0 + self.n <= W and self.y0 + self.n <= H
        if not self.ok:
            return
        ref = _luma(frame_bgr, self.x0, self.y0, self.n)
        gx = cv2.Sobel(ref, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
        gy = cv2.Sobel(ref, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
        gx, gy = gx.ravel(), gy.ravel()
        a, b, c = float(np.dot(gx, gx)), float(np.dot(gx, gy)), float(np.dot(gy, gy))
        det = a * c - b * b
        self.contrast = float(ref.max() - ref.min())
        self.ok = det > 1e-6 and self.contrast > 10.0
        if self.ok:
            self.ref, self.gx, self.gy = ref.ravel(), gx, gy
            self.ginv = (c / det, -b / det, a / det)

    def shift(self, frame_bgr, max_shift_px: float, max_residual: float) -> tuple[float, float] | None:
        """The window's brightness shift (dx, dy) px since the reference when it is at most
        `max_shift_px` and explains the change within `max_residual` rms; else None."""
        if not self.ok:
            return None
        diff = self.ref - _luma(frame_bgr, self.x0, self.y0, self.n).ravel()
        bx, by = float(np.dot(self.gx, diff)), float(np.dot(self.gy, diff))
        i00, i01, i11 = self.ginv
        dx, dy = i00 * bx + i01 * by, i01 * bx + i11 * by
        if dx * dx + dy * dy > max_shift_px * max_shift_px:
            return None
        # Residual of the least-squares shift: |diff - J d|^2 = |diff|^2 - d . J'diff.
        r2 = float(np.dot(diff, diff)) - dx * bx - dy * by
        if r2 > max_residual * max_residual * diff.size:
            return None
        return dx, dy
