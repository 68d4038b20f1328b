"""Gap closing for every-particle tracks of one camera: a track that ended (lost) and one that started a few
frames later where the first one's motion predicts it are one particle, joined only when nothing else
explains either as well (trackpy's `memory`, or the gap-closing step of a linking LAP, with the doubtful
cases left apart rather than guessed).

For each ended track, the started tracks whose first point lies within the gate of its prediction over
at most `max_gap` frames are its candidates: its last point + its last velocity x gap, and the started
one's first point - its first velocity x gap, each within the gate of the other's point (the gate:
GATE_DIAMETERS of a diameter, widened by GATE_PX_PER_FRAME per frame of gap). A piece seen once has no
known motion: it is joined on the other piece's, and two such pieces are never joined (a fast particle
may pass where another one was lost). It is joined to the earliest candidate, provided no other started
track lies within DOUBT x the gate of it at that frame or before (by any motion, or none), no later
candidate fits clearly better (by half a gate), and no other ended track might reach that start first.
A particle lost again and again (short pieces) is joined piece by piece, in time order, each joined
piece's motion then known from the one before it. Plain data: points in, chains of ids out; `gap_rows`
gives the points that flag the frames between two joined pieces.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

MEASURED = ("tracked", "manual")
MAX_GAP_FRAMES = 8  # the tracker coasts 3 frames before a track ends: a few frames beyond that
GATE_DIAMETERS = 0.15  # the prediction's reach, in particle diameters (at least MIN_GATE_PX)
MIN_GATE_PX = 1.5
GATE_PX_PER_FRAME = 0.25  # ... widened per frame of gap: a velocity known to a fraction of a pixel per frame
VELOCITY_POINTS = 4  # a piece's velocity at either end: over this many of its points (a last jump weighs less)
DOUBT = 3.0  # another piece this much further off than the gate still makes the join doubtful


def ends_and_starts(points: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Per track (marker) of one camera: its last measured point and frame, with its velocity there (px per
    frame, over its last VELOCITY_POINTS points; NaN for a track of one point: not known), and its first
    point and frame, with its velocity there (over its first points)."""
    p = points[points.status.isin(MEASURED) & points.x_px.notna() & points.y_px.notna()]
    p = p.sort_values(["marker", "frame"])
    g = p.groupby("marker")
    return _end(g.nth(-1), g.nth(list(range(-VELOCITY_POINTS, -1))).groupby("marker").nth(0)), \
        _end(g.nth(0), g.nth(list(range(1, VELOCITY_POINTS))).groupby("marker").nth(-1))


def _end(tip: pd.DataFrame, other: pd.DataFrame) -> pd.DataFrame:
    tip = tip.set_index("marker")
    other = other.set_index("marker").reindex(tip.index)
    dt = (tip.frame - other.frame).to_numpy(float)
    return pd.DataFrame({"frame": tip.frame.to_numpy(int), "x": tip.x_px.to_numpy(float),
                         "y": tip.y_px.to_numpy(float), "vx": (tip.x_px - other.x_px).to_numpy(float) / dt,
                         "vy": (tip.y_px - other.y_px).to_numpy(float) / dt}, index=tip.index)


def find_joins(points: pd.DataFrame, diameter_px: float, first_frame: int, last_frame: int,
               max_gap: int = MAX_GAP_FRAMES) -> tuple[list[tuple[int, int]], int]:
    """(ended id, started id) joins of one camera's tracks over frames first_frame..last_frame, and how many
    ended tracks had a candidate but were left apart (doubtful)."""
    ends, starts = ends_and_starts(points)
    ends = ends[ends.frame < last_frame]
    starts = starts[starts.frame > first_frame].sort_values("frame")
    reach = _Reach(starts, max(MIN_GATE_PX, GATE_DIAMETERS * diameter_px), max_gap)
    tips = {int(e): [int(f), x, y, vx, vy] for e, f, x, y, vx, vy in zip(
        ends.index, ends.frame, ends.x, ends.y, ends.vx, ends.vy, strict=True)}
    choice, claims_of, claims, doubtful = {}, {}, {}, {}
    taken: set[int] = set()

    def evaluate(e: int) -> None:
        for s in claims_of.pop(e, ()):
            claims[s].discard(e)
        choice[e], claims_of[e], doubtful[e] = reach.of(*tips[e], taken)
        for s in claims_of[e]:
            claims.setdefault(s, set()).add(e)

    for e in tips:
        evaluate(e)
    joins: list[tuple[int, int]] = []
    while True:
        made = [(e, s) for e, s in choice.items() if s is not None and s not in taken and claims.get(s) == {e}]
        if not made:
            break
        for e, s in made:
            joins.append((e, s))
            taken.add(s)
            choice[e] = None
        for e, s in made:
            tip = tips.get(s)
            if tip is not None and np.isnan(tip[3]) and tip[0] == int(starts.frame[s]):
                # a piece seen once, joined: its motion is known now, from the piece before it
                gap = tip[0] - tips[e][0]
                tip[3], tip[4] = (tip[1] - tips[e][1]) / gap, (tip[2] - tips[e][2]) / gap
                evaluate(s)
    return joins, sum(s is not None or doubtful[e] for e, s in choice.items())


