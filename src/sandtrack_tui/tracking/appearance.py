"""Appearance model of one marker, chosen from its seed box: what makes it stand out from its surround.

A marker is a contrast point. The seed box (the marker with some sand around it) is compared with
a ring of sand just outside the box, and the first of these that clearly separates the two is kept:

- ``colour``: the marker has a colour of its own that differs from the sand's (blue, red,
  fluorescent markers): a Fisher discriminant on chromaticity (colour.py). Brightness does not
  enter, so the marker's shaded side and its contact shadow on the sand do not move its centre.
- ``dark`` / ``bright``: the marker is darker or lighter than the sand (black, white, grey beads,
  retro-reflective markers, any grey-level video): the brightness (BT.601 luma) scaled so the sand
  scores 0 and the marker 1 (brightness.py). A grey marker (white, grey, black: no colour of its
  own) gets this model whenever its brightness stands out, even on coloured sand; otherwise colour
  comes first.
- ``texture``: the box holds structure the ring does not (a pattern, a corner), but no uniform blob:
  matched as a brightness template only; no centroid, no blob search.

Every model scores pixels by one formula, score = (w . bgr) / (den (B + G + R) + eps) + b (den 1
for chromaticity, 0 for brightness, so "score >= t" is a linear test on B, G, R in both), which is
what the compiled kernels, the 4:2:0 window reader and the blob search use. For the models with a
blob (colour, dark, bright) the clipped score of a pixel is its coverage by the marker, the weight
of the centroid.

The choice among them, from a seed box, is learning.py's (learn).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

from ..errors import SandtrackError
from . import kernels

COLOUR, DARK, BRIGHT, TEXTURE = "colour", "dark", "bright", "texture"
KINDS = (COLOUR, DARK, BRIGHT, TEXTURE)
_CLOSE = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
_SQUARE3 = np.ones((3, 3), np.uint8)
MIN_SEPARATION = 0.2  # marker median score minus the sand's 99.5th percentile, in marker-contrast units
MARKER_MEDIAN = 0.75  # a window whose median scores this much is mostly marker (a crowd): its sand level is unknown
CENTRE_RING_SHARE = 0.75  # share of a circle of half its radius around a seed box's centre that is marker
FOLLOW_RANGE = (0.5, 1.5)  # a dark model's contrast follows its marker within these multiples of the seed's ...
FOLLOW_DEADBAND = 0.1  # ... once its middle's score has changed by more than this share
# A window whose sand level (the marker removed) spans this much, in marker-contrast units, is crossed by
# a shadow's edge: each pixel is read against the sand on its own side of it.
SHADOW_STEP = 0.3
_SQUARES: dict = {}  # side -> the opening's structuring element


@dataclass
class AppearanceModel:
    w: np.ndarray  # (3,) weights on B, G, R (or on their chromaticity)
    b: float  # offset: score = (w . bgr) / (den (B + G + R) + eps) + b
    threshold: float  # score at or above which a pixel counts as marker
    disc_area: float  # marker pixels in the seed (px², soft)
    radius: float  # equivalent disc radius (px)
    sand_spread: float  # std of sand scores around the seed
    kind: str = COLOUR
    den: float = 1.0
    eps: float = 3.0
    floor: float | None = None  # weight floor (see weight_floor); None: the colour model's rule
    contrast: float = float("nan")  # marker minus sand, in units of the sand's own spread
    levels: tuple = field(default_factory=tuple)  # (marker, sand) in the model's natural unit, for reports
    # The marker stands out in brightness too (a brightness model would separate it): a shift of the
    # brightness around it is its own motion (rest.py). Not so for a white marker on beige sand, whose
    # shaded half is as bright as the sand: its window's brightness is the sand's texture, which stays.
    luma_follows: bool = True
    # A grey marker on coloured sand (white on beige): set apart by the sand's colour, which it lacks; it
    # has no chroma of its own to spread (see interpolated_score_window).
    grey: bool = False
    crowd: bool = False  # learned among touching markers like it (a dense layer)
    pattern: np.ndarray | None = None  # a crowd marker's brightness around it (finds the others like it)

    @property
    def has_blob(self) -> bool:
        """True when the marker is a blob whose clipped score is a coverage (colour, dark, bright)."""
        return self.kind != TEXTURE

    def score(self, bgr: np.ndarray) -> np.ndarray:
        """Per-pixel score, float32: ~0 on sand, ~1 on the marker."""
        if not bgr.size:
            return np.zeros(bgr.shape[:2], dtype=np.float32)
        return kernels.colour_score(bgr, *self._score_coeffs)

    def prepared(self, score: np.ndarray) -> np.ndarray:
        """A brightness model's score window as the matcher reads it. Brightness depends on the light:
        in a shadow (the tool's, a furrow's) the sand and the marker are darker by the same factor k.
        The window's median (its sand, unless markers fill most of it) gives k, and the score is that
        of the window's brightness divided by k: shadows do not look like a dark marker, and a
        marker in a shadow still scores 1. Where a shadow's edge crosses a dark marker's window, k is
        that of the sand on each pixel's side of the edge (_shadow_edge). Then small gaps inside the
        marker are filled (morphological closing):
        the specular highlight of a dark bead, the dark pole of a bright one are marker too. Colour
        and texture scores are returned as they are."""
        if self.kind not in (DARK, BRIGHT) or min(score.shape) < 3:
            return score
        b0 = kernels.median(score)
        sand = self._shadow_edge(score) if self.kind == DARK and not self.crowd else None
        level_d, level_s = self.levels
        if sand is not None:  # the sand level on each pixel's own side of the edge
            k = np.clip(1.0 + sand * np.float32((level_d - level_s) / level_s), 0.25, 2.0)
            score = (score - sand) / k
        elif abs(b0) > 0.05 and b0 < MARKER_MEDIAN:
            k = min(max(1.0 + b0 * (level_d - level_s) / level_s, 0.25), 2.0)
            score = (score - np.float32(b0)) * np.float32(1.0 / k)
        return np.maximum(score, cv2.morphologyEx(score, cv2.MORPH_CLOSE, _CLOSE))

    def _shadow_edge(self, score: np.ndarray) -> np.ndarray | None:
        """The sand level under each pixel of a window crossed by a shadow's edge (the tool's, a
        furrow's), or None when the window's sand is lit alike. (For a dark marker: a shadow's sand
        is as dark as the marker in the light and would be taken for it; a bright marker's surround
        may be a pattern, such as a board's, that no level per pixel describes.) A grey opening with a square wider than
        the marker removes the marker and keeps whatever is larger than it: the sand on either side of
        the edge, even where the shadow fills most of the window and its sand is as dark as the marker
        in the light (then smoothed, and raised by the median of what it removed, since an opening of
        sand grains sits below their median)."""
        d = 2 * int(np.ceil(self.radius)) + 3
        if min(score.shape) <= d:
            return None
        square = _SQUARES.get(d)
        if square is None:  # (a square: separable, a few times faster than a disc, and no marker holds it)
            square = _SQUARES[d] = np.ones((d, d), np.uint8)
        sand = cv2.blur(cv2.morphologyEx(score, cv2.MORPH_OPEN, square, borderType=cv2.BORDER_REPLICATE), (d, d),
                        borderType=cv2.BORDER_REPLICATE)
        if float(sand.max() - sand.min()) < SHADOW_STEP:
            return None
        return sand + np.float32(kernels.median(score - sand))

    def score_window(self, frame, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """score() of the window [y0:y1, x0:x1] of a frame (inside it), also of a frame still in its
        4:2:0 planes (yuv.py), without converting the window separately."""
        yuv = getattr(frame, "yuv", None)
        if yuv is not None and x1 > x0 and y1 > y0:
            return kernels.colour_score_yuv(*yuv, x0, y0, x1, y1, *self._score_coeffs)
        return self.score(frame[y0:y1, x0:x1])

    def interpolated_score_window(self, frame, x0: int, y0: int, x1: int, y1: int) -> np.ndarray | None:
        """score_window of a grey marker's colour model with the 4:2:0 chroma interpolated between its
        samples (kernels.colour_score_yuv_interpolated) rather than held over 2 x 2 blocks, which snaps
        the sand's colour edge around the marker to the block grid (a centre error fixed per marker and
        position: 0.27 side / 0.35 front px at intra frames on the rendered rig). A coloured marker's
        interpolated chroma spreads onto the darker pixels around it (its contact shadow), where it reads
        as more saturated than the marker itself and pulls the centre towards the shadow (measured: red
        markers 0.02-0.03 px further along their shadow's side, red on wet sand 0.29 -> 0.33 px mean); a
        grey marker has no chroma of its own to spread. None for other models and frames not in their
        4:2:0 planes."""
        yuv = getattr(frame, "yuv", None)
        if yuv is None or not self.grey or self.kind != COLOUR or x1 <= x0 or y1 <= y0:
            return None
        return kernels.colour_score_yuv_interpolated(*yuv, x0, y0, x1, y1, *self._score_coeffs)

    @cached_property
    def _score_coeffs(self) -> tuple:
        """(w0, w1, w2, b, eps, den) as float32, as the kernels take them."""
        return (*np.float32(self.w), np.float32(self.b), np.float32(self.eps), np.float32(self.den))

    @property
    def weight_floor(self) -> float:
        """Score from which a pixel counts towards a centroid or a blob's area: its weight is
        (score - floor) / (1 - floor), clipped to 0..1 (≈ its coverage by the marker)."""
        return self.floor if self.floor is not None else min(0.5 * self.threshold, 0.15)

    def mask_box(self, frame, x0: int, y0: int, x1: int, y1: int, threshold: float | None = None) -> tuple:
        """(mask, found, bx0, by0, bx1, by1): uint8 0/1 per pixel of the window [y0:y1, x0:x1] of a
        frame, score >= threshold (default: the model's), and the box of its ones in window
        coordinates. For 8-bit pixels the test is linear, (w + c den) . bgr + c eps >= 0 with
        c = b - threshold (the denominator is positive); a frame still in its 4:2:0 planes (yuv.py)
        computes it without converting the window."""
        t = self.threshold if threshold is None else threshold
        coeffs = self._mask_coeffs if threshold is None else self._coeffs_for(t)
        linear_mask = getattr(frame, "linear_mask", None)
        if linear_mask is not None:
            return linear_mask(coeffs, x0, y0, x1, y1)
        bgr = frame[y0:y1, x0:x1]
        if bgr.dtype == np.uint8 and bgr.size:
            return kernels.colour_mask(bgr, *coeffs)
        mask = (self.score(bgr) >= t).astype(np.uint8)
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        if not len(rows):
            return mask, False, 0, 0, 0, 0
        return mask, True, int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1

    def any_in(self, frame, boxes: np.ndarray) -> np.ndarray:
        """Per window (x0, y0, x1, y1) of `boxes` (n x 4 int64, inside the frame): may it hold a pixel
        of mask_box's mask? Exact (mask_box's `found`) for a colour model on a frame still in its 4:2:0
        planes, tested in one call; True where not tested."""
        found = getattr(frame, "linear_found", None)
        if found is None or self.kind in (DARK, BRIGHT) or not len(boxes):
            return np.ones(len(boxes), bool)
        return found(self._mask_coeffs, boxes)

    @cached_property
    def _mask_coeffs(self) -> tuple:
        return self._coeffs_for(self.threshold)

    def _coeffs_for(self, threshold: float) -> tuple:
        c = self.b - threshold
        return (*np.float32(self.w + c * self.den), np.float32(c * self.eps))

    def blob_moments(self, bgr: np.ndarray, labels: np.ndarray, k: int, xa: int, ya: int, xb: int, yb: int):
        """(area, m10, m01, pixels): pixel weights (see weight_floor) summed over component k of
        `labels` grown by one pixel, its first moments from (xa, ya), within rows ya..yb-1 and columns
        xa..xb-1 of `bgr`, and the component's pixel count there."""
        return kernels.blob_moments(bgr, labels, k, xa, ya, xb, yb, *self._score_coeffs, self.weight_floor)

    def follow_level(self, marker_score: float, alpha: float) -> None:
        """Let a dark model's marker level follow the marker. A glass bead shows the sand beneath it
        through its body, a wetted or dusted bead darkens or lightens: its body's brightness changes
        while the sand's does not. `marker_score`: the score of the marker's middle in a clean match;
        the first call gives its level as learned. The level moves by `alpha` of the change beyond
        FOLLOW_DEADBAND and stays within FOLLOW_RANGE times the seed's contrast with the sand (never
        onto the sand's own level). (A bright model's level is its shaded part, which moves with the
        light across it as it rolls: following it followed the light, not the marker, and cost the
        bright variants accuracy; a crowd's model is shared by its beads.)"""
        if self.kind != DARK or not self.levels or self.crowd or not np.isfinite(marker_score):
            return
        level_d, level_s = self.levels
        seed_d = self.__dict__.setdefault("_seed_levels", self.levels)[0]
        ref = self.__dict__.setdefault("_seed_middle", marker_score)
        if ref <= 0.25:
            return
        lo, hi = FOLLOW_RANGE
        c0 = seed_d - level_s
        change = marker_score / ref - 1.0  # (noise, blur and shading within FOLLOW_DEADBAND are not followed)
        change = float(np.sign(change) * max(abs(change) - FOLLOW_DEADBAND, 0.0))
        c = (level_d - level_s) * (1.0 + alpha * change)
        c = float(np.clip(abs(c), lo * abs(c0), hi * abs(c0))) * np.sign(c0)
        if abs(c - (level_d - level_s)) < 1e-3 * abs(c0):
            return
        self.w = self.w * ((level_d - level_s) / c)
        self.b = -level_s / c
        self.levels = (level_s + c, level_s)
        for key in ("_score_coeffs", "_mask_coeffs"):
            self.__dict__.pop(key, None)

    def display_mask(self, bgr: np.ndarray, scale: float = 1.0) -> np.ndarray | None:
        """uint8 mask (255 = looks like this marker) of an image shown at `scale` source px per pixel,
        for the display's marker boost; None for a texture model (nothing per pixel to find). A
        brightness model's score is read against the sand level under each pixel, found as
        _shadow_edge finds it (a grey opening wider than the marker keeps a shadow and drops the
        markers), so that a shadow is not shown as marker."""
        if self.kind == TEXTURE or not bgr.size:
            return None
        score = self.score(bgr)
        if self.kind in (DARK, BRIGHT) and self.levels:
            d = max(3, int(np.ceil((2 * self.radius + 3) / max(scale, 1e-6))) | 1)
            square = np.ones((d, d), np.uint8)
            sand = cv2.blur(cv2.morphologyEx(score, cv2.MORPH_OPEN, square, borderType=cv2.BORDER_REPLICATE), (d, d),
                            borderType=cv2.BORDER_REPLICATE)
            sand += np.float32(np.median(score[::4, ::4] - sand[::4, ::4]))
            level_d, level_s = self.levels
            k = np.clip(1.0 + sand * np.float32((level_d - level_s) / level_s), 0.25, 2.0)
            score = (score - sand) / k
        return cv2.compare(score, float(self.threshold), cv2.CMP_GE)

    def describe(self) -> dict:
        """What the model is and what it measured, for reports (`track --json`, the seeding list)."""
        out = {"model": self.kind, "contrast": round(float(self.contrast), 1), "radius_px": round(self.radius, 2)}
        levels = self.__dict__.get("_seed_levels", self.levels)  # (as learned at the seed)
        if levels:
            out["marker_level"], out["sand_level"] = (round(float(v), 3) for v in levels)
        return out


def describe_text(desc: dict) -> str:
    """One line from AppearanceModel.describe(), e.g. "dark (luma 38 on 151), contrast 11.2"."""
    what = desc["model"]
    if what in (DARK, BRIGHT) and "marker_level" in desc:
        what += f" (luma {desc['marker_level']:.0f} on {desc['sand_level']:.0f})"
    return f"{what}, contrast {desc['contrast']:.1f}"


def _first_gap(mask: np.ndarray, px: int, py: int, rays: int = 32) -> float | None:
    """Median over rays from (px, py) of the distance at which `mask` first ends (rays that leave the
    image without meeting a gap, through the contacts with touching markers, are left out); None
    when too few rays meet one. (Every ray's steps of 0.25 px at once, each rounded to its pixel.)"""
    h, w = mask.shape
    a = np.linspace(0, 2 * np.pi, rays, endpoint=False)
    d = np.arange(0.5, max(h, w), 0.25)
    x = np.rint(px + d[None, :] * np.cos(a)[:, None]).astype(np.int64)
    y = np.rint(py + d[None, :] * np.sin(a)[:, None]).astype(np.int64)
    inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    gap = inside & ~mask[np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)].astype(bool)
    stop = gap | ~inside
    first = np.argmax(stop, axis=1)  # each ray's first step off the image or onto a gap
    met = stop.any(axis=1) & gap[np.arange(rays), first]
    hits = d[first[met]]
    return float(np.median(hits)) if len(hits) >= rays // 4 else None


