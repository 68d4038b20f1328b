"""Detect every particle that looks like one seeded particle, in a whole frame (or a part of it).

`learn_particle(frame, x, y, diameter_px)` learns the look of the particle at (x, y): the colour
direction that separates it from what surrounds it (grey frames: darker or brighter) and its radial
profile along that direction, as a rotationally symmetric template. `detect(frame, model, roi)` is a
matched filter (normalised cross-correlation with that template) over the frame, non-maximum
suppression at `NMS_DIAMETERS` of a diameter (touching beads of a packed bed each give one peak) and
a sub-pixel centre from a parabola through the peak. A solid particle's blob that is two overlapping
particles is resolved into both (split_merged) or, when that is not clear, marked `merged`. Returns a
DataFrame with DETECTION_COLUMNS.
Frames may be grey or colour (BGR), of any integer or float type.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import pandas as pd

from ..errors import SandtrackError

DETECTION_COLUMNS = ["x_px", "y_px", "size_px", "contrast", "confidence", "merged", "split"]
NMS_DIAMETERS = 0.7  # two peaks closer than this many diameters are one particle
MIN_CONFIDENCE = 0.7  # normalised cross-correlation with the learnt template
REMAP_ROWS = 30000
# A particle with a pattern inside (a glass bead's bright centre) is matched by that pattern alone, out
# to this share of its radius: in a packed bed the rim touches other beads and is no clue.
PATTERN_RADIUS = 0.6
PATTERN_MIN = 0.2  # a pattern: the profile inside varies by this share of the particle's contrast
# The body check: along every one of BODY_RAYS rays, the ring from BODY_RING[0] to BODY_RING[1] radii
# must look at least BODY_MIN like the seed's body (1) rather than its surroundings (0). A bright gap
# between three touching beads also looks like a bright centre, but bright arms cross that ring.
BODY_RAYS, BODY_RING, BODY_MIN = 16, (0.45, 0.85), 0.9
# A solid particle (no pattern) is matched with its rim, so no gap looks like it; its body check is
# against its OWN surroundings, as a marker in shade or on darker sand is darker all round: along all but
# SOLID_RAYS_MISSED rays (a marker partly hidden by a grain or a neighbour) the body ring must stand out
# of the local background (the darker quarter of the ring SOLID_BACKGROUND radii out) by SOLID_MIN of
# the seed's own contrast, and along most rays (more than half) out of that same ray's ring: a particle
# stands out on most sides, an edge between two levels on one side only. Shade, depth (size) and partial
# hiding lower the template match, so a solid particle's match may be weaker; the body check keeps what is
# not a particle out.
SOLID_RAYS_MISSED, SOLID_BACKGROUND, SOLID_MIN = 4, (1.3, 1.8), 0.35
SOLID_MIN_CONFIDENCE = 0.4
EDGE_REACH = 1.8  # blob_axes: an edge farther than this many of the blob's radii is a touching neighbour's
SIZE_SLACK = 1.5  # ... and is looked for out to this many times EDGE_REACH of the model's radius
# Two overlapping solid particles (one partly behind the other) give one template peak: their union is
# a blob longer than it is wide. Of two discs of radius r whose centres are s apart, the union's half
# length is a = r + s/2 and its half width b = sqrt(r^2 - s^2/4), so 1 - (b/a)^2 = s/a: at
# MERGED_ELONGATION the centres are ~0.6 radius apart. A single marker measures 0.17 (median), two
# merged ones 0.61 (dense300's side view, 13 px markers). Such a detection is `merged`: its centre is
# neither particle's.
MERGED_ELONGATION = 0.4
# Two overlapping particles both partly covered (by the tool, by sand) leave a round union, wider than one
# particle: a blob whose half width exceeds MERGED_WIDTH times the median of the frame's blobs is merged
# too. On dense300 (frames 0-55, every 5th) no single marker of the side view measured that wide and 26 %
# of the merged pairs the elongation missed did; the front view's 7 px blobs: 0.2 % and none. The median
# needs MERGED_WIDTH_MIN_BLOBS blobs in the frame (a window round a few tracks is too few).
MERGED_WIDTH = 1.3
MERGED_WIDTH_MIN_BLOBS = 20
# A merged blob resolved into its two particles: two discs of the particles' edge radius r (the median of
# the frame's single blobs, MERGED_WIDTH_MIN_BLOBS of them at least, else the model's radius), their
# centres first at the blob's centre +- (a - r) along its long axis, then each fitted to the edge along
# the rays from its own centre that point away from the other (the outer half of its rim). Split when the
# two discs explain those edge points clearly better than one disc of r or of any radius (a particle nearer
# the camera is a larger disc, not two): rms at most SPLIT_RATIO of one disc's, and each disc's under
# SPLIT_RMS radii (three particles fit neither half), each seen along SPLIT_MIN_RAYS rays at least, the
# centres SPLIT_SEPARATION radii apart (nearer, the one behind is mostly hidden: one blob for any fit;
# dense300, both views, frames 0, 30, 60, 90, 101, 118: 190 of 517 merged blobs split, 189 with both
# halves within 3 px of two markers, 188 within 2 px). Otherwise it stays `merged`.
SPLIT_RATIO, SPLIT_RMS, SPLIT_MIN_RAYS, SPLIT_SEPARATION = 0.5, 0.12, 6, (0.8, 3.2)
SPLIT_SAME = 0.5  # radii: a half this near another detection is the same particle


@dataclass(frozen=True)
class ParticleModel:
    """The look of the seeded particle: what detect() matches."""

    weights: np.ndarray  # per channel: the projection on which the particle is brighter than its ring
    template: np.ndarray  # float32, odd square, rotationally symmetric
    diameter_px: float
    body: float  # the projected frame's mean over the body ring (BODY_RING), at the seed
    ring: float  # ... and just outside the particle
    patterned: bool
    min_confidence: float = MIN_CONFIDENCE
    body_min: float = BODY_MIN

    @property
    def half(self) -> int:
        return self.template.shape[0] // 2

    def describe(self) -> dict:
        return {"diameter_px": round(self.diameter_px, 2), "patterned": self.patterned,
                "template_px": int(self.template.shape[0]), "min_confidence": self.min_confidence}


def as_float(frame: np.ndarray) -> np.ndarray:
    img = np.asarray(frame)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    return img.astype(np.float32, copy=False)


def project(frame: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The frame along the model's colour direction (one float32 channel; the particle bright)."""
    img = as_float(frame)
    if img.ndim == 2:
        return img * float(weights.sum())
    if img.shape[2] == 1:
        return img[:, :, 0] * float(weights.sum())
    out = cv2.transform(img, weights.reshape(1, -1).astype(np.float32))
    return out if out.ndim == 2 else out[:, :, 0]


