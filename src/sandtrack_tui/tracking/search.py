"""The step's first search: every track stepping this frame proposes its best match in its gate
(MarkerTrack.propose; a coasting one its pattern's return, MarkerTrack.pattern_return), and a match
among touching markers is kept only when it is clearly this marker's (Crowded.reject)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from . import crowd as crowd_rules
from .matcher import Match, Proposal
from .tracker import MarkerTrack


def gated(cam, j, img, tracks, props, crowded: Crowded) -> dict:
    """Each track's match in its gate into `props` ((marker, camera) -> Proposal); returns the tracks whose
    predictions touch (Crowded.neighbours), as they were before the search."""
    near = crowded.neighbours(tracks)
    for t in tracks:
        m = t.pattern_return(img, j) if t.coasting and not t.awaiting_outline else t.propose(img, j)
        if m is not None and crowded.reject(t, m, near.get(id(t), ())):
            m = None
        if m is not None:
            props[(t.marker, cam)] = Proposal(m)
    return near


@dataclass(frozen=True)
class Crowded:
    """When markers touch, and which of their matches are kept."""

    factor: float = 1.4  # tracks closer than this x (r1 + r2) are "touching"
    min_score: float = 0.8
    max_colour: float = 1.4

    def neighbours(self, tracks) -> dict:
        """For each track, the other tracks whose predictions touch it: id(track) -> [(track, xy)]."""
        if len(tracks) < 2:
            return {}
        pts = [(*t.kf.xy, t.model.radius) for t in tracks]
        near: list[list[int]] = [[] for _ in tracks]  # neighbour indices, ascending
        for i, k in touching_pairs(pts, lambda ri, rk: self.factor * (ri + rk)):
            near[i].append(k)
            near[k].append(i)
        return {id(tracks[i]): [(tracks[k], pts[k][:2]) for k in ks] for i, ks in enumerate(near) if ks}

    def reject(self, t: MarkerTrack, m: Match, neighbours) -> bool:
        """Markers touching each other: their discs merge, the centroid and the NCC peak both lie.
        Keep a match only if it is clearly this marker's: nearer to this track's prediction than to
        the neighbour's, and either centred on its own share of the blob (the matcher split it from
        the touching markers) or of a high score and not a merged blob. Otherwise the track coasts
        (honestly)."""
        if not neighbours:
            return False
        px, py = t.kf.xy
        own = math.hypot(m.x - px, m.y - py)
        for _o, q in neighbours:
            if math.hypot(m.x - q[0], m.y - q[1]) < own:
                return True
        if t.model.crowd and m.outline:
            # (centred on its own outline: the coverage around it holds the rims of its touching neighbours)
            return m.score < self.min_score or m.colour_frac > crowd_rules.packed_coverage(
                t.model.radius, self.max_colour)
        if m.touching and m.used_centroid:
            return m.colour_frac > self.max_colour
        return m.score < self.min_score or m.colour_frac > self.max_colour



def touching_pairs(pts, limit) -> list[tuple[int, int]]:
    """Index pairs (i, k), i < k, in ascending order, of points (x, y, r) closer than limit(ri, rk)
    (a function growing with both radii). Swept along x: a camera's markers are mostly far apart,
    so few pairs are looked at. Plain floats: a handful of points, where numpy's per-call cost
    would dominate."""
    order = sorted((i for i, p in enumerate(pts) if math.isfinite(p[0]) and math.isfinite(p[1])),
                   key=lambda i: pts[i][0])
    if len(order) < 2:
        return []
    r_max = max(pts[i][2] for i in order)
    reach = limit(r_max, r_max)
    pairs = []
    for a, i in enumerate(order):
        xi, yi, ri = pts[i]
        for k in order[a + 1:]:
            xk, yk, rk = pts[k]
            if xk - xi >= reach:
                break
            lim = limit(ri, rk)
            if xk - xi < lim and abs(yk - yi) < lim and math.hypot(xk - xi, yk - yi) < lim:
                pairs.append((i, k) if i < k else (k, i))
    pairs.sort()
    return pairs

