"""Template matching of one marker: NCC on the colour-score image, sub-pixel peak, colour centroid.

Matching runs on the marker's colour score (see colour.py) rather than on grey levels: the sand's
texture, which is brightness, scores ~0 everywhere, so the marker's disc is the only structure the
template sees. Two templates are matched: the one cut at the seed (never changes, so the track
cannot drift) and a slowly updated one (follows gradual changes: dust, lighting, blur), updated
only on confident matches. The NCC peak is searched inside the Kalman gate only, refined to
sub-pixel by a parabola, then the centre is refined by the colour-weighted centroid of the disc:
the clipped score is the pixel's marker coverage, so the centroid of coverage is the disc centre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .colour import ColourModel


@dataclass
class Match:
    x: float  # refined centre (px)
    y: float
    score: float  # NCC peak, -1..1
    psr: float  # peak-to-sidelobe ratio (NaN if the search area was too small to tell)
    colour_frac: float  # marker coverage found around the centre / seed disc area
    d2: float = float("nan")  # Mahalanobis distance² from the prediction (set by the caller)
    used_centroid: bool = True
    luma: tuple | None = None  # centre of the marker's brightness edge (luma.py), when measured
    rest: bool = False  # the last full measurement moved by the brightness shift since (rest.py)


class TemplateMatcher:
    skip_updated_above = 0.92  # NCC of the seed template above which the updated one is not needed

    def __init__(self, model: ColourModel, frame_bgr: np.ndarray, cx: float, cy: float, half: int | None = None):
        self.model = model
        self.half = int(half if half is not None else np.ceil(model.radius + 3))
        self.seed_template = self._cut(frame_bgr, cx, cy)
        self.template = self.seed_template.copy()

    @property
    def size(self) -> int:
        return 2 * self.half + 1

    def _cut(self, frame_bgr: np.ndarray, cx: float, cy: float) -> np.ndarray:
        r = self.half + 2
        x0, y0 = int(np.floor(cx)) - r, int(np.floor(cy)) - r
        roi = _crop(frame_bgr, x0, y0, 2 * r + 2, 2 * r + 2)
        score = self.model.score(roi)
        return cv2.getRectSubPix(score, (self.size, self.size), (cx - x0, cy - y0))

    def update_template(self, frame_bgr: np.ndarray, cx: float, cy: float, alpha: float = 0.1) -> None:
        last = getattr(self, "_last", None)
        patch = None
        if last is not None:  # reuse the score image of the last match when it holds the patch
            score, x0, y0 = last
            lx, ly = cx - x0, cy - y0
            lim = self.half + 1
            if lim <= lx < score.shape[1] - lim - 1 and lim <= ly < score.shape[0] - lim - 1:
                patch = cv2.getRectSubPix(score, (self.size, self.size), (lx, ly))
        if patch is None:
            patch = self._cut(frame_bgr, cx, cy)
        self.template = ((1 - alpha) * self.template + alpha * patch).astype(np.float32)

    def match(self, frame_bgr: np.ndarray, px: float, py: float, hx: float, hy: float,
              S_inv: np.ndarray | None = None, gate_d2: float = 9.21) -> Match | None:
        """Best match whose centre lies within (hx, hy) of the prediction (px, py) and, given the
        inverse innovation covariance S_inv, inside the gate ellipse. None if nothing to match."""
        H, W = frame_bgr.shape[:2]
        if not (math.isfinite(px) and math.isfinite(py)):
            return None
        r_min = self.model.radius + 4  # room for sidelobes, so the PSR means something
        ex, ey = math.ceil(max(hx, r_min)), math.ceil(max(hy, r_min))
        cx0, cy0 = int(round(px)), int(round(py))
        x0, y0 = max(cx0 - ex - self.half, 0), max(cy0 - ey - self.half, 0)
        x1, y1 = min(cx0 + ex + self.half + 1, W), min(cy0 + ey + self.half + 1, H)
        if x1 - x0 < self.size + 2 or y1 - y0 < self.size + 2:
            return None
        score = self.model.score(frame_bgr[y0:y1, x0:x1])
        res = cv2.matchTemplate(score, self.seed_template, cv2.TM_CCOEFF_NORMED)
        cv2.patchNaNs(res, -1.0)
        if float(res.max()) < self.skip_updated_above:
            # The seed template alone is not convincing: let the updated one (dust, blur) compete.
            res2 = cv2.matchTemplate(score, self.template, cv2.TM_CCOEFF_NORMED)
            cv2.patchNaNs(res2, -1.0)
            res = np.maximum(res, res2)
        # The search box (hx, hy around the prediction) in result-grid indices.
        ox, oy = x0 + self.half - px, y0 + self.half - py  # grid index 0 -> offset from prediction
        c_lo, c_hi = max(math.ceil(-hx - 0.5 - ox), 0), min(math.floor(hx + 0.5 - ox), res.shape[1] - 1)
        r_lo, r_hi = max(math.ceil(-hy - 0.5 - oy), 0), min(math.floor(hy + 0.5 - oy), res.shape[0] - 1)
        if c_hi < c_lo or r_hi < r_lo:
            return None
        box = res[r_lo:r_hi + 1, c_lo:c_hi + 1]
        r, c = divmod(int(np.argmax(box)), box.shape[1])
        r, c = r + r_lo, c + c_lo
        if S_inv is not None and _d2(S_inv, c + ox, r + oy) > gate_d2 + 1.0:
            # The best peak in the box lies outside the gate ellipse: search inside the ellipse only
            # (+1: the grid is integer, the refined centre is not).
            gx = np.arange(c_lo, c_hi + 1, dtype=np.float64) + ox
            gy = np.arange(r_lo, r_hi + 1, dtype=np.float64) + oy
            d2 = (S_inv[0, 0] * gx * gx)[None, :] + (2 * S_inv[0, 1]) * np.outer(gy, gx) \
                + (S_inv[1, 1] * gy * gy)[:, None]
            inside = d2 <= gate_d2 + 1.0
            if not inside.any():
                return None
            r, c = divmod(int(np.argmax(np.where(inside, box, -2.0))), box.shape[1])
            r, c = r + r_lo, c + c_lo
        peak = float(res[r, c])
        sx = _parabola(res[r, c - 1], peak, res[r, c + 1]) if 0 < c < res.shape[1] - 1 else 0.0
        sy = _parabola(res[r - 1, c], peak, res[r + 1, c]) if 0 < r < res.shape[0] - 1 else 0.0
        psr = _psr(res, r, c, math.ceil(self.model.radius) + 1)
        # Peak centre in ROI (score image) coordinates.
        ncc_x, ncc_y = c + self.half + sx, r + self.half + sy
        cxr, cyr, frac = self.centroid(score, ncc_x, ncc_y)
        used = frac >= 0.75 and math.hypot(cxr - ncc_x, cyr - ncc_y) <= 0.5 * self.model.radius
        if used:
            mx, my = cxr, cyr
        else:
            mx, my = ncc_x, ncc_y
        self._last = (score, x0, y0)
        return Match(x=mx + x0, y=my + y0, score=peak, psr=psr, colour_frac=frac, used_centroid=bool(used))

    def centroid(self, score: np.ndarray, x: float, y: float, iterations: int = 2) -> tuple[float, float, float]:
        """Colour-weighted centroid near (x, y) in `score`'s coordinates; returns (x, y, coverage).

        The window is a disc of radius r + 1.5 around the rounded estimate: the whole marker plus
        a rim of sand, whose weights are ~0, so rounding the window's centre costs no accuracy."""
        R, disc = self._centroid_window()
        frac = 0.0
        for _ in range(iterations):
            ix, iy = int(round(x)), int(round(y))
            if ix - R < 0 or iy - R < 0 or ix + R + 1 > score.shape[1] or iy + R + 1 > score.shape[0]:
                return self._centroid_clipped(score, x, y)
            wts = self.model.weights(score[iy - R:iy + R + 1, ix - R:ix + R + 1]) * disc
            mom = cv2.moments(wts)
            tot = mom["m00"]
            frac = tot / self.model.disc_area
            if tot < 1e-6:
                return x, y, 0.0
            x, y = ix - R + mom["m10"] / tot, iy - R + mom["m01"] / tot
            if int(round(x)) == ix and int(round(y)) == iy:
                break  # the window would not move
        return x, y, frac

    def _centroid_window(self):
        w = getattr(self, "_cw", None)
        if w is None:
            rad = self.model.radius + 1.5
            R = int(np.ceil(rad))
            yy, xx = np.mgrid[-R:R + 1, -R:R + 1]
            w = (R, ((xx * xx + yy * yy) <= rad * rad).astype(np.float32))
            self._cw = w
        return w

    def _centroid_clipped(self, score: np.ndarray, x: float, y: float) -> tuple[float, float, float]:
        """Near the image border: the same centroid on the part of the window inside the image."""
        rad = self.model.radius + 1.5
        R = int(np.ceil(rad))
        ix, iy = int(round(x)), int(round(y))
        xa, ya = max(ix - R, 0), max(iy - R, 0)
        xb, yb = min(ix + R + 1, score.shape[1]), min(iy + R + 1, score.shape[0])
        if xb <= xa or yb <= ya:
            return x, y, 0.0
        yy, xx = np.mgrid[ya:yb, xa:xb]
        wts = self.model.weights(score[ya:yb, xa:xb]) * (((xx - ix) ** 2 + (yy - iy) ** 2) <= rad * rad)
        tot = float(wts.sum())
        if tot < 1e-6:
            return x, y, 0.0
        return float((wts * xx).sum() / tot), float((wts * yy).sum() / tot), tot / self.model.disc_area

    def refine_at(self, frame_bgr: np.ndarray, x: float, y: float) -> tuple[float, float, float]:
        """Colour centroid around a given point of the frame (seeding, re-acquisition)."""
        R = int(np.ceil(self.model.radius + 4))
        x0, y0 = int(round(x)) - R, int(round(y)) - R
        roi = _crop(frame_bgr, x0, y0, 2 * R + 1, 2 * R + 1)
        cx, cy, frac = self.centroid(self.model.score(roi), x - x0, y - y0, iterations=3)
        return cx + x0, cy + y0, frac