def _radial_means(patch: np.ndarray, cx: float, cy: float, r_max: int) -> np.ndarray:
    """Mean of each channel of `patch` in 1 px rings round (cx, cy): shape (r_max + 1, channels)."""
    h, w = patch.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot(xx - cx, yy - cy)
    ring = np.clip(np.round(r).astype(int), 0, r_max + 1)
    flat = patch.reshape(h * w, -1)
    out = np.zeros((r_max + 1, flat.shape[1]))
    for k in range(r_max + 1):
        sel = ring.ravel() == k
        if sel.any():
            out[k] = flat[sel].mean(axis=0)
    return out


def learn_particle(frame: np.ndarray, x: float, y: float, diameter_px: float,
                   min_confidence: float | None = None) -> ParticleModel:
    """The look of the particle of diameter `diameter_px` at (x, y) (a click: within a third of a
    diameter). Its centre is found first (the template learnt there matched round it, three times),
    as a radial profile learnt off-centre is blurred and matches nothing well. `min_confidence`:
    default MIN_CONFIDENCE for a patterned particle, SOLID_MIN_CONFIDENCE for a solid one."""
    for _ in range(3):
        model = _learn_at(frame, x, y, diameter_px, min_confidence)
        r = diameter_px / 3
        chan = project(frame, model.weights)
        res, x0, y0 = response(chan, model, (x - r, y - r, x + r + 1, y + r + 1))
        j, i = np.unravel_index(int(np.argmax(res)), res.shape)
        H, W = res.shape
        ic, jc = min(max(i, 1), W - 2), min(max(j, 1), H - 2)
        dx = float(_vertex(*(res[jc, ic - 1:ic + 2, None]))[0]) if W >= 3 else 0.0
        dy = float(_vertex(*(res[jc - 1:jc + 2, ic, None]))[0]) if H >= 3 else 0.0
        nx, ny = x0 + ic + dx, y0 + jc + dy
        if np.hypot(nx - x, ny - y) < 0.02:
            break
        x, y = nx, ny
    return _learn_at(frame, x, y, diameter_px, min_confidence)


