"""Missed markers among touching lookalikes (a dense layer): carried with the layer, given back by
one assignment of all of them to the layer's beads, measured again at their highlight, or, after a
patch of the layer was hidden a while, found again as a whole (`register`).

Identical touching beads cannot be told apart by how they look, only by where they are. The sand
carries a layer's beads together a few px per frame, and a bead's shading and highlight move with it
even where its outline is pressed against its neighbours': a bead the tracker missed is moved each
frame by the image motion around it (`flowed`: pyramidal Lucas-Kanade, checked by tracking back, at
most a radius per frame), else by the median move of the measured markers near it (`carried`; with
fewer than two of them, where it went is not known any more: it stays flagged until the operator
places it). The beads detected in the frame (detection.py: every bead like the marker, touching ones
split) that no tracked marker explains are then assigned to the missed markers at once (Hungarian
method on the distance). A pair counts only when it is unambiguous: the bead within `gate` of where
the marker was carried, and no other bead near that place nor other missed marker near that bead
within `margin` more than the pair's own distance. A carried marker no bead gave back is measured
again where its `highlight` gives a centre agreeing with its carried position (tracker.py).
Beads hidden together (under the tool) while the layer moved on have no motion measured at all: the
patch they formed is matched to the beads no track explains by one affine map of the patch, and
only where the patch's outline tells the map apart from the same map shifted by a bead; the beads
measured around the patch were carried with it (`anchor_misfit`): a map that misplaces them is the
patch shifted onto lookalikes no track follows, and a map they pin needs no more than a few pairs (the
first beads out from under the tool, a column along its edge, are carried by the similarity along
that line: `_fit_map`). The tool stretches the layer more near it than away from it: each bead is
then placed by the map of the pairs and anchors nearest it (`_placed_locally`). A lost bead whose
neighbours are measured again is carried by the affine map of their moves since they were last
measured together (`moved_with`). A bead given back is measured by its own outline (its template, cut
among its old neighbours, may no longer fit it) or, where its outline is pressed against its
neighbours', by its highlight. Anything else stays flagged for the operator.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

BODY_RING = 0.6  # radii: a bead's body is read on this circle around its centre (inside its rim's blur)
BODY_RING_SAMPLES = 16
MIN_NEIGHBOURS = 2  # measured neighbours a missed marker's carried position needs
FLOW_BACK_PX = 0.3  # a bead's image motion is trusted when tracking it back lands within this of its start
FLOW_MAX_MOVE = 1.0  # a bead's move per frame, in radii, beyond which the image motion is not the layer's
FLOW_LEVELS = 2  # pyramid levels of the image motion (a layer moves a few px per frame, a bead is ~15 px)
COLLINEAR = 0.25  # points whose spread across their line is under this share of it along it lie on a line
MIN_ANCHORS = 3  # measured beads around a lost one that carry it (an affine map of their moves)
MIN_GROUP = 4  # lost beads (and pairs) a registration of a hidden patch of the layer needs
# Lost beads a registration takes at most: its hypotheses grow as the patch's square and each is
# refined by assignments of the whole patch (32 touching beads: ~1 s; 81: ~11 s). A larger hidden
# patch stays lost (flagged) rather than stall the run.
MAX_GROUP = 32
REGISTER_MARGIN = 0.85  # a registration's score must be under this share of any other pairing's
FIT_FLOOR_PX = 0.02  # per bead: no bead is placed closer than this, so scores below it tell nothing apart
# A packing of identical beads looks the same turned by 60 degrees: a hidden patch is taken as turned by
# less than half that (the smallest turn that explains it).
MAX_TURN_DEG = 30.0
# Touching beads are not pressed closer together (a little, in the image, where the layer tilts) and a carried
# patch is stretched less than twice (the stretch at which a packing maps onto itself, every other bead):
# the scale of a registration's map along any direction lies between these.
MIN_STRETCH, MAX_STRETCH = 0.7, 1.8


def flowed(prev_bgr: np.ndarray, cur_bgr: np.ndarray, points: np.ndarray, radius: float) -> np.ndarray:
    """Positions (n, 2) of `points` of the previous frame moved by the image motion around them
    (pyramidal Lucas-Kanade on the brightness in a window of a bead's size: the shading and highlight
    of a bead move with it even where its outline is pressed against its neighbours'); NaN where the
    motion is not clear (too little texture, tracking the point back does not land on its start, or a
    move of more than FLOW_MAX_MOVE radii)."""
    pts = np.asarray(points, float).reshape(-1, 2)
    out = np.full_like(pts, np.nan)
    ok = np.isfinite(pts).all(axis=1)
    if not ok.any() or prev_bgr.shape != cur_bgr.shape:
        return out
    H, W = cur_bgr.shape[:2]
    pad = int(4 * radius) + 8
    x0, y0 = max(int(pts[ok, 0].min()) - pad, 0), max(int(pts[ok, 1].min()) - pad, 0)
    x1, y1 = min(int(pts[ok, 0].max()) + pad + 1, W), min(int(pts[ok, 1].max()) + pad + 1, H)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return out
    a, b = _grey(prev_bgr[y0:y1, x0:x1]), _grey(cur_bgr[y0:y1, x0:x1])
    p0 = (pts[ok] - (x0, y0)).astype(np.float32).reshape(-1, 1, 2)
    win = max(2 * int(round(radius)) + 1, 9)
    kw = dict(winSize=(win, win), maxLevel=FLOW_LEVELS,
              criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, **kw)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, None, **kw)
    good = (st1.ravel() == 1) & (st2.ravel() == 1) & \
        (np.hypot(*(back - p0).reshape(-1, 2).T) <= FLOW_BACK_PX)
    moved = p1.reshape(-1, 2).astype(float) + (x0, y0)
    # (the layer moves a few px per frame; what moves faster is something else: the tool over a bead)
    good &= np.hypot(*(moved - pts[ok]).T) <= FLOW_MAX_MOVE * radius
    moved[~good] = np.nan
    out[ok] = moved
    return out


def highlight(frame_bgr: np.ndarray, x: float, y: float, reach: float) -> tuple[float, float] | None:
    """Sub-pixel position of the brightest point (brightness smoothed over a pixel) within `reach` px of
    (x, y): a bead's highlight, the reflection of the light on a smooth sphere, sits at a fixed offset
    from its centre (the light and the view do not change), also where the bead's outline is pressed
    against its neighbours' or partly behind them. None when the brightest point lies on the edge of the
    search (no highlight of its own there) or near the image's edge."""
    R = int(math.ceil(reach)) + 1
    m = R + 3
    H, W = frame_bgr.shape[:2]
    ix, iy = int(round(x)), int(round(y))
    if ix - m < 0 or iy - m < 0 or ix + m + 1 > W or iy + m + 1 > H:
        return None
    g = cv2.GaussianBlur(_grey(frame_bgr[iy - m:iy + m + 1, ix - m:ix + m + 1]).astype(np.float32), (0, 0), 1.0)
    yy, xx = np.mgrid[-m:m + 1, -m:m + 1]
    inside = np.hypot(xx + ix - x, yy + iy - y) <= reach
    k = int(np.argmax(np.where(inside, g, -np.inf)))
    py, px = divmod(k, g.shape[1])
    edge = np.hypot(px - m + ix - x, py - m + iy - y) > reach - 1.0
    c, l, r_, u, d = g[py, px], g[py, px - 1], g[py, px + 1], g[py - 1, px], g[py + 1, px]
    if edge or c <= max(l, r_, u, d) - 1e-6:
        return None
    dx = 0.5 * (l - r_) / (l - 2 * c + r_) if l - 2 * c + r_ < 0 else 0.0
    dy = 0.5 * (u - d) / (u - 2 * c + d) if u - 2 * c + d < 0 else 0.0
    return ix - m + px + float(dx), iy - m + py + float(dy)


def highlight_contrast(frame_bgr: np.ndarray, hx: float, hy: float, cx: float, cy: float, radius: float
                       ) -> float:
    """How far a highlight at (hx, hy) stands out of the body of a bead centred at (cx, cy): its brightness
    (smoothed over a pixel) less the median brightness on the circle of BODY_RING radii around the centre
    (the bead's dark body, away from its rim). A bead's own highlight stands far out of its body; the
    brightest point of a surface with no highlight on it (the tool over a hidden bead) stands out by its
    noise only. NaN near the image's edge."""
    H, W = frame_bgr.shape[:2]
    R = int(math.ceil(radius)) + 3
    ix, iy = int(round(cx)), int(round(cy))
    if ix - R < 0 or iy - R < 0 or ix + R + 1 > W or iy + R + 1 > H or abs(hx - cx) > R - 2 or abs(hy - cy) > R - 2:
        return float("nan")
    g = cv2.GaussianBlur(_grey(frame_bgr[iy - R:iy + R + 1, ix - R:ix + R + 1]).astype(np.float32), (0, 0), 1.0)
    a = np.linspace(0.0, 2.0 * math.pi, BODY_RING_SAMPLES, endpoint=False)
    rx = np.rint(cx - ix + R + BODY_RING * radius * np.cos(a)).astype(int)
    ry = np.rint(cy - iy + R + BODY_RING * radius * np.sin(a)).astype(int)
    peak = g[int(round(hy)) - iy + R, int(round(hx)) - ix + R]
    return float(peak - np.median(g[ry, rx]))


def _grey(bgr: np.ndarray) -> np.ndarray:
    img = np.ascontiguousarray(bgr)
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img


def carried(missed: np.ndarray, measured_from: np.ndarray, measured_to: np.ndarray, reach: float,
            min_neighbours: int = MIN_NEIGHBOURS) -> np.ndarray:
    """Positions (n, 2) of missed markers moved by the median move (to - from) of the measured markers
    within `reach` of them; NaN for a missed marker with fewer than `min_neighbours` of them (where
    the sand took it is not known)."""
    out = np.array(missed, dtype=float).reshape(-1, 2)
    if not len(out):
        return out
    measured_from = np.asarray(measured_from, float).reshape(-1, 2)
    moves = np.asarray(measured_to, float).reshape(-1, 2) - measured_from
    d = np.hypot(out[:, None, 0] - measured_from[None, :, 0], out[:, None, 1] - measured_from[None, :, 1])
    for i in range(len(out)):
        near = d[i] <= reach
        if near.sum() < min_neighbours:
            out[i] = np.nan
        else:
            out[i] += np.median(moves[near], axis=0)
    return out


def assign(markers: np.ndarray, beads: np.ndarray, gate: float, margin: float) -> tuple[dict, list]:
    """Missed markers (n, 2) to beads (m, 2): ({marker index: bead index} of the unambiguous pairs,
    [marker index] of markers with a bead in their gate but a rival as near)."""
    markers = np.asarray(markers, float).reshape(-1, 2)
    beads = np.asarray(beads, float).reshape(-1, 2)
    if not len(markers) or not len(beads):
        return {}, []
    d = np.hypot(markers[:, None, 0] - beads[None, :, 0], markers[:, None, 1] - beads[None, :, 1])
    d = np.where(np.isfinite(d), d, np.inf)
    big = 1e9
    rows, cols = linear_sum_assignment(np.where(d <= gate, d, big))
    pairs, ambiguous = {}, []
    for r, c in zip(rows, cols, strict=True):
        if d[r, c] > gate:
            continue
        limit = d[r, c] + margin
        rival_bead = np.delete(d[r], c).min(initial=np.inf) < limit
        rival_marker = np.delete(d[:, c], r).min(initial=np.inf) < limit
        if rival_bead or rival_marker:
            ambiguous.append(int(r))
        else:
            pairs[int(r)] = int(c)
    return pairs, ambiguous


def moved_with(old: np.ndarray, anchors_old: np.ndarray, anchors_now: np.ndarray, on_line_px: float | None = None
               ) -> tuple[np.ndarray, float] | None:
    """Where a bead that was at `old` (x, y) is now, from the beads around it then (`anchors_old` (k, 2))
    and now (`anchors_now`): the sand carries close beads alike (a smooth field), so the affine map of
    their moves (least squares) carries it too. Anchors nearly on a line do not tell the map across that
    line: they carry a bead within `on_line_px` of their line (None: none) by the similarity of their moves
    (a column of beads carries its own next bead), and no other. Returns (its position, the largest
    distance of an anchor from where the map puts it), or None with fewer than MIN_ANCHORS anchors or a
    bead off their line."""
    a_old = np.asarray(anchors_old, float).reshape(-1, 2)
    a_now = np.asarray(anchors_now, float).reshape(-1, 2)
    if len(a_old) < MIN_ANCHORS:
        return None
    if _on_a_line(a_old):
        if on_line_px is None:
            return None
        centre = a_old.mean(axis=0)
        along = np.linalg.svd(a_old - centre)[2][0]
        off = np.asarray(old, float) - centre
        if abs(off[0] * along[1] - off[1] * along[0]) > on_line_px:
            return None
    homog = np.c_[a_old, np.ones(len(a_old))]
    m = _fit_map(homog, a_now)
    residual = float(np.hypot(*(homog @ m - a_now).T).max())
    return np.r_[np.asarray(old, float), 1.0] @ m, residual


def packed_coverage(radius: float, at_least: float, rim_px: float = 1.5, slack: float = 0.18) -> float:
    """Marker coverage (in discs) a bead shows in the centroid's window (radius + rim_px) when six
    beads like it touch it all round: its own disc plus the six neighbours' slivers inside the window
    (a small bead's window holds relatively more of them), plus `slack` for the soft rims; never below
    `at_least`. More than that: a bead partly hidden behind or merged with another."""
    big = radius + rim_px
    d = 2.0 * radius
    a = big * big * math.acos((d * d + big * big - radius * radius) / (2 * d * big))
    b = radius * radius * math.acos((d * d + radius * radius - big * big) / (2 * d * radius))
    c = 0.5 * math.sqrt(max((-d + big + radius) * (d + big - radius) * (d - big + radius) * (d + big + radius), 0.0))
    return max(at_least, 1.0 + 6.0 * (a + b - c) / (math.pi * radius * radius) + slack)


def register(old: np.ndarray, beads: np.ndarray, radius: float, reach: float, margin: float = REGISTER_MARGIN,
             anchors: tuple | None = None) -> tuple[np.ndarray | None, dict]:
    """Where a group of lost beads went while hidden (under the tool), from where they were together
    (`old` (n, 2): their positions at one frame) and the unclaimed beads detected now (`beads`): the
    patch of layer they form was carried as a whole, stretched and sheared, so one affine map takes the
    group onto the beads. Hypotheses from every lost bead and each of its two nearest neighbours
    matched to two beads as far apart (at most `reach` px from where the first was; the margin below
    means something only when no pairing was left untried), each refined by alternating the assignment
    (Hungarian method, distances capped at a radius) and the least-squares affine map of the pairs
    within a radius (a similarity where they lie on a line: _fit_map), scored by the capped distances
    summed over the group. A map that mirrors the patch, turns it by MAX_TURN_DEG or more (a packing
    looks the same turned by 60 degrees) or scales it beyond MIN_STRETCH..MAX_STRETCH is no carrying
    of a packing. Beads as far apart now as the two lost ones were, stretched as much, start the
    hypotheses. A lattice of identical beads fits itself shifted by a bead almost as well, only the
    patch's outline tells: the best map counts only when it is pinned (_pinned: half the group paired
    within half a radius; with anchors, a few points off a line) and its score is below `margin` x that
    of every hypothesis pairing the group otherwise (fewer than half of the same pairs); and of its
    pairs, only those every hypothesis scoring within that margin agrees on. `anchors` ((then (k, 2),
    now (k, 2))): beads measured around the group then and now, carried with it: each map is fitted to
    them too and pays for each as for a lost bead (its distance from where the map puts it, capped at a
    radius), so a map shifted by a bead pays for all of them, and the best is refused when it misplaces
    any of them by more than a radius (half the pitch of the packing: anchor_misfit). Each lost bead is
    then placed by the map of the pairs and anchors nearest it (_placed_locally); one the patch's map
    left unpaired is paired there when within half a radius of a bead that no pair took, and no rival
    hypothesis within the margin pairs it or that bead otherwise. Returns (the group's positions
    (n, 2), {lost bead: bead} of those pairs), or (None, {})."""
    old = np.asarray(old, float).reshape(-1, 2)
    beads = np.asarray(beads, float).reshape(-1, 2)
    n = len(old)
    if not MIN_GROUP <= n <= MAX_GROUP or len(beads) < MIN_GROUP:
        return None, {}
    d_old = np.hypot(*(old[:, None] - old[None]).transpose(2, 0, 1))
    d_beads = np.hypot(*(beads[:, None] - beads[None]).transpose(2, 0, 1))
    homog = np.c_[old, np.ones(n)]
    fixed = _anchored(anchors)
    found: dict = {}  # pairs (old, bead) within half a radius -> (cost, positions)
    for i1 in range(n):
        for i2 in np.argsort(d_old[i1])[1:3]:
            span = d_old[i1, i2]
            a = complex(*(old[i2] - old[i1]))
            for j1 in np.nonzero(np.hypot(*(beads - old[i1]).T) <= reach)[0]:
                for j2 in np.nonzero((d_beads[j1] >= MIN_STRETCH * span) & (d_beads[j1] <= MAX_STRETCH * span))[0]:
                    if j2 == j1:
                        continue
                    s = complex(*(beads[j2] - beads[j1])) / a
                    at = (old - old[i1]) @ np.array([[s.real, s.imag], [-s.imag, s.real]]) + beads[j1]
                    cost, pairs, at, m = _refine(homog, at, beads, radius, fixed)
                    if not _carried_like(m):
                        continue
                    if pairs not in found or found[pairs][0] > cost:
                        found[pairs] = (cost, at, m)
    if not found:
        return None, {}
    ranked = sorted(found.items(), key=lambda kv: kv[1][0])
    best_pairs, (best, at, m) = ranked[0]
    if not _pinned(old[[i for i, _b in best_pairs]], n, anchors) or \
            (fixed is not None and anchor_misfit(m, *anchors) > radius):
        return None, {}
    rivals = []
    floor = FIT_FLOOR_PX * n  # fits this close are equally perfect: their ratio is rounding
    for pairs, (cost, _at, _m) in ranked[1:]:
        if best + floor < margin * (cost + floor):
            break
        if len(set(pairs) & set(best_pairs)) < 0.5 * len(best_pairs):
            return None, {}
        rivals.append(set(pairs))
    agreed = set(best_pairs).intersection(*rivals)
    # (a layer carried by the tool is not stretched alike all over the patch: each lost bead is placed again by
    # the map of the pairs and anchors nearest it; one the patch's map left unpaired is taken where no rival
    # pairing contradicts it)
    at = _placed_locally(old, at, best_pairs, beads, fixed)
    d = np.hypot(at[:, None, 0] - beads[None, :, 0], at[:, None, 1] - beads[None, :, 1])
    rows, cols = linear_sum_assignment(np.minimum(d, radius))
    paired, taken = {i for i, _b in best_pairs}, {b for _i, b in best_pairs}
    for i, b in zip(rows, cols, strict=True):
        if i not in paired and b not in taken and d[i, b] < 0.5 * radius \
                and not any(_contradicts(rival, i, b) for rival in rivals):
            agreed.add((int(i), int(b)))
    return at, dict(agreed)


def _contradicts(pairs: set, i: int, b: int) -> bool:
    """A pairing `pairs` gives lost bead i another bead, or bead b another lost bead."""
    return any((pi == i) != (pb == b) for pi, pb in pairs)


def _placed_locally(old: np.ndarray, at: np.ndarray, pairs: tuple, beads: np.ndarray, fixed: tuple | None
                    ) -> np.ndarray:
    """Each lost bead of `old` (n, 2) placed by the affine map of the MIN_GROUP or more points (the
    registration's pairs, the anchors `fixed`) nearest it where they were, as many as it takes for them not
    to lie on a line; where there are not enough of them, as `at` (the patch's map) placed it."""
    src = old[[i for i, _b in pairs]]
    dst = beads[[b for _i, b in pairs]]
    if fixed is not None:
        src, dst = np.r_[src, fixed[0][:, :2]], np.r_[dst, fixed[1]]
    out = np.array(at, float)
    if len(src) < MIN_GROUP:
        return out
    for i, p in enumerate(old):
        order = np.argsort(np.hypot(*(src - p).T))
        k = MIN_GROUP
        while k <= len(src) and _on_a_line(src[order[:k]]):
            k += 1
        if k > len(src):
            continue
        near = order[:k]
        m = _fit_map(np.c_[src[near], np.ones(k)], dst[near])
        out[i] = np.r_[p, 1.0] @ m
    return out


def _pinned(paired: np.ndarray, n: int, anchors: tuple | None) -> bool:
    """A registration pairing the lost beads at `paired` (k, 2) of a group of `n` is pinned down. Without
    anchors: by half the group at least (a lattice fits itself shifted by a bead; only a good part of the
    patch's outline tells them apart). With beads measured around the group (anchors: a map shifted by a
    bead misplaces them, and the caller refuses one that misplaces any by more than a radius): by
    MIN_GROUP pairs, or by MIN_GROUP points, pairs and anchors, not on a line (the map across the group
    measured by them)."""
    if anchors is None or not len(anchors[0]):
        return len(paired) >= max(MIN_GROUP, 0.5 * n)
    if len(paired) >= MIN_GROUP:
        return True
    points = np.r_[paired, np.asarray(anchors[0], float).reshape(-1, 2)]
    return len(paired) >= 1 and len(points) >= MIN_GROUP and not _on_a_line(points)


def _on_a_line(points: np.ndarray) -> bool:
    """Points (k, 2) whose spread across their line is under COLLINEAR of their spread along it."""
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return len(points) < 3 or spread[1] < COLLINEAR * spread[0]


def anchor_misfit(m: np.ndarray, anchors_old: np.ndarray, anchors_now: np.ndarray) -> float:
    """How far (px, the largest) the beads measured around a registered patch (`anchors_old` (k, 2) at
    the patch's frame, `anchors_now` now) lie from where the patch's map `m` (3, 2) puts them: the layer
    carried them with the patch, so a map shifted by a bead (a lattice fits itself shifted) misplaces them
    by as much. 0 without anchors."""
    a_old = np.asarray(anchors_old, float).reshape(-1, 2)
    if not len(a_old):
        return 0.0
    placed = np.c_[a_old, np.ones(len(a_old))] @ m
    return float(np.hypot(*(placed - np.asarray(anchors_now, float).reshape(-1, 2)).T).max())


def _carried_like(m: np.ndarray) -> bool:
    """The affine map `m` (3, 2) neither mirrors the group nor turns it by MAX_TURN_DEG or more (the rotation
    nearest its linear part), nor presses it below MIN_STRETCH or stretches it beyond MAX_STRETCH."""
    lin = m[:2].T
    if np.linalg.det(lin) <= 0:
        return False
    u, stretch, vt = np.linalg.svd(lin)
    if stretch.min() < MIN_STRETCH or stretch.max() > MAX_STRETCH:
        return False
    rot = u @ vt
    return abs(math.degrees(math.atan2(rot[1, 0], rot[0, 0]))) < MAX_TURN_DEG


def _anchored(anchors: tuple | None) -> tuple | None:
    """(homogeneous positions then (k, 3), positions now (k, 2)) of a registration's anchors; None without."""
    if anchors is None or not len(anchors[0]):
        return None
    then = np.asarray(anchors[0], float).reshape(-1, 2)
    return np.c_[then, np.ones(len(then))], np.asarray(anchors[1], float).reshape(-1, 2)


def _refine(homog: np.ndarray, at: np.ndarray, beads: np.ndarray, radius: float, fixed: tuple | None = None,
            rounds: int = 3):
    """(cost, pairs within half a radius, positions, map (3, 2)) of one registration hypothesis, refined
    (with the anchors `fixed` (_anchored) in the fit and in the cost)."""
    m = None
    for k in range(rounds + 1):
        d = np.hypot(at[:, None, 0] - beads[None, :, 0], at[:, None, 1] - beads[None, :, 1])
        capped = np.minimum(d, radius)
        rows, cols = linear_sum_assignment(capped)
        ok = d[rows, cols] < radius
        if k == rounds or ok.sum() < MIN_GROUP:
            break
        src, dst = homog[rows[ok]], beads[cols[ok]]
        if fixed is not None:
            src, dst = np.r_[src, fixed[0]], np.r_[dst, fixed[1]]
        m = _fit_map(src, dst)
        at = homog @ m
    pairs = tuple((int(r), int(c)) for r, c in zip(rows, cols, strict=True) if d[r, c] < 0.5 * radius)
    cost = float(capped[rows, cols].sum())
    if m is None:
        m = _fit_map(homog, at)
    if fixed is not None:
        cost += float(np.minimum(np.hypot(*(fixed[0] @ m - fixed[1]).T), radius).sum())
    return cost, pairs, at, m


def _fit_map(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The map (3, 2) taking `src` (homogeneous (k, 3)) to `dst` (k, 2) in least squares: affine, or where
    the points lie nearly on a line (a column of beads out from under the tool), the map across that
    line is not known and the similarity (turned and scaled alike) is taken."""
    if not _on_a_line(src[:, :2]):
        m, *_r = np.linalg.lstsq(src, dst, rcond=None)
        return m
    x, y = src[:, 0], src[:, 1]
    a = np.zeros((2 * len(src), 4))
    a[0::2] = np.c_[x, -y, np.ones_like(x), np.zeros_like(x)]
    a[1::2] = np.c_[y, x, np.zeros_like(x), np.ones_like(x)]
    (p, q, tx, ty), *_r = np.linalg.lstsq(a, dst.reshape(-1), rcond=None)
    return np.array([[p, q], [-q, p], [tx, ty]])
