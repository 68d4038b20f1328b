"""Colour model of one marker, learned from its seed box: marker disc against the sand around it.

A Fisher discriminant on chromaticity (B, G, R divided by their sum) separates the disc's pixels
from the sand ring's and is scaled so sand scores 0 and the disc 1. Chromaticity ignores
brightness, so a marker's own shaded side still scores 1 and the contact shadow it casts on the
sand still scores 0: in BGR both leaked into the score and pulled the centroid ~0.6 px towards the
shadow. A pixel that is a mix of marker and sand (an anti-aliased edge, a marker dusted with sand)
scores roughly its marker fraction, so the clipped score doubles as a coverage weight for the
centroid. Fixed HSV thresholds fail on dusty markers; a model learned per marker does not.
Also here: a generic "blueness" measure for finding markers with no model yet (seeding, snapping).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import SandtrackError
from . import kernels

EPS = 3.0  # added to B + G + R: keeps the chromaticity of near-black pixels finite


def chromaticity(bgr: np.ndarray) -> np.ndarray:
    f = np.asarray(bgr, dtype=np.float64)
    return f / (f.sum(axis=-1, keepdims=True) + EPS)


@dataclass
class ColourModel:
    w: np.ndarray  # (3,) weights on BGR chromaticity
    b: float  # offset: score = (bgr @ w) / (sum(bgr) + EPS) + b
    threshold: float  # score at or above which a pixel counts as marker
    disc_area: float  # marker pixels in the seed (px²)
    radius: float  # equivalent disc radius (px)
    sand_spread: float  # std of sand scores around the seed

    def score(self, bgr: np.ndarray) -> np.ndarray:
        """Per-pixel score, float32: ~0 on sand, ~1 on the marker."""
        if not bgr.size:
            return np.zeros(bgr.shape[:2], dtype=np.float32)
        return kernels.colour_score(bgr, *self._score_coeffs)

    def score_window(self, frame, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """score() of the window [y0:y1, x0:x1] of a frame (inside it), also of a frame still in its
        4:2:0 planes (yuv.py), without converting the window separately."""
        yuv = getattr(frame, "yuv", None)
        if yuv is not None and x1 > x0 and y1 > y0:
            return kernels.colour_score_yuv(*yuv, x0, y0, x1, y1, *self._score_coeffs)
        return self.score(frame[y0:y1, x0:x1])

    @cached_property
    def _score_coeffs(self) -> tuple:
        """(w0, w1, w2, b, EPS) as float32, as the kernels take them."""
        return (*np.float32(self.w), np.float32(self.b), np.float32(EPS))

    @property
    def weight_floor(self) -> float:
        """Score from which a pixel counts towards a centroid or a blob's area: its weight is
        (score - floor) / (1 - floor), clipped to 0..1 (≈ its coverage by the marker)."""
        return min(0.5 * self.threshold, 0.15)

    def mask_box(self, frame, x0: int, y0: int, x1: int, y1: int) -> tuple:
        """(mask, found, bx0, by0, bx1, by1): uint8 0/1 per pixel of the window [y0:y1, x0:x1] of a
        frame, score >= threshold, and the box of its ones in window coordinates. For 8-bit pixels
        (B + G + R + EPS > 0) the test is linear, (w + b - t) . bgr + (b - t) EPS >= 0; a frame still
        in its 4:2:0 planes (yuv.py) computes it without converting the window."""
        linear_mask = getattr(frame, "linear_mask", None)
        if linear_mask is not None:
            return linear_mask(self._mask_coeffs, x0, y0, x1, y1)
        bgr = frame[y0:y1, x0:x1]
        if bgr.dtype == np.uint8 and bgr.size:
            return kernels.colour_mask(bgr, *self._mask_coeffs)
        mask = (self.score(bgr) >= self.threshold).astype(np.uint8)
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        if not len(rows):
            return mask, False, 0, 0, 0, 0
        return mask, True, int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1

    @cached_property
    def _mask_coeffs(self) -> tuple:
        c = self.b - self.threshold
        return (*np.float32(self.w + c), np.float32(c * EPS))

    def blob_moments(self, bgr: np.ndarray, labels: np.ndarray, k: int, xa: int, ya: int, xb: int, yb: int):
        """(area, m10, m01, pixels): pixel weights (see weight_floor) summed over component k of
        `labels` grown by one pixel, its first moments from (xa, ya), within rows ya..yb-1 and columns
        xa..xb-1 of `bgr`, and the component's pixel count there."""
        return kernels.blob_moments(bgr, labels, k, xa, ya, xb, yb, *self._score_coeffs, self.weight_floor)


def blueness(bgr: np.ndarray) -> np.ndarray:
    """Generic blue-against-sand measure, float32: B - (G + R) / 2 (sand is strongly negative)."""
    f = bgr.astype(np.float32)
    return f[..., 0] - 0.5 * (f[..., 1] + f[..., 2])


