"""Marker motion from brightness (luma), to carry the colour centre across inter-coded frames.

H.264/H.265 video codes colour (chroma) at half resolution and, in predicted frames, mostly as a
copy of the reference frame: for a marker creeping along (0.01-1 px/frame, pushed by the sand
heap) the chroma residual is quantised away and the marker's colour trails its true position by
up to ~0.4 px, building up from each intra-coded frame to the next (measured on the rendered rig:
0.12 px at intra frames, 0.45 px 20-49 frames later). Brightness is coded at full resolution and
far more finely, and does not trail. Its edge, though, is biased by shading and by the contact
shadow (0.1-0.5 px, mostly towards the shadow), but that bias changes slowly. So the tracker
measures the marker's luma centre too; at intra-coded frames it records the offset between the
colour centre and the luma centre; in the frames between, luma centre + offset tells how far the
stale colour held the centre back, and the colour centre is moved forward by that much, along the
motion since the intra frame and by at most its length (a lag can do nothing else: this keeps a
shadow sliding over the sand, which shifts the luma edge sideways, from moving the marker).

The luma centre is a circle fitted to the marker's silhouette edge: along rays from the estimate,
the strongest rise of brightness from the (darker) marker to the sand, located to sub-pixel, then
an algebraic circle fit with robust weights (rays through a shadow or a neighbour count less).
A marker with no dark silhouette (a white one on beige sand: its lit side brighter than the sand,
its shaded side as bright) has no such edge; its shading pattern, though, moves with it (the light
does not turn with the marker): `LumaPattern` registers the brightness of its disc at the intra
frame in the frames after it.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from . import kernels
from .chroma import LUMA_BGR
from .streak import STREAK_EXPOSURES, STREAK_MIN_SPEED

N_RAYS = 32
_ANG = np.linspace(0, 2 * np.pi, N_RAYS, endpoint=False)
_COS, _SIN = np.cos(_ANG).astype(np.float32), np.sin(_ANG).astype(np.float32)
STEP = 0.25
MIN_RISE = 2.0  # luma levels per half pixel: a real edge, not noise on flat sand


def edge_centre(frame_bgr, x: float, y: float, radius: float, iterations: int = 3, settle_px: float = 0.35,
                polarity: float = 1.0, outward: bool = False):
    """Centre (x, y) of the marker's dark silhouette (polarity 1; a bright marker's: -1, the steepest
    fall of brightness outward) near (x, y) in frame coordinates, or None (edge_circle without the radius)."""
    c = edge_circle(frame_bgr, x, y, radius, iterations, settle_px, polarity, outward)
    return None if c is None else c[:2]


def edge_circle(frame_bgr, x: float, y: float, radius: float, iterations: int = 3, settle_px: float = 0.35,
                polarity: float = 1.0, outward: bool = False, known_radius: bool = False):
    """(x, y, r, quadrants): the circle of the marker's silhouette near (x, y), of about `radius`, in
    frame coordinates, and how many of the four quadrants around it hold its outline; or None.
    Along N_RAYS rays, cubic brightness profiles at `STEP` px from 0.4 to 1.7 radii; each ray's
    steepest outward rise (parabola vertex, at least MIN_RISE) is an edge point; a robust circle
    through them moves the estimate; up to `iterations` rounds, until it moves < settle_px.
    `known_radius`: the circle keeps `radius` (markers of one size touching each other), only its centre moves."""
    H, W = frame_bgr.shape[:2]
    R = int(np.ceil(1.8 * radius + 3))
    x0, y0 = int(round(x)) - R, int(round(y)) - R
    if x0 < 0 or y0 < 0 or x0 + 2 * R + 1 > W or y0 + 2 * R + 1 > H:
        return None
    args = (float(x - x0), float(y - y0), float(radius), _steps(radius), _COS, _SIN, MIN_RISE, STEP, iterations,
            settle_px, float(polarity), bool(outward), bool(known_radius))
    yuv = getattr(frame_bgr, "yuv", None)  # a frame still in its 4:2:0 planes (yuv.py)
    if yuv is not None:
        ok, cx, cy, r, quadrants = kernels.edge_centre_yuv(*yuv, x0, y0, 2 * R + 1, *args)
    else:
        ok, cx, cy, r, quadrants = kernels.edge_centre(frame_bgr[y0:y0 + 2 * R + 1, x0:x0 + 2 * R + 1], *args)
    return (cx + x0, cy + y0, r, int(quadrants)) if ok else None


def rim_step(frame_bgr, x: float, y: float, radius: float, polarity: float = 1.0, reach: float = 1.5) -> float:
    """The brightness step across the circle of `radius` around (x, y): the median over N_RAYS rays of the
    luma `reach` px outside it minus `reach` px inside (times `polarity`: 1 for a dark marker, whose rim
    is darker than the sand around it; -1 for a bright one); NaN near the image's edge. A marker's outline
    steps by a good part of its contrast all round; sand's texture inside and outside a circle differs
    by a few levels."""
    R = int(np.ceil(radius + reach)) + 2
    x0, y0 = int(round(x)) - R, int(round(y)) - R
    H, W = frame_bgr.shape[:2]
    if x0 < 0 or y0 < 0 or x0 + 2 * R + 1 > W or y0 + 2 * R + 1 > H:
        return float("nan")
    win = np.asarray(frame_bgr[y0:y0 + 2 * R + 1, x0:x0 + 2 * R + 1], dtype=np.float32)
    luma = np.ascontiguousarray(win @ LUMA_BGR if win.ndim == 3 else win)
    cx, cy = np.float32(x - x0), np.float32(y - y0)
    out = cv2.remap(luma, cx + (radius + reach) * _COS[None], cy + (radius + reach) * _SIN[None], cv2.INTER_LINEAR)
    inn = cv2.remap(luma, cx + (radius - reach) * _COS[None], cy + (radius - reach) * _SIN[None], cv2.INTER_LINEAR)
    return float(polarity * np.median(out - inn))


class LumaPattern:
    """The brightness of a marker's disc around (x, y) in one frame, found again in later frames: the
    translation that best fits the pattern (weights: the disc of `radius`, so the sand, which stays
    where it is, hardly counts; brightness offsets are not motion), by Gauss-Newton. A marker moving
    fast is smeared by the exposure along its motion: then the pattern smeared the same way is fitted
    too (see find). `ok` is False near the image's edge or when the disc holds no structure to register."""

    ITERATIONS = 6
    MIN_NCC = 0.9  # a registered disc must look like the pattern this much, or nothing is reported
    SETTLED_PX = 0.01

    def __init__(self, frame, x: float, y: float, radius: float, smears: bool = True):
        self.x, self.y = float(x), float(y)
        self.half = h = int(math.ceil(radius)) + 2
        self.ok = False
        self._room = h if smears else 0  # (room to smear the pattern by up to 2 half; none: still only)
        wide = self._sample(frame, x, y, h + self._room)
        if wide is None:
            return
        self._wide = wide
        yy, xx = np.mgrid[-h:h + 1, -h:h + 1]
        self.w = np.clip(radius + 0.5 - np.hypot(xx, yy), 0.0, 1.0).astype(np.float32)
        self._still = self._prepare(self._smeared(0.0, 0.0, 0.0))
        if self._still is None:
            return
        self._smears: dict = {}
        self.fit = float("nan")  # normalised correlation of the last find with the pattern
        self.place: tuple | None = None  # where the last find registered it, however well it fitted
        self.ok = True

    @staticmethod
    def window(frame, x: float, y: float, radius: float) -> tuple | None:
        """(window, x0, y0): the part of `frame` (its top-left corner at x0, y0) that the still pattern
        of the marker at (x, y) is cut from (see from_window), a copy; None near the image's edge."""
        h = int(math.ceil(radius)) + 2
        x0, y0 = int(math.floor(x)) - h - 2, int(math.floor(y)) - h - 2
        size = 2 * h + 5
        H, W = frame.shape[:2]
        if x0 < 0 or y0 < 0 or x0 + size > W or y0 + size > H:
            return None
        return np.array(frame[y0:y0 + size, x0:x0 + size]), x0, y0

    @classmethod
    def from_window(cls, cut: tuple, x: float, y: float, radius: float) -> LumaPattern:
        """The still pattern of the marker at (x, y) (frame coordinates) from the window kept by `window`
        (no smeared one: find() fits it as it is)."""
        win, x0, y0 = cut
        pattern = cls(win, x - x0, y - y0, radius, smears=False)
        pattern.x, pattern.y = float(x), float(y)
        return pattern

    def _mean(self, a: np.ndarray) -> float:
        return float((self.w * a).sum() / self.w.sum())

    def _smeared(self, ux: float, uy: float, length: float) -> np.ndarray:
        """The pattern's window averaged over a move of `length` px along (ux, uy), centred."""
        size = 2 * self.half + 1
        c = self.half + self._room
        n = max(int(math.ceil(length)) + 1, 1)
        out = np.zeros((size, size), np.float32)
        for s in np.linspace(-0.5 * length, 0.5 * length, n):
            out += cv2.getRectSubPix(self._wide, (size, size), (c + s * ux, c + s * uy))
        return out / n

    def _prepare(self, t: np.ndarray) -> tuple | None:
        """(template, gradients, inverse Hessian, energy) of a pattern window; None without structure."""
        w = self.w
        t = t - self._mean(t)
        gx = cv2.Sobel(t, cv2.CV_32F, 1, 0, ksize=3) / 8
        gy = cv2.Sobel(t, cv2.CV_32F, 0, 1, ksize=3) / 8
        gx, gy = gx - self._mean(gx), gy - self._mean(gy)
        hess = np.array([[(w * gx * gx).sum(), (w * gx * gy).sum()],
                         [(w * gx * gy).sum(), (w * gy * gy).sum()]], np.float64)
        if np.linalg.det(hess) <= 1e-6 * max(np.trace(hess), 1e-12) ** 2:
            return None
        return t, gx, gy, np.linalg.inv(hess), float((w * t * t).sum())

    def _sample(self, frame, x: float, y: float, half: int | None = None) -> np.ndarray | None:
        """The (2 half + 1)² luma window centred at (x, y), sub-pixel, float32; None near the edge."""
        h = self.half if half is None else half
        size = 2 * h + 1
        x0, y0 = int(math.floor(x)) - h - 2, int(math.floor(y)) - h - 2
        H, W = frame.shape[:2]
        if x0 < 0 or y0 < 0 or x0 + size + 4 > W or y0 + size + 4 > H:
            return None
        win = np.asarray(frame[y0:y0 + size + 4, x0:x0 + size + 4], dtype=np.float32)
        luma = win @ LUMA_BGR if win.ndim == 3 else win
        return cv2.getRectSubPix(np.ascontiguousarray(luma), (size, size), (x - x0, y - y0))

    def find(self, frame, x: float, y: float, velocity: tuple | None = None) -> tuple[float, float] | None:
        """Where the pattern lies in `frame`, searched from (x, y); None when it does not fit. With the
        marker's `velocity` (px per frame) at STREAK_MIN_SPEED or more, the pattern smeared along it
        over the exposures of STREAK_EXPOSURES is fitted too, and the best fit is the pattern's
        (a smear along the motion, even about the mid-exposure, lowers the fit, not the place where the
        still pattern registers; the smeared pattern's sand, smeared too, would pull its own place)."""
        if not self.ok:
            return None
        best = self._register(frame, x, y, self._still)
        if velocity is not None and self._room:
            speed = math.hypot(*velocity)
            if speed >= STREAK_MIN_SPEED:
                ux, uy = velocity[0] / speed, velocity[1] / speed
                for e in STREAK_EXPOSURES:
                    length = min(e * speed, 2.0 * self._room)
                    key = (round(ux, 1), round(uy, 1), round(length))
                    prep = self._smears.get(key)
                    if prep is None:
                        prep = self._smears[key] = self._prepare(self._smeared(ux, uy, length))
                    if prep is not None:
                        got = self._register(frame, x, y, prep)
                        if got is not None and (best is None or got[2] > best[2]):
                            best = got if best is None else (best[0], best[1], got[2])
        if best is None:
            self.place = None
            return None
        self.fit, self.place = best[2], (best[0], best[1])
        return (best[0], best[1]) if self.fit >= self.MIN_NCC else None

    def _register(self, frame, x: float, y: float, prep: tuple) -> tuple | None:
        """(x, y, normalised correlation) of the Gauss-Newton fit of one pattern from (x, y); None near
        the image's edge."""
        t, gx, gy, hess_inv, tt = prep
        dx, dy = x - self.x, y - self.y
        s = None
        for _ in range(self.ITERATIONS):
            s = self._sample(frame, self.x + dx, self.y + dy)
            if s is None:
                return None
            s -= self._mean(s)
            e = self.w * (s - t)
            step = hess_inv @ np.array([(e * gx).sum(), (e * gy).sum()])
            dx, dy = dx - float(step[0]), dy - float(step[1])
            if abs(step[0]) + abs(step[1]) < self.SETTLED_PX:
                break
        fit = float((self.w * s * t).sum()) / math.sqrt(float((self.w * s * s).sum()) * tt + 1e-12)
        return self.x + dx, self.y + dy, fit


