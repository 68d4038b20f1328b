"""Brightness and texture models of one marker (appearance.py), learned from its seed box.

Brightness (``dark`` / ``bright``): the marker's luma against the sand ring's. The polarity is the
side on which the box holds more pixels far outside the sand's own spread; the box's pixels are
split into marker and sand by 2-means along it; the score is luma scaled so the sand's mean scores
0 and the marker's 1. Unlike chromaticity, brightness sees the marker's shading and its contact
shadow (a shadow is darker sand): for a dark marker the weight floor is set at half the marker's
contrast, so sand darkened by up to half of it weighs nothing and a pixel's weight still grows with
its coverage (symmetrically around the marker, so the centroid keeps the centre). A bright marker's
"1" is its shaded part (its dimmest tenth), so its lit side does not pull the centre.

Texture: the box's brightness varies well beyond the ring's (a pattern, a corner, a marker of two
tones) without a blob: the score is the luma scaled by the box's spread, for template matching only.
"""

from __future__ import annotations

import numpy as np

from .appearance import BRIGHT, DARK, MIN_SEPARATION, TEXTURE, AppearanceModel, SeedPatch, marker_level
from .chroma import LUMA_BGR

OUTLIER_Z = 3.0  # pixels this many robust deviations of the sand away count towards the polarity
BRIGHTNESS_FLOOR = 0.5
TWO_TONE = 0.6  # darker and lighter areas this balanced make a pattern, not a dark or bright blob
TEXTURE_RATIO = 2.5  # the box's luma spread over the ring's for a texture model


def _robust(v: np.ndarray) -> tuple[float, float]:
    med = float(np.median(v))
    return med, float(1.4826 * np.median(np.abs(v - med)))


def _centre_level(seed: SeedPatch) -> float:
    """Brightness at the box's centre (the marker the box is centred on)."""
    d = np.hypot(seed.xx - seed.cx, seed.yy - seed.cy)
    centre = d <= max(1.5, min(seed.w, seed.h) / 6)
    return float(np.median(seed.luma[centre])) if centre.any() else float(np.median(seed.luma[seed.inner]))


def _surround(ring: np.ndarray, centre: float, sign: float | None = None) -> np.ndarray:
    """The ring's sand. In a dense layer the ring is mostly other markers like the centre one, with
    sand (or gaps) between: when the ring's brightness falls into two clear groups, the sand is the
    group farther from the centre's level (the marker's polarity `sign` known: the brighter group for
    a dark marker, the darker for a bright one)."""
    lo, hi = np.percentile(ring, (10, 90))
    if hi - lo < 1e-6:
        return ring
    t = 0.5 * (lo + hi)
    for _ in range(10):
        a, b = ring[ring < t], ring[ring >= t]
        if not len(a) or not len(b):
            return ring
        t_new = 0.5 * (a.mean() + b.mean())
        if abs(t_new - t) < 1e-3:
            break
        t = t_new
    a, b = ring[ring < t], ring[ring >= t]
    spread = max(_robust(a)[1], _robust(b)[1], 1.0)
    if sign is not None:
        near, far = (a, b) if sign < 0 else (b, a)
    else:
        near, far = (a, b) if abs(np.median(a) - centre) < abs(np.median(b) - centre) else (b, a)
    if abs(np.median(b) - np.median(a)) < 4 * spread or len(near) < 0.25 * len(ring) or len(far) < 12:
        return ring  # one group (sand), or a few neighbour pixels the caller drops
    return far


def _two_tone(z: np.ndarray) -> bool:
    n_dark, n_bright = np.count_nonzero(z < -OUTLIER_Z), np.count_nonzero(z > OUTLIER_Z)
    return n_dark + n_bright > 0 and min(n_dark, n_bright) >= TWO_TONE * max(n_dark, n_bright)


def two_tone(seed: SeedPatch) -> bool:
    """The box holds about as much darker as lighter than the sand around it: a pattern."""
    sand = _surround(seed.luma[seed.ring], _centre_level(seed))
    med, mad = _robust(sand)
    return _two_tone((seed.luma[seed.inner] - med) / max(mad, 1.0))


