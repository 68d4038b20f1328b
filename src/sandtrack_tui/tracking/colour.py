"""Colour model of one marker (appearance.py), learned from its seed box: marker disc against the sand around it.

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

import numpy as np

from .appearance import COLOUR, MIN_SEPARATION, AppearanceModel, marker_level

EPS = 3.0  # added to B + G + R: keeps the chromaticity of near-black pixels finite
MIN_LUMA_FRACTION = 0.25  # a marker darker than this share of the sand's brightness is left to brightness
BODY_SHARE = 0.7  # a marker's body: its pixels within this share of its radius from its middle
BODY_LEVEL_MIN = 0.6  # the body's least coloured tenth scores 1, unless it scores below this (then this) ...
BODY_UNIFORM = 0.95  # ... or above this: a body this uniform has no paler side, only noise


def chromaticity(bgr: np.ndarray) -> np.ndarray:
    f = np.asarray(bgr, dtype=np.float64)
    return f / (f.sum(axis=-1, keepdims=True) + EPS)


def blueness(bgr: np.ndarray) -> np.ndarray:
    """Generic blue-against-sand measure, float32: B - (G + R) / 2 (sand is strongly negative)."""
    f = bgr.astype(np.float32)
    return f[..., 0] - 0.5 * (f[..., 1] + f[..., 2])


def chroma_blueness(bgr: np.ndarray) -> np.ndarray:
    """Blueness of the chromaticity, float32 in about -0.5..1: independent of shading and shadows."""
    f = bgr.astype(np.float32)
    return (f[..., 0] - 0.5 * (f[..., 1] + f[..., 2])) / (f.sum(axis=-1) + EPS)


GREY_CHROMA = 0.04  # a marker whose mean chromaticity is this close to grey (1/3 each) has no colour of its own


def achromatic(seed, model) -> bool:
    """The marker a model learned from `seed` scores (its pixels at or above the threshold in the box)
    is grey: white, grey or black, with no colour of its own."""
    inner = seed.bgr[seed.inner]
    scores = model.score(np.clip(inner, 0, 255).astype(np.uint8)[None])[0]
    disc = inner[scores >= model.threshold]
    if len(disc) < 3:
        return False
    return bool(np.abs(chromaticity(disc.mean(axis=0)) - 1 / 3).max() < GREY_CHROMA)


def _body_level(seed, inner: np.ndarray, chosen: np.ndarray, s_disc: np.ndarray) -> float:
    """Score of the least coloured tenth of the marker's body (its pixels well inside its outline),
    at least BODY_LEVEL_MIN. A lit sphere is less saturated on its lit side (the highlight and the
    light add the colours it lacks) than on its shaded side: scaled so that the body's mean scores 1,
    the lit side weighed less than the shaded side and the centroid slid towards the shade (a red
    marker: ~0.2 px). Scaled so this level scores 1, the whole body weighs 1 (clipped) and only the
    pixels of its outline, mixed with sand, weigh by their coverage, as for a bright marker
    (brightness.py). A grey marker (white on beige sand) has no saturation to lose: 1."""
    if np.abs(chromaticity(seed.bgr[inner][chosen].mean(axis=0)) - 1 / 3).max() < GREY_CHROMA:
        return 1.0
    xs, ys = seed.xx[inner][chosen], seed.yy[inner][chosen]
    r_body = BODY_SHARE * np.sqrt(len(xs) / np.pi)
    body = np.hypot(xs - xs.mean(), ys - ys.mean()) <= r_body
    if np.count_nonzero(body) < 5:
        return 1.0
    return float(np.clip(np.percentile(s_disc[body], 10), BODY_LEVEL_MIN, 1.0))


def learn_colour(seed) -> tuple[AppearanceModel | None, float]:
    """The colour model of a seed (appearance.SeedPatch), or None when the marker's chromaticity
    does not stand out from the sand's; and the separation measured (marker median score minus
    the sand's 99.5th percentile; NaN when there was nothing to separate)."""
    patch = chromaticity(seed.bgr)
    inner, ring = seed.inner, seed.ring
    sand = patch[ring]
    # Neighbouring markers may reach into the ring: drop its pixels clearly of the marker's colour
    # (blue markers: clearly blue pixels).
    blue_dir = np.array([1.0, -0.5, -0.5])
    prelim = patch[inner].mean(axis=0) - np.median(sand, axis=0)
    clean_dir = blue_dir if prelim @ blue_dir > 0 or np.linalg.norm(prelim) < 1e-9 else prelim
    bl = sand @ clean_dir
    med = np.median(bl)
    mad = 1.4826 * np.median(np.abs(bl - med)) + 0.005 * np.linalg.norm(clean_dir) / np.linalg.norm(blue_dir)
    sand = sand[bl <= med + 4 * mad]
    # First direction: inner pixels furthest from sand in the marker-vs-sand sense; split the box's
    # pixels into marker and sand by 2-means along it.
    mu_s = np.median(sand, axis=0)
    d0 = patch[inner].mean(axis=0) - mu_s
    if np.linalg.norm(d0) < 1e-6 or d0 @ clean_dir <= 0:
        d0 = clean_dir
    p_in = (patch[inner] - mu_s) @ d0
    sand_mid = np.median((sand - mu_s) @ d0)
    t = marker_level(p_in, sand_mid)
    chosen, others = seed.centre_component(p_in >= t)
    disc = patch[inner][chosen]
    if len(disc) < 3:
        return None, float("nan")
    if np.median(seed.luma[inner][chosen]) < MIN_LUMA_FRACTION * np.median(seed.luma[ring]):
        return None, float("nan")  # a black marker has no colour: its chromaticity is noise
    # Fisher discriminant between disc and sand.
    mu_d, mu_sand = disc.mean(axis=0), sand.mean(axis=0)
    Sw = np.cov(sand.T) + (np.cov(disc.T) if len(disc) > 3 else 0) + np.eye(3) * 1e-4
    wv = np.linalg.solve(Sw, mu_d - mu_sand)
    scale = float(wv @ (mu_d - mu_sand))
    if scale <= 1e-9:
        return None, float("nan")
    wv = wv / scale
    b = -float(wv @ mu_sand)
    s_sand = sand @ wv + b
    s_disc = disc @ wv + b
    sand_hi = float(np.percentile(s_sand, 99.5))
    separation = float(np.median(s_disc)) - sand_hi
    if separation < MIN_SEPARATION:
        return None, separation
    level = _body_level(seed, inner, chosen, s_disc)
    if level < BODY_UNIFORM:
        wv, b = wv / level, b / level
        s_sand, s_disc = s_sand / level, s_disc / level
        sand_hi /= level
    threshold = float(np.clip(max(0.45, sand_hi + 0.1), 0.3, 0.7))
    # Soft marker area: the box's clipped scores, less what the sand among them scores on its own
    # (its noise clipped at 0 is positive on average), so the area does not grow with the box.
    rest = patch[inner][~chosen & ~others] @ wv + b
    area = float(np.clip(s_disc, 0, 1).sum() + np.clip(rest, 0, 1).sum()
                 - len(rest) * np.clip(s_sand, 0, 1).mean())
    area = max(area, 3.0)
    radius = float(np.sqrt(area / np.pi))
    spread = float(np.std(s_sand))
    floor = None
    if 3 * spread > 0.15:
        # A marker of weak colour (white on beige sand): weights start above the sand's own noise (3
        # spreads), or noisy sand pixels weigh in every centroid; the marker area is then counted with
        # the same weights, as the tracker counts it.
        floor = min(3 * spread, 0.5)
        weight = lambda v: np.clip((v - floor) / (1 - floor), 0, 1)  # noqa: E731
        area = max(float(weight(s_disc).sum() + weight(rest).sum() - len(rest) * weight(s_sand).mean()), 3.0)
    return AppearanceModel(w=wv, b=b, threshold=threshold, disc_area=area, radius=radius,
                           sand_spread=spread, kind=COLOUR, den=1.0, eps=EPS, floor=floor,
                           contrast=float(np.median(s_disc) - np.median(s_sand)) / max(spread, 1e-6)), separation