def _learn_at(frame: np.ndarray, x: float, y: float, diameter_px: float,
              min_confidence: float | None) -> ParticleModel:
    img = as_float(frame)
    if img.ndim == 2:
        img = img[:, :, None]
    H, W = img.shape[:2]
    if not (np.isfinite(diameter_px) and 3.0 <= diameter_px <= 200.0):
        raise SandtrackError(f"particle diameter {diameter_px} px out of 3..200")
    r = diameter_px / 2
    R = int(np.ceil(r + 5))
    xi, yi = int(round(x)), int(round(y))
    if not (R <= xi < W - R and R <= yi < H - R):
        raise SandtrackError(f"the seed ({x:.1f}, {y:.1f}) is too near the image border to learn its look")
    patch = img[yi - R:yi + R + 1, xi - R:xi + R + 1]
    prof = _radial_means(patch, x - (xi - R), y - (yi - R), R)
    inner = int(np.floor(r * 0.8))
    disc = prof[:inner + 1].mean(axis=0)
    ring = prof[int(np.ceil(r + 1)):].mean(axis=0)
    diff = disc - ring
    norm = float(np.linalg.norm(diff))
    if norm < 1e-6 * max(float(np.abs(ring).max()), 1.0):
        raise SandtrackError("the seeded particle does not stand out from what surrounds it")
    weights = diff / norm
    prof1 = prof @ weights
    radii = np.arange(len(prof1))
    inner = prof1[radii <= PATTERN_RADIUS * r]
    patterned = bool(inner.max() - inner.min() > PATTERN_MIN * norm)
    reach = PATTERN_RADIUS * r if patterned else r + 1.0
    half = max(int(np.ceil(reach)), 1)
    yy, xx = np.mgrid[-half:half + 1, -half:half + 1]
    rr = np.hypot(xx, yy)
    template = np.interp(np.minimum(rr, reach), radii, prof1).astype(np.float32)
    if float(template.std()) < 1e-6 * norm:
        raise SandtrackError("the seeded particle shows no shape to match")
    body = float(prof1[(radii >= BODY_RING[0] * r) & (radii <= BODY_RING[1] * r)].mean())
    ring = float(prof1[radii >= r + 1.5].mean())
    if min_confidence is None:
        min_confidence = MIN_CONFIDENCE if patterned else SOLID_MIN_CONFIDENCE
    return ParticleModel(weights.astype(np.float32), template, float(diameter_px), body, ring, patterned,
                         min_confidence)