def learn_brightness(seed: SeedPatch, sign: float | None = None) -> tuple[AppearanceModel | None, float]:
    """The dark or bright model of a seed, or None; and the separation measured (see colour.py).
    `sign`: -1 a dark marker, 1 a bright one is wanted (known from a marker it is like); else the
    side on which the box stands out more."""
    L = seed.luma
    inside = L[seed.inner]
    sand = _surround(L[seed.ring], _centre_level(seed), sign)
    sand_around = len(sand) == np.count_nonzero(seed.ring)  # (the ring is one group: no lookalikes in it)
    med, mad = _robust(sand)
    mad = max(mad, 1.0)  # quantised, clean sand (grey-level images): one level
    z = (inside - med) / mad
    dark, bright = np.clip(-z - OUTLIER_Z, 0, None).sum(), np.clip(z - OUTLIER_Z, 0, None).sum()
    if (dark if sign is not None and sign < 0 else bright if sign is not None else dark + bright) == 0:
        return None, float("nan")
    if sign is None and _two_tone(z):
        return None, float("nan")  # as much darker as lighter than the sand: a pattern (texture), no blob
    if sign is None:
        sign = -1.0 if dark >= bright else 1.0
    sand = sand[sign * (sand - med) <= 4 * mad]  # neighbouring markers reaching into the ring
    mu_s = float(np.median(sand))
    p_in = sign * (inside - mu_s)
    sand_mid = np.median(sign * (sand - mu_s))
    t = marker_level(p_in, sand_mid)
    chosen, others = seed.centre_component(p_in >= t, sand_around=sand_around)
    if chosen.sum() < 3:
        return None, float("nan")
    own_radius, own_centre = None, None
    if seed.crowded:
        chosen, others, own_radius, own_centre = _own_disc(seed, p_in >= t, chosen, others, sign)
        if chosen.sum() < 3:  # (no disc of its own among the touching ones)
            return None, float("nan")
    # A bright marker is lit on one side and shaded on the other: its level is that of its shaded
    # part (its dimmest tenth), so the whole marker weighs alike and the centre is its outline's.
    level_d = float(inside[chosen].mean() if sign < 0 else np.percentile(inside[chosen], 10))
    level_s = float(sand.mean())
    contrast = level_d - level_s
    if abs(contrast) < 1.0:
        return None, float("nan")
    s_sand = (sand - level_s) / contrast
    s_disc = (inside[chosen] - level_s) / contrast
    sand_hi = float(np.percentile(s_sand, 99.5))
    separation = float(np.median(s_disc)) - sand_hi
    if separation < MIN_SEPARATION:
        return None, separation
    threshold = float(np.clip(max(0.45, sand_hi + 0.1), 0.3, 0.7))
    # Darker sand (a shadow) looks like a dark marker, not like a bright one: only a dark marker's
    # weights start as high as half its contrast.
    floor = max(BRIGHTNESS_FLOOR, min(sand_hi, threshold - 0.05)) if sign < 0 else max(min(0.5 * threshold, 0.15),
                                                                                       min(sand_hi, 0.5))
    # Soft area with the floor's weights (as the centroid counts them), less the sand's own share.
    weight = lambda s: np.clip((s - floor) / (1 - floor), 0, 1)  # noqa: E731
    rest = (inside[~chosen & ~others] - level_s) / contrast
    area = float(weight(s_disc).sum() + weight(rest).sum() - len(rest) * weight(s_sand).mean())
    area = max(area, 3.0)
    # The radius from the plain clipped scores (a shaded sphere's rim counts by its coverage).
    plain = lambda v: np.clip(v, 0, 1)  # noqa: E731
    full = max(float(plain(s_disc).sum() + plain(rest).sum() - len(rest) * plain(s_sand).mean()), area)
    spread = float(np.std(s_sand))
    kind = DARK if sign < 0 else BRIGHT
    w = LUMA_BGR.astype(np.float64) / contrast
    return AppearanceModel(w=w, b=-level_s / contrast, threshold=threshold, disc_area=area,
                           radius=own_radius or float(np.sqrt(full / np.pi)), sand_spread=spread, kind=kind, den=0.0,
                           eps=1.0,
                           floor=floor, contrast=float(np.median(s_disc) - np.median(s_sand)) / max(spread, 1e-6),
                           levels=(level_d, level_s), crowd=seed.crowded,
                           pattern=_luma_patch(seed, own_centre, own_radius) if own_radius else None), separation


