"""Every-particle tracks of two calibrated cameras paired across the views: a track of the first camera and
one of the second are one particle when their points lie on each other's epipolar lines over enough frames
measured together (the second camera's points taken at the first's frame times: sync offset respected),
and no other track of either view lies on them as well. A pair is made from measured points only; a track
that might be the particle (a rival) is found from its detections, flagged ones too: a marker whose
detections were merged with a neighbour's is still there, and two particles at rest on one epipolar
line (one track in each view, each view's track of the other particle flagged) would otherwise pair as a
ghost.

The idea of the seeded crowd pairing (pairing.py), on whole tracks at once: per frame, every tracked point of
one view against every one of the other; a pair of tracks counts the frames both were measured and the frames
their points left each other's lines. Tracks are grouped by the pairs that stayed on the line (`on_line`) or
may have (`rival`: too few frames off to tell them apart); a group is one particle when all its links are
on the line and its tracks of one view never overlap in time (pieces of one particle's track, split by a gap);
any other group stays unpaired (`ambiguous`). Plain data in and out: points DataFrames, groups of ids.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .gaps import MEASURED

DETECTED = "detected"  # measured points and the detections the tracker flagged (merged: a score, no coasting)
PAIR_MIN_FRAMES = 10  # frames measured together before two tracks may be called one particle
OFF_LINE_SHARE = 0.05  # an on-line pair may leave the line at this share of its frames (a merged detection)
# Another track is told apart when it left the line at PAIR_BREAKS frames or more, and at this share of
# the frames measured together: a particle beside the line, not one measured badly once or twice.
PAIR_BREAKS = 3
APART_SHARE = 0.2
RIVAL_MIN_FRAMES = PAIR_BREAKS  # fewer frames together tell nothing either way


@dataclass
class Pairing:
    """groups: each particle's tracks {camera: [ids in time order]} (both cameras); ambiguous: track ids (per
    camera) left unpaired because another track lay on the line as well; lonely: ids with enough points but
    no track of the other view on their line."""
    groups: list[dict] = field(default_factory=list)
    ambiguous: dict = field(default_factory=dict)
    lonely: dict = field(default_factory=dict)


def measured(points: pd.DataFrame, camera: str, statuses: tuple | str = MEASURED) -> pd.DataFrame:
    """A camera's points with a position, of `statuses` (DETECTED: measured, or flagged with a detector's
    score: a detection of merged particles, not a coasting prediction)."""
    p = points[points.camera == camera]
    if statuses == DETECTED:
        scored = p.score.notna() if "score" in p else np.zeros(len(p), bool)
        p = p[p.status.isin(MEASURED) | scored]
    else:
        p = p[p.status.isin(statuses)]
    return p[np.isfinite(p.x_px.to_numpy(float)) & np.isfinite(p.y_px.to_numpy(float))]


def at_reference_times(points_b: pd.DataFrame, frames_b_at: np.ndarray, ref_frames: np.ndarray) -> dict:
    """Camera b's measured points at each reference frame's time: {ref frame: (ids, xy)}. frames_b_at: b's
    continuous frame index at each of ref_frames. Between two frames of b, linear between the track's two
    points (both measured), never across a gap."""
    key = points_b.marker.to_numpy(np.int64) * (1 << 32) + points_b.frame.to_numpy(np.int64)
    order = np.argsort(key)
    key = key[order]
    xy = points_b[["x_px", "y_px"]].to_numpy(float)[order]
    by_frame = {int(f): g.marker.to_numpy(np.int64) for f, g in points_b.groupby("frame")}
    out = {}
    for f, u in zip(ref_frames, frames_b_at, strict=True):
        if not np.isfinite(u):
            continue
        j0 = int(np.floor(u + 1e-6))
        w = u - j0
        ids = by_frame.get(j0)
        if ids is None:
            continue
        if w > 1e-6:
            ids = np.intersect1d(ids, by_frame.get(j0 + 1, np.zeros(0, np.int64)))
            if not len(ids):
                continue
            p0 = xy[np.searchsorted(key, ids * (1 << 32) + j0)]
            p1 = xy[np.searchsorted(key, ids * (1 << 32) + j0 + 1)]
            out[int(f)] = (ids, (1 - w) * p0 + w * p1)
        else:
            out[int(f)] = (ids, xy[np.searchsorted(key, ids * (1 << 32) + j0)])
    return out


def line_counts(points: pd.DataFrame, calibration, cams: tuple[str, str], timeline, threshold_px: float = 2.0,
                statuses: tuple | str = MEASURED, ids: tuple | None = None, ref_frames: np.ndarray | None = None):
    """(ids_a, ids_b, on, seen_a, seen_b): `on` (sparse, rows: camera a's ids, columns: b's) counts the frames
    a pair of tracks' points lay within threshold_px of each other's epipolar lines (in either view,
    undistorted pixels; b taken at a's frame times); seen_a, seen_b (sparse, a's frames x ids) the frames each
    track was measured at, so that `together(seen_a, seen_b, i, j)` counts a pair's frames measured together.
    Points of `statuses` (see `measured`); `ids` ((a's, b's), sorted: a superset of the
    points' ids) and `ref_frames` (a's frames, the rows of seen_*) give the same rows and columns as another
    call. Sparse: a long recording's thousands of tracks meet few lines."""
    from scipy.sparse import coo_matrix

    from ..triangulation import fundamental_matrix

    a, b = cams
    pa, pb = measured(points, a, statuses), measured(points, b, statuses)
    if ids is None:
        ids = np.unique(pa.marker.to_numpy(np.int64)), np.unique(pb.marker.to_numpy(np.int64))
    ids_a, ids_b = ids
    if ref_frames is None:
        ref_frames = np.unique(pa.frame.to_numpy(np.int64))
    b_at = at_reference_times(pb, timeline.position(b, ref_frames), ref_frames) if len(ids_b) else {}
    F = fundamental_matrix(calibration, a, b)  # x_b^T F x_a = 0
    cam_a, cam_b = calibration.cameras[a], calibration.cameras[b]
    on_r, on_c, sa_r, sa_c, sb_r, sb_c = [], [], [], [], [], []
    for f, g in pa.groupby("frame"):
        row = int(np.searchsorted(ref_frames, f))
        ia = np.searchsorted(ids_a, g.marker.to_numpy(np.int64))
        sa_r.append(np.full(len(ia), row))
        sa_c.append(ia)
        got = b_at.get(int(f))
        if got is None:
            continue
        ib_ids, xy_b = got
        ib = np.searchsorted(ids_b, ib_ids)
        sb_r.append(np.full(len(ib), row))
        sb_c.append(ib)
        ua = _homogeneous(cam_a.undistort(g[["x_px", "y_px"]].to_numpy(float)))
        ub = _homogeneous(cam_b.undistort(xy_b))
        lines_b = ua @ F.T  # a's points -> lines in b
        lines_a = ub @ F  # b's points -> lines in a
        d_b = np.abs(lines_b @ ub.T) / np.hypot(lines_b[:, :1], lines_b[:, 1:2])
        d_a = np.abs(ua @ lines_a.T) / np.hypot(lines_a[:, 0], lines_a[:, 1])[None, :]
        r, c = np.nonzero(np.maximum(d_a, d_b) <= threshold_px)
        on_r.append(ia[r])
        on_c.append(ib[c])

    def sparse(r, c, shape):
        r = np.concatenate(r) if r else np.zeros(0, int)
        c = np.concatenate(c) if c else np.zeros(0, int)
        return coo_matrix((np.ones(len(r), np.int32), (r, c)), shape=shape).tocsc()

    n = len(ref_frames)
    return (ids_a, ids_b, sparse(on_r, on_c, (len(ids_a), len(ids_b))).tocsr(),
            sparse(sa_r, sa_c, (n, len(ids_a))), sparse(sb_r, sb_c, (n, len(ids_b))))


