"""One global assignment per frame: every track to at most one detection, "not seen" and "new
particle" as costed choices.

`assign(S, X, reach, det_xy, motion, missed)` gates every (track, detection) pair by the Mahalanobis
distance of the track's prediction, splits the gated graph into connected groups and solves each
group on its own (a group of one track and one detection needs no solver): the cost of a pair is its
squared Mahalanobis distance, of leaving a track unseen `gate_d2`, of leaving a detection to a new
particle 0. Then the margin rule for an unsure track (one that missed frames, or a new one not yet
confirmed: its gate is wide): it keeps its detection only when no other track reaches it almost as
cheaply and no unclaimed detection lies almost as near its prediction; and for every track: no other
track's prediction lies nearer the detection in pixels (whatever that track's gate: a bead that stopped
short of its track's gate is still that track's bead); otherwise it stays unseen (flagged), never
guessed. A track in doubt (its last detection was two merged particles, so it may sit on either)
takes a detection only when that one is clearly the nearest to its prediction: every other detection
lies at least `lead_px` farther. Before all that, a track whose detection lies within `rest_px` of its
prediction, clear of every other detection and track, takes it whatever its gate (`_at_rest`; only
the tracks `still`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .predict import Motion, mahalanobis

MARGIN_D2 = 4.0  # a coasting track's detection must be this much cheaper than any other explanation
REST_CLEAR = 3.0  # _at_rest: every other detection and track this many `rest_px` farther


def gated_pairs(S, X, reach, det_xy, motion: Motion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(track index, detection index, squared Mahalanobis distance) of every pair inside the gate."""
    if len(X) == 0 or len(det_xy) == 0:
        e = np.zeros(0, int)
        return e, e, np.zeros(0)
    hits = cKDTree(det_xy).query_ball_point(X[:, :2], reach)
    counts = np.fromiter((len(h) for h in hits), int, len(hits))
    ti = np.repeat(np.arange(len(X)), counts)
    dj = np.fromiter((j for h in hits for j in h), int, int(counts.sum()))
    d2 = mahalanobis(S, X, ti, det_xy[dj])
    ok = d2 <= motion.gate_d2
    return ti[ok], dj[ok], d2[ok]