def _luma_patch(seed: SeedPatch, centre: tuple, radius: float) -> np.ndarray | None:
    """The brightness of a marker among touching ones (its shading, its highlight), a square of its
    diameter centred on it: what every marker like it looks like."""
    import cv2

    from ..video import to_bgr8

    half = int(np.ceil(radius))
    size = 2 * half + 1
    x0, y0 = int(np.floor(centre[0])) - half - 2, int(np.floor(centre[1])) - half - 2
    H, W = seed.frame.shape[:2]
    if x0 < 0 or y0 < 0 or x0 + size + 4 > W or y0 + size + 4 > H:
        return None
    win = to_bgr8(seed.frame[y0:y0 + size + 4, x0:x0 + size + 4]).astype(np.float32) @ LUMA_BGR
    return cv2.getRectSubPix(np.ascontiguousarray(win, np.float32), (size, size), (centre[0] - x0, centre[1] - y0))


def _own_disc(seed: SeedPatch, selected: np.ndarray, chosen: np.ndarray, others: np.ndarray, sign: float):
    """Among touching markers like it (a dense layer) the marker's own pixels are those inside its
    outline, fitted where it borders the gaps between the markers (luma.edge_circle; the contacts with
    its neighbours show no edge, or a neighbour's far one, which lies outside the circle). The rest
    of the box is other markers. Returns (chosen, others, the outline's radius, its centre); (chosen,
    others, None, None) when no outline is found."""
    from ..video import to_bgr8
    from .luma import edge_circle

    guess = max(float(np.sqrt(chosen.sum() / np.pi)), 2.0)
    H, W = seed.frame.shape[:2]
    R = int(np.ceil(1.8 * 1.5 * guess + 5))
    ox, oy = max(int(round(seed.cx)) - R, 0), max(int(round(seed.cy)) - R, 0)
    win = np.ascontiguousarray(to_bgr8(seed.frame[oy:min(int(round(seed.cy)) + R + 1, H),
                                                  ox:min(int(round(seed.cx)) + R + 1, W)]))
    c = edge_circle(win, seed.cx - ox, seed.cy - oy, guess, iterations=5, polarity=-sign, outward=sign < 0)
    if c is None or np.hypot(c[0] + ox - seed.cx, c[1] + oy - seed.cy) > 0.5 * c[2]:
        return chosen, others, None, None
    d = np.hypot(seed.xx[seed.inner] - (c[0] + ox), seed.yy[seed.inner] - (c[1] + oy))
    return selected & (d <= c[2]), (d > c[2] + 1.0), float(c[2]), (c[0] + ox, c[1] + oy)


def learn_texture(seed: SeedPatch) -> AppearanceModel | None:
    """A texture model when the box's luma varies well beyond the ring's (a template to match), or None."""
    L = seed.luma
    level_s, sd_ring = _robust(L[seed.ring])
    sd_in = float(np.std(L[seed.inner]))
    sd_ring = max(sd_ring, 1.0)
    if sd_in < TEXTURE_RATIO * sd_ring:
        return None
    w = LUMA_BGR.astype(np.float64) / sd_in
    radius = max(0.5 * min(seed.w, seed.h) - 1.0, 2.0)
    return AppearanceModel(w=w, b=-level_s / sd_in, threshold=float("nan"), disc_area=float("nan"), radius=radius,
                           sand_spread=sd_ring / sd_in, kind=TEXTURE, den=0.0, eps=1.0, floor=0.0,
                           contrast=sd_in / sd_ring, levels=(float(np.median(L[seed.inner])), level_s))