def response(chan: np.ndarray, model: ParticleModel, roi: tuple | None = None) -> tuple[np.ndarray, int, int]:
    """Normalised cross-correlation with the template at every pixel of the projected frame (or of
    roi = (x0, y0, x1, y1)): (map, x0, y0), map[j, i] being the score of a centre at (x0 + i, y0 + j)."""
    H, W = chan.shape
    x0, y0, x1, y1 = (0, 0, W, H) if roi is None else (max(int(roi[0]), 0), max(int(roi[1]), 0),
                                                      min(int(roi[2]), W), min(int(roi[3]), H))
    h = model.half
    # pad by the template's half size (edge pixels repeated) so that a centre near the border is scored
    a0, b0, a1, b1 = max(x0 - h, 0), max(y0 - h, 0), min(x1 + h, W), min(y1 + h, H)
    sub = chan[b0:b1, a0:a1]
    sub = cv2.copyMakeBorder(sub, h - (y0 - b0), h - (b1 - y1), h - (x0 - a0), h - (a1 - x1), cv2.BORDER_REPLICATE)
    res = cv2.matchTemplate(sub, model.template, cv2.TM_CCOEFF_NORMED)
    return res, x0, y0


def peaks(res: np.ndarray, model: ParticleModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local maxima of the response (at least NMS_DIAMETERS diameters apart) above the model's
    confidence: (x, y) sub-pixel in the map's pixels, and their scores."""
    k = max(3, int(round(NMS_DIAMETERS * model.diameter_px)) | 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    dil = cv2.dilate(res, kernel)
    ys, xs = np.nonzero((res >= dil) & (res >= model.min_confidence))
    if len(xs) == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    score = res[ys, xs]
    # plateaus (equal neighbours) give several maxima: keep the strongest within the NMS radius
    keep = _suppress(xs, ys, score, k / 2)
    xs, ys, score = xs[keep], ys[keep], score[keep]
    H, W = res.shape
    xc, yc = np.clip(xs, 1, W - 2), np.clip(ys, 1, H - 2)
    dx = _vertex(res[yc, xc - 1], res[yc, xc], res[yc, xc + 1])
    dy = _vertex(res[yc - 1, xc], res[yc, xc], res[yc + 1, xc])
    return xc + dx, yc + dy, score


def _vertex(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    den = a - 2 * b + c
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(den < 0, 0.5 * (a - c) / den, 0.0)
    return np.clip(d, -0.5, 0.5)


def _suppress(xs: np.ndarray, ys: np.ndarray, score: np.ndarray, radius: float) -> np.ndarray:
    """Indices of the peaks to keep: strongest first, none within `radius` of a kept one."""
    if len(xs) < 2:
        return np.arange(len(xs))
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.c_[xs, ys]).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return np.arange(len(xs))
    order = np.argsort(-score, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    drop = np.zeros(len(xs), bool)
    # a pair drops its weaker member unless that weaker one's stronger partner was itself dropped
    for i, j in sorted(pairs.tolist(), key=lambda p: min(rank[p[0]], rank[p[1]])):
        a, b = (i, j) if rank[i] < rank[j] else (j, i)
        if not drop[a]:
            drop[b] = True
    return np.nonzero(~drop)[0]


def detect(frame: np.ndarray, model: ParticleModel, roi: tuple | None = None) -> pd.DataFrame:
    """Every particle like the model's in the frame (or roi = (x0, y0, x1, y1) px), DETECTION_COLUMNS:
    sub-pixel centre, size (the model's diameter), contrast (its body against the background, as the
    seed's = 1), confidence (the normalised cross-correlation with the template, 0..1) and merged
    (a solid particle's blob that is two overlapping particles: see MERGED_ELONGATION)."""
    chan = project(frame, model.weights)
    res, x0, y0 = response(chan, model, roi)
    px, py, score = peaks(res, model)
    px, py = px + x0, py + y0
    body = body_levels(chan, model, px, py)
    merged = np.zeros(len(px), bool)
    if not len(px):
        keep = np.zeros(0, bool)
    elif model.patterned:
        keep = body.min(axis=1) >= model.body_min
    else:
        background = local_background(chan, model, px, py)
        keep = np.sort(body - background[:, None], axis=1)[:, SOLID_RAYS_MISSED] >= SOLID_MIN
        # (an edge between two levels of the projection, sand against a darker wall: half the rays at most)
        own = body[keep] - _ray_levels(chan, model, px[keep], py[keep], SOLID_BACKGROUND, BODY_RAYS)
        keep[keep] = (own >= SOLID_MIN).sum(axis=1) > BODY_RAYS // 2
        a, b, axis, _, own = blob_edges(chan, model, px[keep], py[keep], background[keep])
        with np.errstate(invalid="ignore"):
            merged[keep] = 1 - (b / a) ** 2 >= MERGED_ELONGATION
            if np.isfinite(b).sum() >= MERGED_WIDTH_MIN_BLOBS:
                merged[keep] |= b > MERGED_WIDTH * np.nanmedian(b)
        single = ~merged[keep] & np.isfinite(own)
        edge_r = float(np.median(own[single])) if single.sum() >= MERGED_WIDTH_MIN_BLOBS else model.diameter_px / 2
        out = pd.DataFrame({"x_px": px[keep], "y_px": py[keep], "size_px": model.diameter_px,
                            "contrast": body[keep].mean(axis=1), "confidence": score[keep].astype(float),
                            "merged": merged[keep], "split": False})
        pairs = split_merged(chan, model, px[keep], py[keep], merged[keep], a, axis, background[keep], edge_r)
        return _with_pairs(out, pairs, chan, model, res, x0, y0, edge_r)
    return pd.DataFrame({"x_px": px[keep], "y_px": py[keep], "size_px": np.full(int(keep.sum()), model.diameter_px),
                         "contrast": body[keep].mean(axis=1) if len(px) else np.zeros(0),
                         "confidence": score[keep].astype(float), "merged": merged[keep],
                         "split": np.zeros(int(keep.sum()), bool)})


def _with_pairs(det: pd.DataFrame, pairs: tuple, chan: np.ndarray, model: ParticleModel, res: np.ndarray,
                x0: int, y0: int, r: float) -> pd.DataFrame:
    """The detections with each resolved merged one replaced by its two particles (ordinary detections:
    the template's score at each centre, the body's level round it). A half within SPLIT_SAME radii of
    another detection is that detection (the blob's other particle was found on its own), or of another
    pair's half the same particle seen from both; a half nearer another detection than NMS_DIAMETERS
    (but not on it) leaves its pair unresolved."""
    from scipy.spatial import cKDTree

    idx, c = pairs
    if not len(idx):
        return det
    halves = c.reshape(-1, 2)
    others = np.delete(det[["x_px", "y_px"]].to_numpy(), idx, axis=0)
    d = cKDTree(others).query(halves)[0] if len(others) else np.full(len(halves), np.inf)
    same = d < SPLIT_SAME * r
    clear = ~((d >= SPLIT_SAME * r) & (d < NMS_DIAMETERS * 2 * r)).reshape(-1, 2).any(axis=1)
    emit = ~same & np.repeat(clear, 2)
    for a, b in sorted(cKDTree(halves).query_pairs(SPLIT_SAME * r)):
        if emit[a] and emit[b] and a // 2 != b // 2:
            emit[b] = False
    xy = halves[emit]
    H, W = res.shape
    i = np.clip(np.round(xy[:, 0] - x0).astype(int), 0, W - 1)
    j = np.clip(np.round(xy[:, 1] - y0).astype(int), 0, H - 1)
    found = pd.DataFrame({"x_px": xy[:, 0], "y_px": xy[:, 1], "size_px": model.diameter_px,
                          "contrast": body_levels(chan, model, xy[:, 0], xy[:, 1]).mean(axis=1),
                          "confidence": res[j, i].astype(float), "merged": False, "split": True})
    return pd.concat([det.drop(det.index[idx[clear]]), found], ignore_index=True)


def split_merged(chan: np.ndarray, model: ParticleModel, x: np.ndarray, y: np.ndarray, merged: np.ndarray,
                 a: np.ndarray, axis: np.ndarray, background: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """The merged blobs that are clearly two overlapping discs of radius r (see SPLIT_RATIO): their
    indices and the two centres of each, shape (k, 2, 2). a, axis: the blob's half length and long
    axis' angle (blob_edges), background: its local background."""
    idx = np.flatnonzero(merged & np.isfinite(a))
    if not len(idx):
        return idx, np.zeros((0, 2, 2))
    c, rms1, rms2, n = two_disc_fit(chan, model, x[idx], y[idx], a[idx], axis[idx], background[idx], r)
    s = np.hypot(c[:, 0, 0] - c[:, 1, 0], c[:, 0, 1] - c[:, 1, 1])
    pooled = np.sqrt((np.nan_to_num(rms2) ** 2 * n).sum(axis=1) / np.maximum(n.sum(axis=1), 1))
    ok = ((pooled <= SPLIT_RATIO * rms1) & (np.fmax(*rms2.T) <= SPLIT_RMS * r) & (n.min(axis=1) >= SPLIT_MIN_RAYS)
          & (s >= SPLIT_SEPARATION[0] * r) & (s <= SPLIT_SEPARATION[1] * r))
    return idx[ok], c[ok]


def two_disc_fit(chan: np.ndarray, model: ParticleModel, x: np.ndarray, y: np.ndarray, a: np.ndarray,
                 axis: np.ndarray, background: np.ndarray, r: float, rounds: int = 2) -> tuple[np.ndarray, ...]:
    """Two discs of radius r for each blob: centres first at (x, y) +- (a - r) along the axis, then each
    fitted to the blob's edge along the rays from its own centre that point away from the other's (the
    outer half of its rim), `rounds` times. Returns the centres (k, 2, 2), the rms distance of all those
    edge points to one disc of radius r fitted to them, the same to each disc of its own half (k, 2) and
    each disc's count of edge points (k, 2)."""
    rays = 2 * BODY_RAYS
    ang = np.linspace(0, 2 * np.pi, rays, endpoint=False)
    off = np.maximum(a - r, 0.25 * r)
    ux, uy = np.cos(axis), np.sin(axis)
    c = np.stack([np.stack([x + off * ux, y + off * uy], 1), np.stack([x - off * ux, y - off * uy], 1)], 1)
    for _ in range(rounds):
        ex, ey, w = [], [], []
        both = blob_edges(chan, model, c[:, :, 0].T.ravel(), c[:, :, 1].T.ravel(), np.tile(background, 2))[3]
        for d in range(2):
            cx, cy = c[:, d, 0], c[:, d, 1]
            rho = both[d * len(x):(d + 1) * len(x)]
            out_x, out_y = cx - c[:, 1 - d, 0], cy - c[:, 1 - d, 1]
            outward = np.cos(ang)[None] * out_x[:, None] + np.sin(ang)[None] * out_y[:, None] > 0
            wd = np.isfinite(rho) & outward
            rho = np.where(wd, rho, 0)
            ex.append(cx[:, None] + rho * np.cos(ang)[None])
            ey.append(cy[:, None] + rho * np.sin(ang)[None])
            w.append(wd)
        fits = [_fit_discs(ex[d], ey[d], w[d], c[:, d, 0].copy(), c[:, d, 1].copy(), r) for d in range(2)]
        c = np.stack([np.stack([f[0], f[1]], 1) for f in fits], 1)
    n = np.stack([w[0].sum(axis=1), w[1].sum(axis=1)], 1)
    rms2 = np.stack([fits[0][2], fits[1][2]], 1)
    ax, ay, aw = np.hstack(ex), np.hstack(ey), np.hstack(w)
    rms1 = np.fmin(_fit_discs(ax, ay, aw, c[:, :, 0].mean(axis=1), c[:, :, 1].mean(axis=1), r)[2],
                   _circle_rms(ax, ay, aw))
    return c, rms1, rms2, n


def _circle_rms(ex: np.ndarray, ey: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per row: the rms distance of the edge points (ex, ey) where w to the circle of any radius fitted
    to them (algebraic fit): one particle nearer the camera than the rest is a larger disc, not two."""
    wf = w.astype(float)
    A = np.stack([ex, ey, np.ones_like(ex)], axis=2) * wf[..., None]
    z = -(ex ** 2 + ey ** 2) * wf
    ata = np.einsum("kni,knj->kij", A, A) + 1e-9 * np.eye(3)
    sol = np.linalg.solve(ata, np.einsum("kni,kn->ki", A, z)[..., None])[..., 0]
    cx, cy = -sol[:, 0] / 2, -sol[:, 1] / 2
    R = np.sqrt(np.maximum(cx ** 2 + cy ** 2 - sol[:, 2], 0))
    d = np.hypot(ex - cx[:, None], ey - cy[:, None]) - R[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(((d * wf) ** 2).sum(axis=1) / wf.sum(axis=1))


def _fit_discs(ex: np.ndarray, ey: np.ndarray, w: np.ndarray, cx: np.ndarray, cy: np.ndarray, r: float,
               iters: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row: the centre of the circle of radius r nearest (least squares, Gauss-Newton from (cx, cy))
    to the edge points (ex, ey) where w; and the rms distance of those points to it (nan without any)."""
    wf = w.astype(float)
    for _ in range(iters):
        dx, dy = ex - cx[:, None], ey - cy[:, None]
        d = np.maximum(np.hypot(dx, dy), 1e-6)
        e = (d - r) * wf
        jx, jy = -dx / d * wf, -dy / d * wf
        a11, a12, a22 = (jx * jx).sum(1) + 1e-6, (jx * jy).sum(1), (jy * jy).sum(1) + 1e-6
        b1, b2 = (jx * e).sum(1), (jy * e).sum(1)
        det = a11 * a22 - a12 * a12
        cx = cx - (a22 * b1 - a12 * b2) / det
        cy = cy - (a11 * b2 - a12 * b1) / det
    d = np.hypot(ex - cx[:, None], ey - cy[:, None])
    cnt = wf.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt((((d - r) * wf) ** 2).sum(1) / cnt)
    return cx, cy, rms


def body_levels(chan: np.ndarray, model: ParticleModel, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per centre and ray: the projected frame's mean over the body ring, 0 = the seed's surroundings,
    1 = the seed's body; shape (len(x), BODY_RAYS)."""
    return _ray_levels(chan, model, x, y, BODY_RING, BODY_RAYS)


def local_background(chan: np.ndarray, model: ParticleModel, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Per centre: its surroundings' level on body_levels' scale (the darker quarter of 2 * BODY_RAYS
    rays over SOLID_BACKGROUND radii; brighter neighbours there are other particles)."""
    return np.percentile(_ray_levels(chan, model, x, y, SOLID_BACKGROUND, 2 * BODY_RAYS), 25, axis=1)


def _ray_levels(chan: np.ndarray, model: ParticleModel, x: np.ndarray, y: np.ndarray, ring: tuple,
                rays: int) -> np.ndarray:
    if len(x) == 0:
        return np.zeros((0, rays))
    r = model.diameter_px / 2
    ang = np.linspace(0, 2 * np.pi, rays, endpoint=False)
    rad = np.linspace(ring[0] * r, ring[1] * r, 5)
    dx = (np.cos(ang)[:, None] * rad[None, :]).astype(np.float32)
    dy = (np.sin(ang)[:, None] * rad[None, :]).astype(np.float32)
    mx = (np.asarray(x, np.float32)[:, None, None] + dx[None]).reshape(len(x), -1)
    my = (np.asarray(y, np.float32)[:, None, None] + dy[None]).reshape(len(x), -1)
    # cv2.remap takes maps of fewer than 32767 rows: thousands of candidates in a 1080p frame go in slices
    vals = np.concatenate([cv2.remap(chan, mx[i:i + REMAP_ROWS], my[i:i + REMAP_ROWS], cv2.INTER_LINEAR,
                                     borderMode=cv2.BORDER_REPLICATE) for i in range(0, len(x), REMAP_ROWS)])
    level = vals.reshape(len(x), rays, -1).mean(axis=2)
    return (level - model.ring) / (model.body - model.ring)


def blob_axes(chan: np.ndarray, model: ParticleModel, x: np.ndarray, y: np.ndarray,
              background: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per centre: the half lengths of the bright blob round it along its longest and its shortest
    axis (px) and the longest axis' angle (blob_edges)."""
    return blob_edges(chan, model, x, y, background)[:3]


def blob_edges(chan: np.ndarray, model: ParticleModel, x: np.ndarray, y: np.ndarray,
               background: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per centre: the half lengths of the bright blob round it along its longest and its shortest
    axis (px), the longest axis' angle, the edge's distance along each of 2 * BODY_RAYS rays (inf: no
    edge) and the blob's own radius (the median ray). Along each ray the blob's edge is where the level
    first falls below half way from `background` to the centre's own body level; a ray that runs on
    into a touching neighbour (no edge within EDGE_REACH of the blob's median radius) leaves its axis out."""
    n, rays = len(x), 2 * BODY_RAYS
    if n == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0), np.zeros((0, rays)), np.zeros(0)
    r = model.diameter_px / 2
    rad = np.arange(0.4 * r, EDGE_REACH * SIZE_SLACK * r + 0.25, 0.25, dtype=np.float32)
    ang = np.linspace(0, 2 * np.pi, rays, endpoint=False)
    dx = (np.cos(ang)[:, None] * rad[None, :]).astype(np.float32)
    dy = (np.sin(ang)[:, None] * rad[None, :]).astype(np.float32)
    mx = (np.asarray(x, np.float32)[:, None, None] + dx[None]).reshape(n * rays, -1)
    my = (np.asarray(y, np.float32)[:, None, None] + dy[None]).reshape(n * rays, -1)
    vals = cv2.remap(chan, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(n, rays, -1)
    level = (vals - model.ring) / (model.body - model.ring)
    body = np.median(level[:, :, :2], axis=(1, 2))
    half = 0.5 * (body + background)
    below = level < half[:, None, None]
    first = np.argmax(below, axis=2)
    found = below.any(axis=2)
    k = np.clip(first, 1, len(rad) - 1)
    lv = np.take_along_axis(level, k[..., None], 2)[..., 0]
    lp = np.take_along_axis(level, (k - 1)[..., None], 2)[..., 0]
    h = half[:, None]
    frac = np.clip((lp - h) / np.maximum(lp - lv, 1e-6), 0, 1)
    rho = np.where(found, rad[k - 1] + frac * (rad[1] - rad[0]), np.inf)
    # the particle's own radius (the median ray: a seed's box may misjudge the size by a third)
    own = np.median(np.minimum(rho, rad[-1]), axis=1)
    rho[rho > EDGE_REACH * own[:, None]] = np.inf
    width = rho[:, :rays // 2] + rho[:, rays // 2:]  # (n, axes)
    valid = np.isfinite(width)
    long_w = np.where(valid, width, -np.inf)
    major = np.argmax(long_w, axis=1)
    a = long_w[np.arange(n), major] / 2
    perp = (major + rays // 4) % (rays // 2)
    bw = width[np.arange(n), perp]
    bmin = np.where(valid, width, np.inf).min(axis=1)
    b = np.where(np.isfinite(bw), bw, bmin) / 2
    a = np.where(valid.any(axis=1), a, np.nan)
    b = np.where(valid.any(axis=1), b, np.nan)
    return a, b, ang[major], rho, own