def _group_medians(values: np.ndarray, groups: np.ndarray, n: int) -> np.ndarray:
    """np.median of `values` in each group 0..n-1 that has any, in group order (one sort for all)."""
    order = np.lexsort((values, groups))
    v = values[order]
    counts = np.bincount(groups, minlength=n)
    counts = counts[counts > 0]
    start = np.cumsum(counts) - counts
    hi = start + counts // 2
    lo = np.where(counts % 2 == 1, hi, hi - 1)
    return (v[lo] + v[hi]) / 2


def _holes_filled(mask: np.ndarray) -> np.ndarray:
    """A 0/1 uint8 mask with its holes filled (bool): the background not 4-connected to the border
    is filled, as scipy.ndimage.binary_fill_holes does (a flood fill from a border around it)."""
    h, w = mask.shape
    canvas = np.zeros((h + 2, w + 2), np.uint8)
    canvas[1:-1, 1:-1] = mask
    cv2.floodFill(canvas, None, (0, 0), 2, flags=4)
    return canvas[1:-1, 1:-1] != 2


def marker_level(p_in: np.ndarray, sand_mid: float) -> float:
    """The level that splits a seed box's inner pixels, projected on the marker-vs-sand direction
    (`p_in`, larger = more like the marker), into marker and sand: 2-means started halfway between
    the 95th percentile and the sand ring's median `sand_mid`, the sand side's mean pulled halfway to
    that median."""
    t = 0.5 * (np.percentile(p_in, 95) + sand_mid)
    for _ in range(10):
        hi, lo = p_in[p_in >= t], p_in[p_in < t]
        if len(hi) == 0 or len(lo) == 0:
            break
        t_new = 0.5 * (hi.mean() + 0.5 * (lo.mean() + sand_mid))
        if abs(t_new - t) < 1e-6:
            break
        t = t_new
    return t


