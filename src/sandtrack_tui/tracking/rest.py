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
in predicted frames as the half-resolution colour does (luma.py), so following it is no loss. A
frame still in its 4:2:0 planes (yuv.py) is read in that coded brightness itself (its brightness
plane, in the levels of the BGR conversion): the brightness of its BGR pixels would mix in the
half-resolution colour wherever a channel clips, and converting a window costs more than the test.
"""

from __future__ import annotations

import numpy as np

from . import kernels


class RestReference:
    """Brightness window of a marker at its last full measurement, ready for the shift test."""

    def __init__(self, frame_bgr, x: float, y: float, radius: float, match, residual: float = 3.0,
                 residual_frac: float = 0.03):
        self.n = 2 * int(np.ceil(radius + 3)) + 1
        self.residual_limit = residual
        self.x0, self.y0 = int(round(x)) - self.n // 2, int(round(y)) - self.n // 2
        self.match = match
        H, W = frame_bgr.shape[:2]
        self.ok = self.x0 >= 0 and self.y0 >= 0 and self.x0 + self.n <= W and self.y0 + self.n <= H
        if not self.ok:
            return
        # Gradients: Sobel 3 x 3 / 8; ginv: the inverse of the 2 x 2 normal matrix (xx, xy, yy).
        yuv = getattr(frame_bgr, "yuv", None)  # a frame still in its 4:2:0 planes (yuv.py): its brightness plane
        if yuv is not None:
            out = kernels.rest_reference_luma(yuv[0], yuv[3][0], self.x0, self.y0, self.n)
        else:
            out = kernels.rest_reference(self._window(frame_bgr))
        self.ok, self.contrast, self.ref, self.gx, self.gy, self.ginv = out
        # The change no shift explains that still counts as rest: rms levels, at least `residual`,
        # more on a marker of strong contrast.
        self.residual_limit = max(residual, residual_frac * self.contrast)

    def _window(self, frame_bgr):
        return frame_bgr[self.y0:self.y0 + self.n, self.x0:self.x0 + self.n]

    def shift(self, frame_bgr, max_shift_px: float, max_residual: float) -> tuple[float, float] | None:
        """The window's brightness shift (dx, dy) px since the reference when it is at most
        `max_shift_px` and explains the change within `max_residual` rms; else None."""
        if not self.ok:
            return None
        yuv = getattr(frame_bgr, "yuv", None)
        if yuv is not None:
            ok, dx, dy = kernels.rest_shift_luma(yuv[0], yuv[3][0], self.x0, self.y0, self.ref, self.gx, self.gy,
                                                 self.ginv, max_shift_px, max_residual)
        else:
            ok, dx, dy = kernels.rest_shift(self._window(frame_bgr), self.ref, self.gx, self.gy, self.ginv,
                                            max_shift_px, max_residual)
        return (dx, dy) if ok else None