def chroma_blueness(bgr: np.ndarray) -> np.ndarray:
    """Blueness of the chromaticity, float32 in about -0.5..1: independent of shading and shadows."""
    f = bgr.astype(np.float32)
    return (f[..., 0] - 0.5 * (f[..., 1] + f[..., 2])) / (f.sum(axis=-1) + EPS)


def learn(frame_bgr: np.ndarray, cx: float, cy: float, w: float, h: float) -> ColourModel:
    """Learn a ColourModel from a seed box centred at (cx, cy) of size w x h (px)."""
    H, W = frame_bgr.shape[:2]
    if not (np.isfinite(cx) and np.isfinite(cy)) or not (0 <= cx < W and 0 <= cy < H):
        raise SandtrackError(f"seed point ({cx:.1f}, {cy:.1f}) lies outside the {W}x{H} image")
    if not (w >= 3 and h >= 3):
        raise SandtrackError(f"seed box {w}x{h} px is too small (at least 3x3)")
    half_in = 0.5 * max(w, h)
    margin = max(4.0, 0.5 * half_in)
    R = int(np.ceil(half_in + margin))
    x0, x1 = int(round(cx)) - R, int(round(cx)) + R + 1
    y0, y1 = int(round(cy)) - R, int(round(cy)) + R + 1
    patch = frame_bgr[max(y0, 0):min(y1, H), max(x0, 0):min(x1, W)].reshape(-1, 3).astype(np.float64)
    yy, xx = np.mgrid[max(y0, 0):min(y1, H), max(x0, 0):min(x1, W)]
    dx, dy = np.abs(xx.ravel() - cx), np.abs(yy.ravel() - cy)
    inner = (dx <= 0.5 * w) & (dy <= 0.5 * h)
    ring = (np.maximum(dx, dy) >= half_in + 1.5)
    if inner.sum() < 4 or ring.sum() < 12:
        raise SandtrackError("seed box lies too close to the image border to learn the marker's colour")
    patch = chromaticity(patch)
    sand = patch[ring]
    # Neighbouring markers may reach into the ring: drop its clearly blue pixels.
    bl = sand @ np.array([1.0, -0.5, -0.5])
    med = np.median(bl)
    mad = 1.4826 * np.median(np.abs(bl - med)) + 0.005
    sand = sand[bl <= med + 4 * mad]
    # First direction: inner pixels furthest from sand in the blue-vs-sand sense; split the box's
    # pixels into marker and sand by 2-means along it.
    mu_s = np.median(sand, axis=0)
    d0 = patch[inner].mean(axis=0) - mu_s
    blue_dir = np.array([1.0, -0.5, -0.5])
    if np.linalg.norm(d0) < 1e-6 or d0 @ blue_dir <= 0:
        d0 = blue_dir
    p_in = (patch[inner] - mu_s) @ d0
    t = 0.5 * (np.percentile(p_in, 95) + np.median((sand - mu_s) @ d0))
    for _ in range(10):
        hi, lo = p_in[p_in >= t], p_in[p_in < t]
        if len(hi) == 0 or len(lo) == 0:
            break
        t_new = 0.5 * (hi.mean() + 0.5 * (lo.mean() + np.median((sand - mu_s) @ d0)))
        if abs(t_new - t) < 1e-6:
            break
        t = t_new
    disc = patch[inner][p_in >= t]
    if len(disc) < 3:
        raise SandtrackError("no marker found in the seed box (empty box?)")
    # Fisher discriminant between disc and sand.
    mu_d, mu_sand = disc.mean(axis=0), sand.mean(axis=0)
    Sw = np.cov(sand.T) + (np.cov(disc.T) if len(disc) > 3 else 0) + np.eye(3) * 1e-4
    wv = np.linalg.solve(Sw, mu_d - mu_sand)
    scale = float(wv @ (mu_d - mu_sand))
    if scale <= 1e-9:
        raise SandtrackError("the seed box's marker does not differ in colour from the sand around it")
    wv = wv / scale
    b = -float(wv @ mu_sand)
    s_sand = sand @ wv + b
    s_disc = disc @ wv + b
    sand_hi = float(np.percentile(s_sand, 99.5))
    separation = float(np.median(s_disc)) - sand_hi
    if separation < 0.2:
        raise SandtrackError("no marker found in the seed box: its colour is not distinct from the sand")
    threshold = float(np.clip(max(0.45, sand_hi + 0.1), 0.3, 0.7))
    # Soft marker area: the box's clipped scores, less what the sand among them scores on its own
    # (its noise clipped at 0 is positive on average), so the area does not grow with the box.
    rest = patch[inner][p_in < t] @ wv + b
    area = float(np.clip(s_disc, 0, 1).sum() + np.clip(rest, 0, 1).sum()
                 - len(rest) * np.clip(s_sand, 0, 1).mean())
    area = max(area, 3.0)
    return ColourModel(w=wv, b=b, threshold=threshold, disc_area=area, radius=float(np.sqrt(area / np.pi)),
                       sand_spread=float(np.std(s_sand)))