@dataclass
class SeedPatch:
    """The pixels around a seed box: `bgr` (N, 3) float64, masks `inner` (the box) and `ring` (sand
    just outside it), pixel coordinates `xx`, `yy`, the box centre and size."""

    bgr: np.ndarray
    inner: np.ndarray
    ring: np.ndarray
    xx: np.ndarray
    yy: np.ndarray
    cx: float
    cy: float
    w: float
    h: float
    frame: np.ndarray | None = None  # the image the box was cut from
    crowded: bool = False  # the marker's part runs out of the box: it touches others like it (centre_component)

    @classmethod
    def cut(cls, frame, cx: float, cy: float, w: float, h: float, widen: float = 1.0) -> SeedPatch:
        from ..video import to_bgr8

        H, W = frame.shape[:2]
        if not (np.isfinite(cx) and np.isfinite(cy)) or not (0 <= cx < W and 0 <= cy < H):
            raise SandtrackError(f"seed point ({cx:.1f}, {cy:.1f}) lies outside the {W}x{H} image")
        if not (w >= 3 and h >= 3):
            raise SandtrackError(f"seed box {w}x{h} px is too small (at least 3x3)")
        half_in = 0.5 * max(w, h)
        margin = max(4.0, 0.5 * half_in) * widen
        R = int(np.ceil(half_in + margin))
        x0, x1 = int(round(cx)) - R, int(round(cx)) + R + 1
        y0, y1 = int(round(cy)) - R, int(round(cy)) + R + 1
        win = to_bgr8(frame[max(y0, 0):min(y1, H), max(x0, 0):min(x1, W)])
        patch = win.reshape(-1, 3).astype(np.float64)
        yy, xx = np.mgrid[max(y0, 0):min(y1, H), max(x0, 0):min(x1, W)]
        dx, dy = np.abs(xx.ravel() - cx), np.abs(yy.ravel() - cy)
        inner = (dx <= 0.5 * w) & (dy <= 0.5 * h)
        ring = (np.maximum(dx, dy) >= half_in + 1.5)
        if inner.sum() < 4 or ring.sum() < 12:
            raise SandtrackError("seed box lies too close to the image border to learn the marker's appearance")
        return cls(patch, inner, ring, xx.ravel(), yy.ravel(), float(cx), float(cy), float(w), float(h), frame)

    def centre_scores(self, model: AppearanceModel) -> bool:
        """The model scores the box's centre as marker: the pixels within 1.5 px of it, and most of
        those on a circle of half the marker's radius around it (a box centred on a blob has marker
        all around its centre; one centred on where dark and light areas meet, a corner of a
        pattern, has the blob on one side only)."""
        d = self._centre_distance
        near = d <= 1.5
        if not near.any():
            return True
        scores = model.score(self._bgr8[None])[0]
        if np.median(scores[near]) < model.threshold:
            return False
        rho = 0.5 * model.radius
        ring = np.abs(d - rho) <= 0.75
        if rho <= 2.0 or np.count_nonzero(ring) < 8:
            return True
        # Per eighth of the circle (a dusty marker's specks are scattered; a pattern's other half is whole
        # sectors): the share of sectors whose median scores as marker.
        on = _group_medians(scores[ring], self._centre_sector[ring], 8) >= model.threshold
        return bool(np.mean(on) >= CENTRE_RING_SHARE)

    @cached_property
    def _centre_distance(self) -> np.ndarray:
        return np.hypot(self.xx - self.cx, self.yy - self.cy)

    @cached_property
    def _centre_sector(self) -> np.ndarray:
        """Each pixel's eighth of the circle around the box's centre."""
        return np.floor((np.arctan2(self.yy - self.cy, self.xx - self.cx) + np.pi) / (np.pi / 4)).astype(int) % 8

    @cached_property
    def _bgr8(self) -> np.ndarray:
        return np.clip(self.bgr, 0, 255).astype(np.uint8)

    def _central_holes_filled(self, own: np.ndarray, solid: np.ndarray, x0: int, y0: int) -> np.ndarray:
        """`own` with its holes near the box's centre filled: with sand all around the box, a hole
        there is the marker's own highlight (a glossy bead reflects the lamp near its middle), not a
        gap between touching markers (which lie about a marker's radius from its centre)."""
        holes = (solid & ~own).astype(np.uint8)
        if not holes.any():
            return own
        _n, labels = cv2.connectedComponents(holes, connectivity=4)
        gy, gx = np.ogrid[0:own.shape[0], 0:own.shape[1]]
        near = np.hypot(gx + x0 - self.cx, gy + y0 - self.cy) <= 0.25 * min(self.w, self.h)
        central = np.unique(labels[near & (labels > 0)])
        return own | np.isin(labels, central) if len(central) else own

    @cached_property
    def luma(self) -> np.ndarray:
        from .chroma import LUMA_BGR

        return self.bgr @ LUMA_BGR.astype(np.float64)

    def centre_component(self, selected: np.ndarray, sand_around: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(chosen, others): `selected` (a mask over the inner pixels) reduced to its connected part at
        the box centre, when it splits into several parts of some size (a loose box holding more
        than one marker; parts of 1-2 pixels, noise, are kept); and the other parts grown by a pixel
        (other markers, left out of the marker's area)."""
        xi, yi = self.xx[self.inner], self.yy[self.inner]
        none = np.zeros_like(selected)
        if not selected.any():
            return selected, none
        x0, y0 = xi.min(), yi.min()
        img = np.zeros((yi.max() - y0 + 1, xi.max() - x0 + 1), np.uint8)
        img[yi[selected] - y0, xi[selected] - x0] = 1
        n, labels, stats, cents = cv2.connectedComponentsWithStats(img, connectivity=8)
        big = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= 3]
        if not big:
            return selected, none
        d = [np.hypot(cents[k, 0] + x0 - self.cx, cents[k, 1] + y0 - self.cy) for k in big]
        keep = big[int(np.argmin(d))]
        own = labels == keep
        # Touching markers (a dense layer) are one connected part: the marker's own disc is the one
        # around the distance-transform peak nearest the centre, of the radius at which rays from it
        # first meet sand (the median: rays through the contacts with neighbours meet none in the box).
        # (a dusty marker's sand specks are not gaps: closed and filled first)
        crowded = own[0].any() or own[-1].any() or own[:, 0].any() or own[:, -1].any()  # runs out of the box
        solid = _holes_filled(cv2.morphologyEx(own.astype(np.uint8), cv2.MORPH_CLOSE, _SQUARE3)) \
            if sand_around or crowded else None
        body = self._central_holes_filled(own, solid, x0, y0) if sand_around else own
        dt = cv2.distanceTransform(body.astype(np.uint8), cv2.DIST_L2, 5)
        peaks = (dt >= cv2.dilate(dt, np.ones((3, 3), np.uint8))) & (dt >= 0.6 * dt.max()) & body
        ys, xs = np.nonzero(peaks)
        if len(xs) and crowded:
            k = int(np.argmin(np.hypot(xs + x0 - self.cx, ys + y0 - self.cy)))
            px, py = int(xs[k]), int(ys[k])
            rd = _first_gap(solid, px, py)
            if rd is not None and own.sum() > 1.3 * np.pi * rd**2:
                gy, gx = np.ogrid[0:own.shape[0], 0:own.shape[1]]
                own &= np.hypot(gx - px, gy - py) <= rd + 0.5
                # (its part is far more than its own disc, and holds another disc as deep: it touches others)
                self.crowded = bool(np.any((np.hypot(xs - px, ys - py) >= 1.6 * rd) & (dt[ys, xs] >= 0.6 * dt[py, px])))
        lab_own = own[yi - y0, xi - x0]
        other = (img.astype(bool) & ~own).astype(np.uint8)
        is_big = np.zeros(n, bool)
        is_big[big] = True
        other[~is_big[labels]] = 0  # noise pixels are kept with the marker
        grown = cv2.dilate(other, np.ones((3, 3), np.uint8))[yi - y0, xi - x0] > 0
        noise = ~is_big[labels[yi - y0, xi - x0]]
        return selected & (lab_own | noise), grown & ~lab_own