_STEPS: dict = {}


def _steps(radius: float) -> np.ndarray:
    key = round(radius, 1)
    s = _STEPS.get(key)
    if s is None:
        s = np.arange(0.4 * key, 1.7 * key, STEP, dtype=np.float32)
        if len(s) < 6:
            s = np.arange(6, dtype=np.float32) * STEP + 0.4 * key
        _STEPS[key] = s
    return s


def intra_frames(source) -> np.ndarray | None:
    """Boolean mask over the source's frames: True where the video frame is intra-coded (a key
    frame). None when the source is not a video file (image folders, in-memory clips)."""
    path = getattr(source, "path", None)
    times = getattr(source, "times_s", None)
    if path is None or times is None or getattr(source, "is_folder", True):
        return None
    known = getattr(source, "keyframes", None)  # FrameSource lists them when it opens the file
    if known is not None and len(known) == len(times):
        return np.asarray(known, dtype=bool)
    import av

    try:
        with av.open(str(path)) as c:
            st = c.streams.video[0]
            tb = float(st.time_base)
            key_t = [p.pts * tb for p in c.demux(st) if p.pts is not None and p.is_keyframe]
    except (av.error.FFmpegError, OSError, ValueError, IndexError):
        return None
    times = np.asarray(times, dtype=np.float64)
    mask = np.zeros(len(times), dtype=bool)
    if key_t and len(times):
        idx = np.clip(np.searchsorted(times, np.array(key_t) - 1e-6), 0, len(times) - 1)
        near = np.abs(times[idx] - np.array(key_t)) < 0.25 / max(float(getattr(source, "fps", 50.0)), 1.0)
        mask[idx[near]] = True
    return mask
