"""Which existing marker a blob found by auto-seeding is.

Auto-seeding proposes markers (blobs, paired across cameras). Before any proposal is numbered as
a new marker it is matched to the markers the project already has, by where each marker is
known to be: its point in the frame being seeded, else its nearest usable point in time (manual,
tracked, interpolated or imported; not occluded or lost, whose position is a guess or absent).

A blob is the same bead as a marker when its centre lies within half a bead diameter of where
the marker is (two beads can never be closer than one diameter), plus an allowance for the
motion possible since the marker's known frame. The proposals and markers are then assigned one
to one (Hungarian method on the distance), so two neighbouring blobs never take the same id.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

USABLE = ("manual", "tracked", "interpolated", "imported")
KNOWN_COLUMNS = ["marker", "camera", "x_px", "y_px", "gap_frames"]


def known_positions(points: pd.DataFrame, frames: dict[str, int]) -> pd.DataFrame:
    """Each (marker, camera)'s usable point nearest in time to `frames[camera]` (that camera's own
    frame index), an earlier one winning a tie: DataFrame[KNOWN_COLUMNS]."""
    rows = []
    ok = points[points["status"].isin(USABLE) & points["x_px"].notna() & points["y_px"].notna()]
    for camera, frame in frames.items():
        sel = ok[ok["camera"] == camera]
        if sel.empty:
            continue
        gap = (sel["frame"].to_numpy(np.int64) - int(frame))
        order = np.lexsort((gap > 0, np.abs(gap), sel["marker"].to_numpy()))
        best = sel.iloc[order].assign(gap_frames=np.abs(gap[order])).drop_duplicates("marker")
        rows.append(best[["marker", "camera", "x_px", "y_px", "gap_frames"]])
    if not rows:
        return pd.DataFrame(columns=KNOWN_COLUMNS)
    out = pd.concat(rows, ignore_index=True)
    out["marker"] = out["marker"].astype(int)
    return out


def match_proposals(proposals: pd.DataFrame, known: pd.DataFrame, motion_px_per_frame: float = 2.0,
                    max_gate_px: float = 60.0, default_diameter_px: float = 10.0) -> dict[int, tuple[int, float]]:
    """Assign proposals (auto-seed rows: marker = proposal id, camera, x_px, y_px, w, h) to known
    markers (`known_positions`). Returns {proposal id: (marker id, distance px)} for the matched
    proposals; the distance is the mean over the cameras both have. A proposal of one camera only that
    is left over takes a marker whose place in that camera no matched proposal holds, if one is there.

    A proposal and a marker can match when, in every camera both have a position in, the blob lies
    within max(half its diameter, 2 px) + motion_px_per_frame x the marker's gap in frames there
    (at most max_gate_px); a camera only one of them has does not count for or against."""
    if proposals.empty or known.empty:
        return {}
    pids = np.array(sorted(proposals["marker"].unique()))
    mids = np.array(sorted(known["marker"].unique()))
    total = np.zeros((len(pids), len(mids)))
    shared = np.zeros((len(pids), len(mids)), int)
    feasible = np.ones((len(pids), len(mids)), bool)
    dist_in, shared_in = {}, {}  # camera -> distances (inf: not both in it), both in it
    for cam in sorted(set(proposals["camera"]) & set(known["camera"])):
        p = proposals[proposals["camera"] == cam].drop_duplicates("marker")
        k = known[known["camera"] == cam].drop_duplicates("marker")
        d = np.hypot(p["x_px"].to_numpy(float)[:, None] - k["x_px"].to_numpy(float)[None, :],
                     p["y_px"].to_numpy(float)[:, None] - k["y_px"].to_numpy(float)[None, :])
        gate = np.minimum(_half_bead(p, default_diameter_px)[:, None]
                          + motion_px_per_frame * k["gap_frames"].to_numpy(float)[None, :], max_gate_px)
        sub = np.ix_(np.searchsorted(pids, p["marker"].to_numpy()), np.searchsorted(mids, k["marker"].to_numpy()))
        total[sub] += d
        shared[sub] += 1
        feasible[sub] &= d <= gate
        dist_in[cam] = np.full((len(pids), len(mids)), np.inf)
        dist_in[cam][sub] = d
        shared_in[cam] = np.isfinite(dist_in[cam])
    big = 1e9
    cost = np.where(feasible & (shared > 0), total / np.maximum(shared, 1), big)
    rows, cols = linear_sum_assignment(cost)
    out = {int(pids[r]): (int(mids[c]), float(cost[r, c])) for r, c in zip(rows, cols, strict=True)
           if cost[r, c] < big}
    # A proposal seen in one camera only (not paired: touching lookalikes) may be the bead a marker is in
    # that camera while another one-camera proposal took the marker in the other camera.
    cams_of = proposals.groupby("marker")["camera"].agg(frozenset)
    taken = {(m, c) for p, (m, _) in out.items() for c in cams_of[p]}
    for cam in sorted(set(proposals["camera"]) & set(known["camera"])):
        rest = [i for i, p in enumerate(pids) if p not in out and cams_of[p] == {cam}]
        free = [k for k, m in enumerate(mids) if (m, cam) not in taken and shared_in[cam][:, k].any()]
        if not rest or not free:
            continue
        sub = np.where(feasible[np.ix_(rest, free)] & shared_in[cam][np.ix_(rest, free)],
                       dist_in[cam][np.ix_(rest, free)], big)
        for r, c in zip(*linear_sum_assignment(sub), strict=True):
            if sub[r, c] < big:
                out[int(pids[rest[r]])] = (int(mids[free[c]]), float(sub[r, c]))
    return out


def _half_bead(blobs: pd.DataFrame, default_diameter: float) -> np.ndarray:
    """Half of each blob's diameter, at least 2 px (detection boxes hold the blob plus 2 px of sand on
    each side; without a box, `default_diameter`)."""
    size = blobs.reindex(columns=["w", "h"]).to_numpy(float)
    n = np.isfinite(size).sum(axis=1)
    mean = np.where(n > 0, np.where(np.isfinite(size), size, 0.0).sum(axis=1) / np.maximum(n, 1), np.nan)
    diameter = np.where(np.isfinite(mean), np.maximum(mean - 4.0, 1.0), default_diameter)
    return np.maximum(0.5 * diameter, 2.0)


def number_proposals(proposals: pd.DataFrame, matches: dict[int, tuple[int, float]], next_id: int) -> pd.DataFrame:
    """The proposals with their final ids: a matched proposal takes its marker's id, the others are
    numbered from `next_id` in their order. Adds `existing` (bool) and `match_px` (NaN when new)."""
    out = proposals.copy()
    new_ids, ids, dist = {}, [], []
    for p in out["marker"].tolist():
        if p in matches:
            ids.append(matches[p][0])
            dist.append(matches[p][1])
            continue
        if p not in new_ids:
            new_ids[p] = next_id
            next_id += 1
        ids.append(new_ids[p])
        dist.append(np.nan)
    out["existing"] = [p in matches for p in out["marker"].tolist()]
    out["marker"] = ids
    out["match_px"] = dist
    return out