def assign(S, X, reach, det_xy, motion: Motion, unsure: np.ndarray, doubt: np.ndarray | None = None,
           lead_px: float = 0.0, rest_px: float = 0.0,
           still: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per track: the detection index it takes (-1: not seen) and that pair's cost; per track also
    True where the margin rule withheld a detection (ambiguous)."""
    n_t, n_d = len(X), len(det_xy)
    taken = np.full(n_t, -1)
    cost = np.full(n_t, np.nan)
    ambiguous = np.zeros(n_t, bool)
    fixed = _at_rest(X, det_xy, rest_px, np.ones(n_t, bool) if still is None else still,
                     np.zeros(n_t, bool) if doubt is None else doubt)
    if len(fixed[0]):
        t_s, d_s = fixed
        taken[t_s] = d_s
        cost[t_s] = mahalanobis(S, X, t_s, det_xy[d_s])
        rest_t = np.setdiff1d(np.arange(n_t), t_s)
        rest_d = np.setdiff1d(np.arange(n_d), d_s)
        sub = assign(S[rest_t], X[rest_t], reach[rest_t], det_xy[rest_d], motion, unsure[rest_t],
                     None if doubt is None else doubt[rest_t], lead_px)
        got = sub[0] >= 0
        taken[rest_t[got]] = rest_d[sub[0][got]]
        cost[rest_t], ambiguous[rest_t] = sub[1], sub[2]
        return taken, cost, ambiguous
    ti, dj, d2 = gated_pairs(S, X, reach, det_xy, motion)
    if len(ti) == 0:
        return taken, cost, ambiguous
    graph = coo_matrix((np.ones(len(ti)), (ti, n_t + dj)), shape=(n_t + n_d, n_t + n_d))
    _, label = connected_components(graph, directed=False)
    tdeg = np.bincount(ti, minlength=n_t)
    ddeg = np.bincount(dj, minlength=n_d)
    single = (tdeg[ti] == 1) & (ddeg[dj] == 1)
    taken[ti[single]] = dj[single]
    cost[ti[single]] = d2[single]
    rest = ~single
    if rest.any():
        order = np.argsort(label[ti[rest]], kind="stable")
        rt, rd, rc = ti[rest][order], dj[rest][order], d2[rest][order]
        bounds = np.flatnonzero(np.diff(label[rt])) + 1
        for gt, gd, gc in zip(np.split(rt, bounds), np.split(rd, bounds), np.split(rc, bounds), strict=True):
            _solve_group(gt, gd, gc, motion.gate_d2, taken, cost)
    _margin(ti, dj, d2, taken, cost, unsure, ambiguous)
    _nearer_owner(X, det_xy, taken, cost, ambiguous)
    if doubt is not None:
        _clear_lead(X, det_xy, taken, cost, doubt, ambiguous, lead_px)
    return taken, cost, ambiguous


def _at_rest(X, det_xy, rest_px: float, still, doubt) -> tuple[np.ndarray, np.ndarray]:
    """(tracks, detections) paired at once, before the gates: the detection within `rest_px` of the track's
    prediction with every other detection and every other track's prediction REST_CLEAR * `rest_px`
    farther; tracks `still` and not in doubt only."""
    e = np.zeros(0, int)
    if rest_px <= 0 or len(X) < 2 or len(det_xy) < 2:
        return e, e
    dd, dk = cKDTree(det_xy).query(X[:, :2], k=2)
    td, tk = cKDTree(X[:, :2]).query(det_xy[dk[:, 0]], k=2)
    clear = REST_CLEAR * rest_px
    ok = ((dd[:, 0] <= rest_px) & (dd[:, 1] - dd[:, 0] >= clear) & (tk[:, 0] == np.arange(len(X)))
          & (td[:, 1] - td[:, 0] >= clear) & still & ~doubt)
    t = np.flatnonzero(ok)
    return t, dk[t, 0]


def _solve_group(gt, gd, gc, miss_cost: float, taken, cost) -> None:
    tracks, t_idx = np.unique(gt, return_inverse=True)
    dets, d_idx = np.unique(gd, return_inverse=True)
    nt, nd = len(tracks), len(dets)
    big = 1e9
    m = np.full((nt + nd, nd + nt), big)
    m[t_idx, d_idx] = gc
    m[np.arange(nt), nd + np.arange(nt)] = miss_cost  # track not seen
    m[nt + np.arange(nd), np.arange(nd)] = 0.0  # detection left to a new particle
    m[nt:, nd:] = 0.0
    rows, cols = linear_sum_assignment(m)
    for r, c in zip(rows, cols, strict=True):
        if r < nt and c < nd and m[r, c] < big:
            taken[tracks[r]] = dets[c]
            cost[tracks[r]] = m[r, c]


def _margin(ti, dj, d2, taken, cost, unsure, ambiguous) -> None:
    coasting = np.flatnonzero((taken >= 0) & unsure)
    if len(coasting) == 0:
        return
    claimed = np.zeros(int(dj.max()) + 1 if len(dj) else 0, bool)
    claimed[taken[taken >= 0]] = True
    for t in coasting:
        j, c = taken[t], cost[t]
        rival_track = (dj == j) & (ti != t) & (d2 < c + MARGIN_D2)
        # a detection nearer its prediction that another track took: the one it took is its second choice
        rival_det = (ti == t) & (dj != j) & (~claimed[dj] | (d2 < c)) & (d2 < c + MARGIN_D2)
        if rival_track.any() or rival_det.any():
            taken[t] = -1
            cost[t] = np.nan
            ambiguous[t] = True


def _nearer_owner(X, det_xy, taken, cost, ambiguous) -> None:
    """A track gives up a detection that lies nearer another track's prediction than its own: a sure track
    too, whose gate (3 px per frame of acceleration) reaches a neighbour's detection when its own particle
    is not detected, while the solver left that neighbour's new track (velocity unknown) another choice."""
    mine = np.flatnonzero(taken >= 0)
    if len(mine) == 0 or len(X) < 2:
        return
    z = det_xy[taken[mine]]
    own = np.hypot(*(z - X[mine, :2]).T)
    d, k = cKDTree(X[:, :2]).query(z, k=2)
    other = np.where(k[:, 0] == mine, d[:, 1], d[:, 0])
    drop = mine[other < own]
    taken[drop] = -1
    cost[drop] = np.nan
    ambiguous[drop] = True


def _clear_lead(X, det_xy, taken, cost, doubt, ambiguous, lead_px: float) -> None:
    """A track in doubt gives up its detection unless every other one lies `lead_px` farther from it."""
    mine = np.flatnonzero((taken >= 0) & doubt)
    if len(mine) == 0 or len(det_xy) < 2:
        return
    d, k = cKDTree(det_xy).query(X[mine, :2], k=2)
    own = np.hypot(*(det_xy[taken[mine]] - X[mine, :2]).T)
    second = np.where(k[:, 0] == taken[mine], d[:, 1], d[:, 0])
    drop = mine[second - own < lead_px]
    taken[drop] = -1
    cost[drop] = np.nan
    ambiguous[drop] = True