def together(seen_a, seen_b, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Frames measured together by each pair (seen_a's column i[k], seen_b's column j[k])."""
    if not len(i):
        return np.zeros(0, np.int64)
    return np.asarray(seen_a[:, i].multiply(seen_b[:, j]).sum(axis=0)).ravel().astype(np.int64)


def pair_tracks(points: pd.DataFrame, calibration, cams: tuple[str, str], timeline, threshold_px: float = 2.0,
                min_frames: int = PAIR_MIN_FRAMES) -> Pairing:
    """Groups of tracks (both views) that are one particle each; see the module docstring."""
    a, b = cams
    ids_a, ids_b, on_any, seen_a_any, seen_b_any = line_counts(points, calibration, cams, timeline, threshold_px,
                                                               DETECTED)
    result = Pairing()
    if not len(ids_a) or not len(ids_b):
        return result
    ref_frames = np.unique(measured(points, a, DETECTED).frame.to_numpy(np.int64))
    _, _, on, seen_a, seen_b = line_counts(points, calibration, cams, timeline, threshold_px, MEASURED,
                                           (ids_a, ids_b), ref_frames)
    evidence = (on, seen_a, seen_b), (on_any, seen_a_any, seen_b_any)
    met = (on + on_any).tocoo()
    i, j = met.row, met.col
    on_line, rival, _apart = _verdicts(evidence, i, j, min_frames)
    linked = on_line | rival
    spans = {a: _spans(measured(points, a), ids_a), b: _spans(measured(points, b), ids_b)}
    for comp_a, comp_b in _components(i[linked], j[linked], len(ids_a), len(ids_b)):
        # every pair of the group, also those that never met a line (measured together, apart: not one particle)
        ca, cb = np.repeat(comp_a, len(comp_b)), np.tile(comp_b, len(comp_a))
        sub_on, sub_rival, sub_apart = _verdicts(evidence, ca, cb, min_frames)
        fine = not sub_rival.any() and not sub_apart.any() and sub_on.any() \
            and _disjoint(spans[a][comp_a]) and _disjoint(spans[b][comp_b])
        if fine:
            result.groups.append({a: [int(ids_a[k]) for k in comp_a[np.argsort(spans[a][comp_a, 0])]],
                                  b: [int(ids_b[k]) for k in comp_b[np.argsort(spans[b][comp_b, 0])]]})
        else:
            result.ambiguous.setdefault(a, []).extend(int(ids_a[k]) for k in comp_a)
            result.ambiguous.setdefault(b, []).extend(int(ids_b[k]) for k in comp_b)
    long_a = np.setdiff1d(np.flatnonzero(spans[a][:, 2] >= min_frames), i[linked])
    long_b = np.setdiff1d(np.flatnonzero(spans[b][:, 2] >= min_frames), j[linked])
    result.lonely = {a: [int(ids_a[k]) for k in long_a], b: [int(ids_b[k]) for k in long_b]}
    return result


def _verdicts(evidence, i: np.ndarray, j: np.ndarray, min_frames: int):
    """(on the line, rival, apart) of the pairs (a's track i[k], b's track j[k]). evidence: (on, seen_a,
    seen_b) of the measured points, then of the detected ones. On the line: measured together at least
    `min_frames`, off the line at no more than OFF_LINE_SHARE of them. Apart: off the line often, measured
    (or detected, when not on the line measured). Rival: neither, detected together at least RIVAL_MIN_FRAMES."""
    (on, sa, sb), (on_any, sa_any, sb_any) = evidence
    n_on = np.asarray(on[i, j]).ravel().astype(np.int64) if len(i) else np.zeros(0, np.int64)
    n_on_any = np.asarray(on_any[i, j]).ravel().astype(np.int64) if len(i) else np.zeros(0, np.int64)
    tog, tog_any = together(sa, sb, i, j), together(sa_any, sb_any, i, j)
    off, off_any = tog - n_on, tog_any - n_on_any
    on_line = (tog >= min_frames) & (off <= OFF_LINE_SHARE * tog)
    apart = ((off >= PAIR_BREAKS) & (off >= APART_SHARE * tog)) \
        | ((off_any >= PAIR_BREAKS) & (off_any >= APART_SHARE * tog_any) & ~on_line)
    rival = (tog_any >= RIVAL_MIN_FRAMES) & ~on_line & ~apart
    return on_line, rival, apart


def _homogeneous(xy: np.ndarray) -> np.ndarray:
    return np.hstack([xy, np.ones((len(xy), 1))])


def _spans(p: pd.DataFrame, ids: np.ndarray) -> np.ndarray:
    """(first frame, last frame, points) of each id's measured points, rows in the order of ids."""
    g = p.groupby("marker").frame.agg(["min", "max", "size"]).reindex(ids)
    return g.fillna({"min": -1, "max": -1, "size": 0}).to_numpy(np.int64)


def _disjoint(spans: np.ndarray) -> bool:
    """No two of these tracks (one view) measured at a common frame."""
    s = spans[np.argsort(spans[:, 0])]
    return bool(np.all(s[1:, 0] > s[:-1, 1]))


def _components(i: np.ndarray, j: np.ndarray, na: int, nb: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Connected groups of the bipartite graph with links (a's track i[k], b's track j[k]), as (a's tracks,
    b's tracks); tracks without a link are left out."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(len(i)), (i, na + j)), shape=(na + nb, na + nb))
    _, label = connected_components(graph, directed=False)
    used = np.zeros(na + nb, bool)
    used[i], used[na + j] = True, True
    out = []
    order = np.argsort(label, kind="stable")
    cut = np.flatnonzero(np.diff(label[order])) + 1
    for members in np.split(order, cut):
        members = members[used[members]]
        if len(members):
            out.append((members[members < na], members[members >= na] - na))
    return out
