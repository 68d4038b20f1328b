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

from . import kernels
from .appearance import BRIGHT, DARK, AppearanceModel
from .luma import edge_circle
from .streak import STREAK_EXPOSURES, STREAK_MIN_SPEED


@dataclass(slots=True)
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
    touching: bool = False  # other markers touch this one: its centre is from its own share of the blob
    outline: bool = True  # False: a crowd marker whose own outline was not found (its NCC peak only)
    lit: bool = False  # a crowd marker centred by its highlight (its outline not found, or pulled off)
    assigned: bool = False  # a crowd marker measured where an assignment put it, its template not asked
    look: bool = False  # placed by its look at its last full measurement (MarkerTrack.look_match), not measured
    line: bool = False  # measured on the other view's epipolar line, its outline found all round (LineSearch.on_line)


@dataclass
class Proposal:
    """The match a track proposes for this step (Engine collects them before any commits)."""

    match: Match
    reattach: bool = False
    jump: bool = False  # re-attached beyond the gate: the marker's velocity starts from that move


class TemplateMatcher:
    skip_updated_above = 0.92  # NCC of the seed template above which the updated one is not needed
    confident_score = 0.85  # a peak this good is a confident match (the track sets TrackParams.confident_score)

    def __init__(self, model: AppearanceModel, frame_bgr: np.ndarray, cx: float, cy: float, half: int | None = None):
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
        score = self.model.prepared(self.model.score(roi))
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
              s_inv: tuple | None = None, gate_d2: float = 9.21, velocity: tuple | None = None) -> Match | None:
        """Best match whose centre lies within (hx, hy) of the prediction (px, py) and, given the
        inverse innovation covariance s_inv = (i00, i01, i11), inside the gate ellipse. None if
        nothing to match. `velocity` (px per frame): a fast marker is also matched as the streak the
        exposure smears it into (see _streaks)."""
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
        # The search box (hx, hy around the prediction) in result-grid indices.
        ox, oy = x0 + self.half - px, y0 + self.half - py  # grid index 0 -> offset from prediction
        c_lo, c_hi = max(math.ceil(-hx - 0.5 - ox), 0), min(math.floor(hx + 0.5 - ox), x1 - x0 - self.size)
        r_lo, r_hi = max(math.ceil(-hy - 0.5 - oy), 0), min(math.floor(hy + 0.5 - oy), y1 - y0 - self.size)
        if c_hi < c_lo or r_hi < r_lo:
            return None
        # The peak inside the gate ellipse (+1: the grid is integer, the refined centre is not).
        gate = (0.0, 0.0, 0.0, -1.0) if s_inv is None else (*map(float, s_inv), float(gate_d2) + 1.0)
        box = (c_lo, c_hi, r_lo, r_hi, float(ox), float(oy), *gate)
        score = self.model.prepared(self.model.score_window(frame_bgr, x0, y0, x1, y1))
        res = cv2.matchTemplate(score, self.seed_template, cv2.TM_CCOEFF_NORMED)
        cv2.patchNaNs(res, -1.0)
        top = float(res.max())
        peak_found = None
        if top < self.skip_updated_above and self.model.has_blob:
            # The seed template alone is not convincing: let the updated one (dust, blur) compete. (Not
            # for a pattern: with no blob to centre on, an updated template would carry its drift on.)
            # Unless the seed template's peak inside the gate already makes the match confident: then
            # the updated one can change neither which marker is matched, nor whether, nor how surely,
            # only where its peak falls on that marker, which the centroid measures anyway. (Not for a
            # marker fast enough to be smeared: its streaks compete with both templates, see _streaks.)
            if velocity is None or math.hypot(*velocity) < STREAK_MIN_SPEED:
                peak_found = self._peak(res, score, box, 0.0)
                if not (peak_found[0] and peak_found[3] >= self.confident_score):
                    peak_found = None
            if peak_found is None:
                res2 = cv2.matchTemplate(score, self.template, cv2.TM_CCOEFF_NORMED)
                cv2.patchNaNs(res2, -1.0)
                res = np.maximum(res, res2)
                top = max(top, float(res2.max()))
        streak = 0.0
        if peak_found is None:
            if velocity is not None and top < self.skip_updated_above:
                res, streak = self._streaks(score, res, velocity, top)
            peak_found = self._peak(res, score, box, streak)
        found, mx, my, peak, psr, frac, used, touching = peak_found
        if not found:
            return None
        self._last = (score, x0, y0)
        if used and not touching and not streak:
            smooth = self.model.interpolated_score_window(frame_bgr, x0, y0, x1, y1)
            if smooth is not None:  # (a grey marker: centred on its chroma interpolated, see the model)
                mx, my, _ = self.centroid(smooth, mx, my)
        x, y = mx + x0, my + y0
        if self.model.crowd:
            e = self.silhouette(frame_bgr, x, y, strict=True)
            if e is None and math.hypot(px - x, py - y) <= self.model.radius:
                # (the coverage centroid is pulled by the touching neighbours: the outline may be found
                # from the prediction instead)
                e = self.silhouette(frame_bgr, px, py, strict=True)
            if e is None:  # (among touching lookalikes only a marker whose own outline is found is measured)
                return Match(x=x, y=y, score=peak, psr=psr, colour_frac=frac, used_centroid=False, touching=True,
                             outline=False)
            x, y = e
        elif used and not touching and not streak:
            x, y = self.silhouette(frame_bgr, x, y)
        return Match(x=x, y=y, score=peak, psr=psr, colour_frac=frac, used_centroid=used, touching=touching)

    def _peak(self, res: np.ndarray, score: np.ndarray, box: tuple, streak: float) -> tuple:
        """kernels.match_peak of the NCC surface `res` on the score window, inside the gate `box`, for a
        marker smeared over `streak` px: (found, x, y, peak, psr, coverage, centroid used, touching)."""
        r = self.model.radius
        return kernels.match_peak(res, score, *box[:6], *box[6:], self.half, math.ceil(r + 0.5 * streak) + 1,
                                  r + 1.5 + 0.5 * streak, self.model.weight_floor * self._dilution(streak),
                                  self.model.disc_area, r + 0.5 * streak)

    def silhouette(self, frame_bgr, x: float, y: float, strict: bool = False) -> tuple[float, float] | None:
        """A brightness model's marker centred on its outline (luma.edge_centre), not on its pixels'
        weights: a bright marker's lit side is brighter than its shaded side, and a dark marker's
        contact shadow is dark too; either pulls a weighted centroid by a few tenths of a pixel,
        while where the outline lies depends on neither. A dark marker's outline can only be pushed
        outward (by its shadow), so only edge points outside the circle are suspects. Among touching
        lookalikes (a crowd model) the circle keeps the marker's radius: the beads are of one size, and
        a free radius would be drawn off by the outlines of the neighbours pressed against it. Colour
        and texture models, or no clear outline within a pixel: (x, y) as it is (`strict`: None when
        no outline of the marker's radius is found all around it)."""
        if self.model.kind not in (BRIGHT, DARK):
            return None if strict else (x, y)
        dark = self.model.kind == DARK
        # (among touching markers the estimate may start a little off: the neighbours pull centroids)
        reach = 0.5 * self.model.radius if self.model.crowd else 1.0
        e = edge_circle(frame_bgr, x, y, self.model.radius, iterations=5 if self.model.crowd else 3,
                        polarity=1.0 if dark else -1.0, outward=dark, known_radius=self.model.crowd)
        if e is None or (e[0] - x) ** 2 + (e[1] - y) ** 2 > reach**2 or \
                (strict and (abs(e[2] - self.model.radius) > 0.3 * self.model.radius or e[3] < 4)):
            return None if strict else (x, y)
        return e[0], e[1]

    def middle_score(self, frame_bgr, x: float, y: float) -> float:
        """The score of the marker's middle (the median within half its radius of (x, y)), relative to its
        window's sand (the median beyond 1.8 radii) and to the light on it (as prepared() scales it);
        NaN near the image's edge."""
        r = self.model.radius
        R = int(np.ceil(2.5 * r + 2))
        H, W = frame_bgr.shape[:2]
        x0, y0 = int(round(x)) - R, int(round(y)) - R
        if x0 < 0 or y0 < 0 or x0 + 2 * R + 1 > W or y0 + 2 * R + 1 > H:
            return float("nan")
        masks = self.__dict__.get("_middle_masks")
        if masks is None or masks[0] != R:
            yy, xx = np.mgrid[-R:R + 1, -R:R + 1]
            d = np.hypot(xx, yy)
            masks = self._middle_masks = (R, d <= 0.5 * r, d >= 1.8 * r)
        score = self.model.score_window(frame_bgr, x0, y0, x0 + 2 * R + 1, y0 + 2 * R + 1)
        sand = kernels.median(score[masks[2]])
        mid = kernels.median(score[masks[1]])
        level_d, level_s = self.model.levels
        k = 1.0 + sand * (level_d - level_s) / level_s  # (the light on the sand, as in prepared())
        return (mid - sand) / k if k > 0.25 else float("nan")

    def _streaks(self, score: np.ndarray, res: np.ndarray, velocity: tuple, top: float) -> tuple[np.ndarray, float]:
        """A marker moving v px per frame is smeared over e |v| px by an exposure of e frames. For a
        fast marker (|v| >= STREAK_MIN_SPEED) the seed template smeared along v over half and a whole
        frame's move competes too (`top`: the maximum of `res`); returns the best NCC surface and the
        winning smear length (px; 0: the round marker won). The centroid then covers the streak: its
        coverage centre is the marker at mid-exposure."""
        vx, vy = velocity
        speed = math.hypot(vx, vy)
        if speed < STREAK_MIN_SPEED:
            return res, 0.0
        best, best_len = res, 0.0
        for e in STREAK_EXPOSURES:
            length = e * speed
            res_e = cv2.matchTemplate(score, self._smeared(vx / speed, vy / speed, length), cv2.TM_CCOEFF_NORMED)
            cv2.patchNaNs(res_e, -1.0)
            top_e = float(res_e.max())
            if top_e > top:
                best, best_len, top = res_e, length, top_e
        return best, best_len

    def _dilution(self, streak: float) -> float:
        """A streak spreads a marker's coverage over (d + L) / d of its length: its pixels score that
        much less, and the weight floor is lowered as much (or the streak's coverage would be lost)."""
        d = 2 * self.model.radius
        return d / (d + streak)

    def _smeared(self, ux: float, uy: float, length: float) -> np.ndarray:
        key = (round(math.degrees(math.atan2(uy, ux)) / 10) % 36, round(length))
        cache = self.__dict__.setdefault("_smear_cache", {})
        t = cache.get(key)
        if t is None:
            ang, n = math.radians(key[0] * 10), max(int(key[1]), 1)
            size = 2 * (n // 2) + 3
            kern = np.zeros((size, size), np.float32)
            c = size // 2
            for i in range(4 * n + 1):  # a line of n px through the centre, finely sampled
                d = (i / (4 * n) - 0.5) * n
                cv2.circle(kern, (int(round(c + d * math.cos(ang))), int(round(c + d * math.sin(ang)))), 0, 1.0, -1)
            t = cv2.filter2D(self.seed_template, -1, kern / kern.sum(), borderType=cv2.BORDER_CONSTANT)
            if len(cache) > 64:
                cache.clear()
            cache[key] = t
        return t

    def centroid(self, score: np.ndarray, x: float, y: float, iterations: int = 2) -> tuple[float, float, float]:
        """Colour-weighted centroid near (x, y) in `score`'s coordinates; returns (x, y, coverage).

        The window is a disc of radius r + 1.5 around the rounded estimate: the whole marker plus
        a rim of sand, whose weights are ~0, so rounding the window's centre costs no accuracy."""
        m = self.model
        return kernels.centroid(score, float(x), float(y), iterations, m.radius + 1.5, m.weight_floor, m.disc_area)

    def refine_at(self, frame_bgr: np.ndarray, x: float, y: float) -> tuple[float, float, float]:
        """Colour centroid around a given point of the frame (seeding, re-acquisition)."""
        R = int(np.ceil(self.model.radius + 4))
        x0, y0 = int(round(x)) - R, int(round(y)) - R
        roi = _crop(frame_bgr, x0, y0, 2 * R + 1, 2 * R + 1)
        cx, cy, frac = self.centroid(self.model.prepared(self.model.score(roi)), x - x0, y - y0, iterations=3)
        if self.model.crowd:  # (among touching markers the centroid is pulled by the neighbours)
            cx, cy = x - x0, y - y0
        cx, cy = self.silhouette(frame_bgr, cx + x0, cy + y0) or (cx + x0, cy + y0)
        return cx, cy, frac


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
