"""Corrections of tracked points, each one undoable edit in the project store.

Positions are pixels in each camera's own frame index (as stored). "Good" points are those with
a position the trajectory can use: tracked, manual, interpolated or imported, with finite x/y.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .errors import SandtrackError
from .store import Project

GOOD_STATUSES = ("tracked", "manual", "interpolated", "imported")


def _good(df: pd.DataFrame) -> pd.Series:
    return df["status"].isin(GOOD_STATUSES) & np.isfinite(df["x_px"].astype(float)) & np.isfinite(
        df["y_px"].astype(float))


def ensure_marker(project: Project, marker: int) -> None:
    if marker not in set(project.markers()["id"].tolist()):
        project.add_marker(str(marker), marker)


def set_manual(project: Project, marker: int, camera: str, frame: int, x: float, y: float,
               description: str | None = None) -> int:
    """Place a marker by hand (status "manual")."""
    ensure_marker(project, marker)
    row = {"frame": frame, "camera": camera, "marker": marker, "x_px": x, "y_px": y, "status": "manual",
           "score": 1.0}
    return project.set_points([row], description or f"place marker {marker} in {camera} at frame {frame}")


def nudge(project: Project, marker: int, camera: str, frame: int, dx: float, dy: float) -> int:
    """Move one point by (dx, dy) px; it becomes "manual"."""
    pts = project.points(frame=frame, camera=camera, marker=marker)
    if pts.empty or pd.isna(pts["x_px"].iloc[0]) or pd.isna(pts["y_px"].iloc[0]):
        raise SandtrackError(f"marker {marker} has no position in {camera} at frame {frame} to nudge")
    r = pts.iloc[0]
    row = {**r.to_dict(), "x_px": float(r["x_px"]) + dx, "y_px": float(r["y_px"]) + dy, "status": "manual"}
    return project.set_points([row], f"nudge marker {marker} in {camera} at frame {frame} by ({dx:+g}, {dy:+g}) px")


def mark_occluded(project: Project, marker: int, camera: str, frames: tuple[int, int]) -> int:
    """Mark a marker hidden in one camera over frames a..b (inclusive): status "occluded", no position."""
    a, b = sorted(frames)
    ensure_marker(project, marker)
    rows = [{"frame": f, "camera": camera, "marker": marker, "x_px": None, "y_px": None, "status": "occluded"}
            for f in range(a, b + 1)]
    span = f"frame {a}" if a == b else f"frames {a}-{b}"
    return project.set_points(rows, f"mark marker {marker} occluded in {camera} at {span}")


def delete_range(project: Project, marker: int, camera: str | None, frames: tuple[int, int]) -> int:
    a, b = sorted(frames)
    where = camera or "both cameras"
    return project.delete_points(marker, camera, (a, b), f"delete marker {marker} in {where}, frames {a}-{b}")


def gap_around(project: Project, marker: int, camera: str, frame: int) -> tuple[int, int] | None:
    """The stretch of frames without a good point that contains `frame`, bounded by good points on
    both sides; None if `frame` has a good point or the stretch is open-ended."""
    df = project.points(camera=camera, marker=marker)
    good = df.loc[_good(df), "frame"].to_numpy(int)
    if frame in set(good.tolist()):
        return None
    before, after = good[good < frame], good[good > frame]
    if not len(before) or not len(after):
        return None
    return int(before.max()) + 1, int(after.min()) - 1


def interpolate_gap(project: Project, marker: int, camera: str, frames: tuple[int, int]) -> int:
    """Fill frames a..b that lack a good point by linear interpolation between the nearest good points
    around them (status "interpolated"). Returns the number of frames filled."""
    a, b = sorted(frames)
    df = project.points(camera=camera, marker=marker)
    good = df[_good(df)].sort_values("frame")
    gf = good["frame"].to_numpy(int)
    if not len(gf) or gf.min() >= b or gf.max() <= a:
        raise SandtrackError(f"marker {marker} in {camera}: no good points on both sides of frames {a}-{b}")
    todo = np.setdiff1d(np.arange(a, b + 1), gf)
    todo = todo[(todo > gf.min()) & (todo < gf.max())]
    if not len(todo):
        raise SandtrackError(f"marker {marker} in {camera}: nothing to interpolate in frames {a}-{b}")
    xs = np.interp(todo, gf, good["x_px"].to_numpy(float))
    ys = np.interp(todo, gf, good["y_px"].to_numpy(float))
    rows = [{"frame": int(f), "camera": camera, "marker": marker, "x_px": float(x), "y_px": float(y),
             "status": "interpolated"} for f, x, y in zip(todo, xs, ys, strict=True)]
    project.set_points(rows, f"interpolate marker {marker} in {camera}, frames {int(todo[0])}-{int(todo[-1])}")
    return len(rows)


def swap_markers(project: Project, m1: int, m2: int, frames, cameras: list[str] | None = None) -> int:
    """Exchange the identities of two markers over frames a..b (inclusive) in the given cameras
    (all by default), as one edit. `frames` is (a, b), or {camera: (a, b)} when each camera has its
    own frame range (cameras with their own clocks). Returns the number of points moved."""
    if m1 == m2:
        raise SandtrackError("choose two different markers to swap")
    ranges = frames if isinstance(frames, dict) else None
    span = "" if ranges else "frames {}-{}".format(*sorted(frames))
    ensure_marker(project, m1)
    ensure_marker(project, m2)
    rows = []
    for m in (m1, m2):
        if ranges is None:
            df = project.points(marker=m, frames=tuple(sorted(frames)))
            rows.append(df if cameras is None else df[df["camera"].isin(cameras)])
        else:
            for cam, rng in ranges.items():
                if cameras is None or cam in cameras:
                    rows.append(project.points(marker=m, camera=cam, frames=tuple(sorted(rng))))
    both = pd.concat(rows, ignore_index=True)
    where = span or ", ".join(f"{c} {min(r)}-{max(r)}" for c, r in ranges.items())
    if both.empty:
        raise SandtrackError(f"markers {m1} and {m2} have no points in {where}")
    swapped = both.copy()
    swapped["marker"] = np.where(both["marker"] == m1, m2, m1)
    with project.edit(f"swap markers {m1} and {m2}, {where}") as ed:
        ed.delete(both[["frame", "camera", "marker"]].itertuples(index=False, name=None))
        ed.write(swapped)
    return len(both)


# Which of two points at one frame and camera a merge keeps: the better-founded status first.
MERGE_PREFERENCE = ("manual", "tracked", "imported", "interpolated", "occluded", "lost")
# Settings keyed "MARKER/CAMERA" (tracking.run: the box and the appearance model a marker's track starts
# from in each camera): a merged marker takes the dropped one's in a camera where it has none of its own.
MARKER_CAMERA_SETTINGS = ("tracking_boxes", "tracking_models")


def merge_markers(project: Project, keep: int, drop: int) -> int:
    """Make `drop` part of `keep` (two ids given to one bead), as one edit: where only `drop` has a
    point it becomes `keep`'s; where both have one, the point with the better status stays
    (MERGE_PREFERENCE; `keep`'s on a tie); marker `drop` is removed. Returns the points taken from
    `drop`."""
    if keep == drop:
        raise SandtrackError("choose two different markers to merge")
    ids = set(project.markers()["id"].tolist())
    if drop not in ids and project.points(marker=drop).empty:
        raise SandtrackError(f"no marker {drop}")
    ensure_marker(project, keep)
    with project.edit(f"merge marker {drop} into {keep}") as ed:
        return merge_in_edit(project, ed, [(keep, drop)])[drop]


def merge_in_edit(project: Project, ed, pairs: list[tuple[int, int]]) -> dict[int, int]:
    """merge_markers' work for every (keep, drop) of `pairs` (each `keep` an existing marker, no marker
    both kept and dropped) as part of the open edit `ed` (Project.edit): undone with the rest of that
    edit. Also gives each `keep` the per-camera settings of its `drop` (MARKER_CAMERA_SETTINGS) in the
    cameras where it has none. Returns {drop: the points taken from it}."""
    into = {int(d): int(k) for k, d in pairs}
    if set(into) & set(into.values()) or len(into) != len(pairs):
        raise SandtrackError("a marker merged away is merged only once, and into a marker that stays")
    points = project.points()
    theirs = points[points.marker.isin(list(into))]
    ours = points[points.marker.isin(list(into.values()))]
    rank = {s: k for k, s in enumerate(MERGE_PREFERENCE)}
    both = theirs.assign(keep=theirs.marker.map(into)).merge(
        ours[["frame", "camera", "marker", "status"]].rename(columns={"marker": "keep"}),
        on=["frame", "camera", "keep"], how="left", suffixes=("", "_keep"))
    their_rank = both["status"].map(rank).fillna(len(rank))
    our_rank = both["status_keep"].map(rank).fillna(len(rank) + 1)  # no point of `keep` there: theirs wins
    wins = their_rank < our_rank
    taken = both.loc[wins, theirs.columns].assign(marker=both.loc[wins, "keep"])
    # written before the dropped go, so an interrupted merge leaves a copy, never a loss (undo mends either)
    ed.write(taken)
    ed.delete(theirs[["frame", "camera", "marker"]].itertuples(index=False, name=None))
    for key in MARKER_CAMERA_SETTINGS:
        per = project.get(key, {}) or {}
        moved = _settings_merged(per, into)
        if moved != per:
            ed.set(key, moved)
    for drop in into:
        ed.delete_marker(drop)
    counts = both.loc[wins, "marker"].value_counts()
    return {drop: int(counts.get(drop, 0)) for drop in into}


def _settings_merged(per: dict, into: dict) -> dict:
    """A {"MARKER/CAMERA": value} setting with each dropped marker's entries ({drop: keep}) given to its
    kept one where that has none."""
    out = {k: v for k, v in per.items() if _int_or_none(k.partition("/")[0]) not in into}
    for k, v in per.items():
        marker, _, camera = k.partition("/")
        if _int_or_none(marker) in into:
            out.setdefault(f"{into[int(marker)]}/{camera}", v)
    return out


def _int_or_none(text: str) -> int | None:
    try:
        return int(text)
    except ValueError:
        return None


def rename_marker(project: Project, marker: int, label: str) -> None:
    """Give a marker a new label (its id, used in exports, stays)."""
    ensure_marker(project, marker)
    project.rename_marker(marker, label)
