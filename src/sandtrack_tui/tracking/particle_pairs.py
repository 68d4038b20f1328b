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
    """(ids_a, ids_b, together, off): per pair of tracks (rows: camera a's ids, columns: b's) the frames both
    were measured (b at a's frame times) and the frames their points lay further than threshold_px from each
    other's epipolar lines (in either view, undistorted pixels)."""
    from ..triangulation import fundamental_matrix

    a, b = cams
    pa, pb = measured(points, a), measured(points, b)
    ids_a, ids_b = np.unique(pa.marker.to_numpy(np.int64)), np.unique(pb.marker.to_numpy(np.int64))
    together = np.zeros((len(ids_a), len(ids_b)), np.int32)
    on = np.zeros_like(together)
    if not len(ids_a) or not len(ids_b):
        return ids_a, ids_b, together, together
    F = fundamental_matrix(calibration, a, b)  # x_b^T F x_a = 0
    ref_frames = np.unique(pa.frame.to_numpy(np.int64))
    b_at = at_reference_times(pb, timeline.position(b, ref_frames), ref_frames)
    cam_a, cam_b = calibration.cameras[a], calibration.cameras[b]
    for f, g in pa.groupby("frame"):
        got = b_at.get(int(f))
        if got is None:
            continue
        ib_ids, xy_b = got
        ia = np.searchsorted(ids_a, g.marker.to_numpy(np.int64))
        ib = np.searchsorted(ids_b, ib_ids)
        ua = _homogeneous(cam_a.undistort(g[["x_px", "y_px"]].to_numpy(float)))
        ub = _homogeneous(cam_b.undistort(xy_b))
        lines_b = ua @ F.T  # a's points -> lines in b
        lines_a = ub @ F  # b's points -> lines in a
        d_b = np.abs(lines_b @ ub.T) / np.hypot(lines_b[:, :1], lines_b[:, 1:2])
        d_a = np.abs(ua @ lines_a.T) / np.hypot(lines_a[:, 0], lines_a[:, 1])[None, :]
        close = np.maximum(d_a, d_b) <= threshold_px
        together[np.ix_(ia, ib)] += 1
        r, c = np.nonzero(close)
        np.add.at(on, (ia[r], ib[c]), 1)
    return ids_a, ids_b, together, together - on


def pair_tracks(points: pd.DataFrame, calibration, cams: tuple[str, str], timeline, threshold_px: float = 2.0,
                min_frames: int = PAIR_MIN_FRAMES) -> Pairing:
    """Groups of tracks (both views) that are one particle each; see the module docstring."""
    a, b = cams
    ids_a, ids_b, together, off = line_counts(points, calibration, cams, timeline, threshold_px)
    result = Pairing()
    if not len(ids_a) or not len(ids_b):
        return result
    on_line = (together >= min_frames) & (off <= OFF_LINE_SHARE * together)
    apart = (off >= PAIR_BREAKS) & (off >= APART_SHARE * together)
    rival = (together >= RIVAL_MIN_FRAMES) & ~on_line & ~apart
    spans = {a: _spans(measured(points, a), ids_a), b: _spans(measured(points, b), ids_b)}
    linked = on_line | rival
    for comp_a, comp_b in _components(linked):
        if not len(comp_b) or not len(comp_a):
            continue
        sub_on, sub_rival = on_line[np.ix_(comp_a, comp_b)], rival[np.ix_(comp_a, comp_b)]
        sub_apart = apart[np.ix_(comp_a, comp_b)]
        fine = not sub_rival.any() and not sub_apart.any() and sub_on.any() \
            and _disjoint(spans[a][comp_a]) and _disjoint(spans[b][comp_b])
        if fine:
            result.groups.append({a: [int(ids_a[i]) for i in comp_a[np.argsort(spans[a][comp_a, 0])]],
                                  b: [int(ids_b[j]) for j in comp_b[np.argsort(spans[b][comp_b, 0])]]})
        else:
            result.ambiguous.setdefault(a, []).extend(int(ids_a[i]) for i in comp_a)
            result.ambiguous.setdefault(b, []).extend(int(ids_b[j]) for j in comp_b)
    grouped_a = np.flatnonzero(linked.any(axis=1))
    grouped_b = np.flatnonzero(linked.any(axis=0))
    long_a = np.setdiff1d(np.flatnonzero(spans[a][:, 2] >= min_frames), grouped_a)
    long_b = np.setdiff1d(np.flatnonzero(spans[b][:, 2] >= min_frames), grouped_b)
    result.lonely = {a: [int(ids_a[i]) for i in long_a], b: [int(ids_b[j]) for j in long_b]}
    return result


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


def _components(linked: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Connected groups of the bipartite graph `linked` (rows: a's tracks, columns: b's), as (rows, columns);
    tracks without a link are left out."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    na, nb = linked.shape
    r, c = np.nonzero(linked)
    graph = coo_matrix((np.ones(len(r)), (r, na + c)), shape=(na + nb, na + nb))
    _, label = connected_components(graph, directed=False)
    used = np.zeros(na + nb, bool)
    used[r], used[na + c] = True, True
    out = []
    for lab in np.unique(label[used]):
        members = np.flatnonzero((label == lab) & used)
        out.append((members[members < na], members[members >= na] - na))
    return out
