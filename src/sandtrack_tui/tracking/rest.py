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

Most of a camera's markers are at rest in most frames: a `RestBank` keeps the references of one
camera's tracks side by side, and tests all of them in one compiled call per frame (the same
arithmetic as each reference's own `shift`), where one call per marker cost more in entering the
call than in the test.
"""

from __future__ import annotations

import numpy as np

from . import kernels


def window_size(radius: float) -> int:
    """Side of the brightness window of a marker of this radius, px."""
    return 2 * int(np.ceil(radius + 3)) + 1


class RestReference:
    """Brightness window of a marker at its last full measurement, ready for the shift test."""

    def __init__(self, frame_bgr, x: float, y: float, radius: float, match, residual: float = 3.0,
                 residual_frac: float = 0.03):
        self.n = window_size(radius)
        self.residual_limit = residual
        self.x0, self.y0 = int(round(x)) - self.n // 2, int(round(y)) - self.n // 2
        self.match = match
        H, W = frame_bgr.shape[:2]
        self.ok = self.x0 >= 0 and self.y0 >= 0 and self.x0 + self.n <= W and self.y0 + self.n <= H
        if not self.ok:
            return
        # Gradients: Sobel 3 x 3 / 8; ginv: the inverse of the 2 x 2 normal matrix (xx, xy, yy).
        yuv = getattr(frame_bgr, "yuv", None)  # a frame still in its 4:2:0 planes (yuv.py)
        if yuv is not None:
            out = kernels.rest_reference_yuv(*yuv, self.x0, self.y0, self.n)
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
            ok, dx, dy = kernels.rest_shift_yuv(*yuv, self.x0, self.y0, self.ref, self.gx, self.gy, self.ginv,
                                                max_shift_px, max_residual)
        else:
            ok, dx, dy = kernels.rest_shift(self._window(frame_bgr), self.ref, self.gx, self.gy, self.ginv,
                                            max_shift_px, max_residual)
        return (dx, dy) if ok else None


class RestBank:
    """The rest references of one camera's tracks, a row each in shared arrays: `shifts` tests many
    of them on a frame in its 4:2:0 planes in one call. A track takes a row (`add`) and puts each new
    reference there (`put`); a row holds the reference until the next is put."""

    def __init__(self):
        self.rows = 0
        self.n = np.zeros(0, np.int64)
        self.x0 = np.zeros(0, np.int64)
        self.y0 = np.zeros(0, np.int64)
        self.ref = self.gx = self.gy = np.zeros((0, 0), np.float32)
        self.ginv = np.zeros((0, 3))
        self.max_shift_px = np.zeros(0)
        self.max_residual = np.zeros(0)

    def add(self, radius: float) -> int:
        """A new row for a track of a marker of this radius; returns its index."""
        n = window_size(radius)
        width = max(self.ref.shape[1], n * n)
        i, self.rows = self.rows, self.rows + 1
        self.n, self.x0, self.y0 = (np.append(a, 0) for a in (self.n, self.x0, self.y0))
        self.max_shift_px, self.max_residual = np.append(self.max_shift_px, 0.0), np.append(self.max_residual, 0.0)
        self.ginv = np.vstack([self.ginv, np.zeros((1, 3))])
        grown = ((0, 1), (0, width - self.ref.shape[1]))
        self.ref, self.gx, self.gy = (np.pad(a, grown) for a in (self.ref, self.gx, self.gy))
        self.n[i] = n
        return i

    def put(self, row: int, reference: RestReference, max_shift_px: float) -> None:
        """Row `row` now holds this (usable) reference, tested up to max_shift_px."""
        m = reference.n * reference.n
        self.ref[row, :m], self.gx[row, :m], self.gy[row, :m] = reference.ref, reference.gx, reference.gy
        self.ginv[row] = reference.ginv
        self.x0[row], self.y0[row] = reference.x0, reference.y0
        self.max_shift_px[row], self.max_residual[row] = max_shift_px, reference.residual_limit

    def shifts(self, yuv: tuple, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ok, dx, dy) per row of `rows` (int64): RestReference.shift of each row's reference on the
        frame whose planes and tables are `yuv` (Yuv420Frame.yuv)."""
        return kernels.rest_shifts_yuv(*yuv, rows, self.n, self.x0, self.y0, self.ref, self.gx, self.gy, self.ginv,
                                       self.max_shift_px, self.max_residual)