class _Reach:
    """The started pieces an ended one may continue as (see the module docstring)."""

    def __init__(self, starts: pd.DataFrame, gate: float, max_gap: int):
        self.gate, self.doubt, self.max_gap = gate, DOUBT * gate, max_gap
        self.frame = starts.frame.to_numpy(int)
        self.xy = starts[["x", "y"]].to_numpy(float)
        self.v = starts[["vx", "vy"]].to_numpy(float)
        self.ids = starts.index.to_numpy(np.int64)

    def of(self, frame: int, x: float, y: float, vx: float, vy: float, taken: set) -> tuple[int | None, list, bool]:
        """(the started piece it continues as, or None; the pieces it might continue as, first in time; whether
        it was left apart as doubtful)."""
        lo = np.searchsorted(self.frame, frame, "right")
        hi = np.searchsorted(self.frame, frame + self.max_gap, "right")
        free = [k for k in range(lo, hi) if int(self.ids[k]) not in taken]
        if not free:
            return None, [], False
        k = np.array(free)
        f = self.frame[k]
        gap = (f - frame)[:, None]
        exy = np.array([x, y])
        ahead = np.hypot(*(self.xy[k] - (exy + np.array([vx, vy]) * gap)).T)  # NaN: speed not known
        back = np.hypot(*(self.xy[k] - self.v[k] * gap - exy).T)
        still = np.hypot(*(self.xy[k] - exy).T)
        with np.errstate(all="ignore"):
            # joined only on a known motion (either piece's own velocity; both must agree where both are
            # known): a piece seen once may be a fast particle passing where another one was lost
            d = np.fmax(ahead, back)
            d[np.isnan(d)] = np.inf
            maybe_d = np.fmin(np.fmin(ahead, back), still)  # anything that might be the particle
        maybe = np.flatnonzero(maybe_d <= self.doubt)
        if not len(maybe):
            return None, [], False
        # the pieces it would reach first (a later one is that piece's own next piece, not a rival for it)
        claimed = [int(self.ids[k[m]]) for m in maybe[f[maybe] == f[maybe].min()]]
        near = np.flatnonzero(d <= self.gate + GATE_PX_PER_FRAME * gap[:, 0])
        if not len(near):
            return None, claimed, False
        best = near[np.argmin(f[near])]
        if np.count_nonzero(f[maybe] <= f[best]) > 1 or np.any(d[near] < d[best] - self.gate / 2):
            return None, claimed, True  # another piece as near, or a later one that fits clearly better
        return int(self.ids[k[best]]), claimed, False


def chains(joins: list[tuple[int, int]]) -> list[list[int]]:
    """Joined pieces as chains of ids in time order (each piece at most once)."""
    nxt = dict(joins)
    has_prev = set(nxt.values())
    out = []
    for head in nxt:
        if head in has_prev:
            continue
        chain = [head]
        while chain[-1] in nxt:
            chain.append(nxt[chain[-1]])
        out.append(chain)
    return out


def pieces_of(points: pd.DataFrame) -> dict:
    """One camera's points by id, as gap_rows reads them: id -> (frames, measured, x, y, status) arrays."""
    p = points.sort_values(["marker", "frame"])
    frame, marker = p.frame.to_numpy(np.int64), p.marker.to_numpy(np.int64)
    x, y, status = p.x_px.to_numpy(float), p.y_px.to_numpy(float), p.status.to_numpy(object)
    measured = np.isin(status, MEASURED) & np.isfinite(x) & np.isfinite(y)
    cut = np.flatnonzero(np.diff(marker)) + 1
    return {int(marker[i]): (frame[i:j], measured[i:j], x[i:j], y[i:j], status[i:j])
            for i, j in zip(np.r_[0, cut], np.r_[cut, len(marker)], strict=True) if j > i}


def gap_rows(by_marker: dict, pieces: list[int], camera: str) -> tuple[list[tuple], list[tuple]]:
    """(rows to write, keys to delete) that make the pieces (ids of one camera, in time order, measured at no
    common frame; by_marker: `pieces_of` the camera's points) one track (once merged into the first id):
    each piece's rows after its last measured point and before the next piece's first become `occluded` (the
    coasting prediction kept, a `lost` one emptied), frames without a row get an empty `occluded` row, and
    rows at or after the next piece's first frame go (that piece has the particle from there). Rows are
    (frame, camera, marker, x, y, status, confidence, sd, score)."""
    writes, deletes = [], []
    for cur, nxt in zip(pieces[:-1], pieces[1:], strict=True):
        frames, measured, x, y, status = by_marker[cur]
        f_end = int(frames[measured].max())
        f_next = int(by_marker[nxt][0][by_marker[nxt][1]].min())
        deletes += [(int(f), camera, int(cur)) for f in frames[frames >= f_next]]
        have = {int(f): k for k, f in enumerate(frames) if f_end < f < f_next}
        for f in range(f_end + 1, f_next):
            k = have.get(f)
            coast = k is not None and status[k] == "occluded" and np.isfinite(x[k]) and np.isfinite(y[k])
            writes.append((f, camera, int(cur), float(x[k]) if coast else None, float(y[k]) if coast else None,
                           "occluded", None, None, None))
    return writes, deletes
