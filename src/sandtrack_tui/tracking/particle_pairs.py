"""Every-particle tracks of two calibrated cameras paired across the views: a track of the first camera and
one of the second are one particle when their points lie on each other's epipolar lines over enough frames
measured together (the second camera's points taken at the first's frame times: sync offset respected),
and no other track of either view lies on them as well.

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

MEASURED = ("tracked", "manual")
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


def measured(points: pd.DataFrame, camera: str) -> pd.DataFrame:
    p = points[(points.camera == camera) & points.status.isin(MEASURED)]
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


def line_counts(points: pd.DataFrame, calibration, cams: tuple[str, str], timeline, threshold_px: float = 2.0):
    """(ids_a, ids_b, on, seen_a, seen_b): `on` (sparse, rows: camera a's ids, columns: b's) counts the frames
    a pair of tracks' points lay within threshold_px of each other's epipolar lines (in either view,
    undistorted pixels; b taken at a's frame times); seen_a, seen_b (sparse, a's frames x ids) the frames each
    track was measured at, so that `together(seen_a, seen_b, i, j)` counts a pair's frames measured together.
    Sparse: a long recording's thousands of tracks meet few lines."""
    from scipy.sparse import coo_matrix

    from ..triangulation import fundamental_matrix

    a, b = cams
    pa, pb = measured(points, a), measured(points, b)
    ids_a, ids_b = np.unique(pa.marker.to_numpy(np.int64)), np.unique(pb.marker.to_numpy(np.int64))
    ref_frames = np.unique(pa.frame.to_numpy(np.int64))
    b_at = at_reference_times(pb, timeline.position(b, ref_frames), ref_frames) if len(ids_b) else {}
    F = fundamental_matrix(calibration, a, b)  # x_b^T F x_a = 0
    cam_a, cam_b = calibration.cameras[a], calibration.cameras[b]
    on_r, on_c, sa_r, sa_c, sb_r, sb_c = [], [], [], [], [], []
    for row, (f, g) in enumerate(pa.groupby("frame")):
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
    ids_a, ids_b, on, seen_a, seen_b = line_counts(points, calibration, cams, timeline, threshold_px)
    result = Pairing()
    if not len(ids_a) or not len(ids_b):
        return result
    met = on.tocoo()
    i, j, n_on = met.row, met.col, met.data.astype(np.int64)
    on_line, rival, _apart = _verdicts(together(seen_a, seen_b, i, j), n_on, min_frames)
    linked = on_line | rival
    spans = {a: _spans(measured(points, a), ids_a), b: _spans(measured(points, b), ids_b)}
    for comp_a, comp_b in _components(i[linked], j[linked], len(ids_a), len(ids_b)):
        # every pair of the group, also those that never met a line (measured together, apart: not one particle)
        ca, cb = np.repeat(comp_a, len(comp_b)), np.tile(comp_b, len(comp_a))
        n_on = np.asarray(on[comp_a][:, comp_b].todense()).ravel()
        sub_on, sub_rival, sub_apart = _verdicts(together(seen_a, seen_b, ca, cb), n_on, min_frames)
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


def _verdicts(together: np.ndarray, n_on: np.ndarray, min_frames: int):
    """(on the line, rival, apart) of pairs measured `together` frames, `n_on` of them on each other's lines."""
    off = together - n_on
    on_line = (together >= min_frames) & (off <= OFF_LINE_SHARE * together)
    apart = (off >= PAIR_BREAKS) & (off >= APART_SHARE * together)
    rival = (together >= RIVAL_MIN_FRAMES) & ~on_line & ~apart
    return on_line, rival, apart


def _homogeneous(xy: np.ndarray) -> np.ndarray:
    return np.hstack([xy, np.ones((len(xy), 1))])


def _spans(p: pd.DataFrame, ids: np.ndarray) -> np.ndarray:
    """(first frame, last frame, points) of each id's measured points, rows in the order of ids."""
    g = p.groupby("marker").frame.agg(["min", "max", "size"]).reindex(ids)
    return g.to_numpy(np.int64)


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