def _crop(img: np.ndarray, x0: int, y0: int, w: int, h: int) -> np.ndarray:
    """Crop with edge replication where the window leaves the image."""
    H, W = img.shape[:2]
    if x0 >= 0 and y0 >= 0 and x0 + w <= W and y0 + h <= H:
        return img[y0:y0 + h, x0:x0 + w]
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + w, W), min(y0 + h, H)
    if xb <= xa or yb <= ya:
        return np.zeros((h, w) + img.shape[2:], dtype=img.dtype)
    sub = img[ya:yb, xa:xb]
    return cv2.copyMakeBorder(sub, ya - y0, y0 + h - yb, xa - x0, x0 + w - xb, cv2.BORDER_REPLICATE)


def _d2(S_inv: np.ndarray, dx: float, dy: float) -> float:
    return float(S_inv[0, 0] * dx * dx + 2 * S_inv[0, 1] * dx * dy + S_inv[1, 1] * dy * dy)


def _parabola(a: float, b: float, c: float) -> float:
    a, b, c = float(a), float(b), float(c)
    den = a - 2 * b + c
    if den >= 0:
        return 0.0
    return min(max(0.5 * (a - c) / den, -0.5), 0.5)


def _psr(res: np.ndarray, r: int, c: int, excl: int) -> float:
    """(peak - mean) / std of the correlation outside a window around the peak."""
    win = res[max(r - excl, 0):r + excl + 1, max(c - excl, 0):c + excl + 1]
    n = res.size - win.size
    if n < 16:
        return float("nan")
    s1, s2 = _sums(res)
    w1, w2 = _sums(win)
    mean = (s1 - w1) / n
    sd = max((s2 - w2) / n - mean * mean, 0.0) ** 0.5
    return float((res[r, c] - mean) / max(sd, 1e-3))


def _sums(a: np.ndarray) -> tuple[float, float]:
    """Sum and sum of squares, in float64 (cv2.sumElems/cv2.norm accumulate in double)."""
    return cv2.sumElems(a)[0], cv2.norm(a, cv2.NORM_L2SQR)
