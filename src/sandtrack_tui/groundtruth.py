"""Scoring against the rendered rig's ground truth (`sandtrack sample` output).

Every figure here is measured: the pipeline's outputs (calibration, tracks, XYZ, model
predictions) are compared with the truth files written by the renderer, never copied from them.
Used by `sandtrack demo` and the benchmarks.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from .camera import Calibration
from .errors import SandtrackError

REPORTED = ("tracked", "manual")  # statuses that claim a measured position
FLAGGED = ("occluded", "lost")  # statuses that admit the marker is not seen


@dataclass
class SampleTruth:
    root: Path
    calibration: Calibration
    sync_offset_s: float
    markers: dict[str, pd.DataFrame]  # per camera: frame, marker, x_px, y_px, visible, ...
    trajectories: pd.DataFrame  # per side frame: frame, time_s, marker, X_mm, Y_mm, Z_mm, ...
    corners: dict[str, pd.DataFrame]  # per camera: frame, corner_id, x_px, y_px, X_mm, Y_mm, Z_mm
    dem_differences: dict
    reference: dict


def load_truth(sample_dir: str | Path) -> SampleTruth:
    root = Path(sample_dir)
    gt = root / "ground_truth"
    if not (gt / "cameras.toml").is_file():
        raise SandtrackError(f"{root}: no ground truth here (render it with `sandtrack sample {root}`)")
    sync = json.loads((gt / "sync.json").read_text())
    diff_path = root / "dem" / "differences.json"
    ref_path = root / "calibration" / "reference.toml"
    return SampleTruth(
        root=root,
        calibration=Calibration.load(gt / "cameras.toml"),
        sync_offset_s=float(sync["offset_s"]),
        markers={c: pd.read_csv(gt / f"markers_{c}.csv") for c in ("side", "front")},
        trajectories=pd.read_csv(gt / "trajectories.csv"),
        corners={c: pd.read_csv(gt / f"calibration_corners_{c}.csv") for c in ("side", "front")},
        dem_differences=json.loads(diff_path.read_text()) if diff_path.is_file() else {},
        reference=tomllib.loads(ref_path.read_text()) if ref_path.is_file() else {},
    )


# -- calibration ---------------------------------------------------------------------------------
def score_calibration(est: Calibration, truth: SampleTruth) -> dict:
    """Intrinsics and relative-pose errors, and the mean error of board corners triangulated from
    their true pixels with the estimated calibration, in the estimated world frame (mm)."""
    from .calibration.report import relative_pose_errors
    from .triangulation import triangulate

    pose = relative_pose_errors(est, truth.calibration)
    out = {
        "focal_error_pct": 100.0 * pose["focal_rel_err"],
        "principal_point_error_px": pose["principal_point_err_px"],
        "rotation_error_deg": pose["rotation_err_deg"],
        "translation_error_mm": pose["translation_err_mm"],
    }
    # The calibration session's front clock lags the side's: pair the cameras' true corners by
    # identical world positions (same instant), once per position (a resting board repeats them).
    key = ["corner_id", "X_mm", "Y_mm", "Z_mm"]
    side, front = (truth.corners[c].drop_duplicates(key) for c in ("side", "front"))
    both = side.merge(front, on=key, suffixes=("_s", "_f"))
    if len(both):
        xyz, _ = triangulate(est, {"side": both[["x_px_s", "y_px_s"]].to_numpy(),
                                   "front": both[["x_px_f", "y_px_f"]].to_numpy()})
        err = np.linalg.norm(xyz - both[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), axis=1)
        out["corner_error_mm"] = float(np.nanmean(err))
        out["corner_p95_error_mm"] = float(np.nanpercentile(err, 95))
        out["corners_scored"] = int(np.isfinite(err).sum())
    return out


# -- tracking ------------------------------------------------------------------------------------
def match_marker_ids(points: pd.DataFrame, truth: SampleTruth, max_px: float = 15.0) -> dict[int, int]:
    """Project marker id -> true marker id: the true marker nearest to each marker's first point."""
    mapping: dict[int, int] = {}
    for marker, rows in points[points.x_px.notna()].groupby("marker"):
        first = rows.sort_values(["frame", "camera"]).iloc[0]
        t = truth.markers[first.camera]
        t = t[t.frame == int(first.frame)]
        if t.empty:
            continue
        d = np.hypot(t.x_px - first.x_px, t.y_px - first.y_px)
        if d.min() <= max_px:
            mapping[int(marker)] = int(t.marker.iloc[int(np.argmin(d))])
    return mapping


def score_tracking(points: pd.DataFrame, truth: SampleTruth, id_map: dict[int, int],
                   false_lock_px: float = 3.0, reacquire_frames: int = 3) -> dict:
    """Centre error on visible frames, false locks, honesty of hidden flags, re-acquisition."""
    errors, false_locks = [], 0
    hidden_n = hidden_flagged = flagged_n = flagged_hidden = 0
    reacq_total = reacq_ok = 0
    for camera, t in truth.markers.items():
        p = points[(points.camera == camera) & points.marker.isin(list(id_map))].copy()
        if p.empty:
            continue
        p["true_marker"] = p.marker.map(id_map)
        m = p.merge(t, left_on=["frame", "true_marker"], right_on=["frame", "marker"], suffixes=("", "_true"))
        err = np.hypot(m.x_px - m.x_px_true, m.y_px - m.y_px_true)
        reported = m.status.isin(REPORTED) & m.x_px.notna()
        visible = m.visible.astype(bool)
        errors.append(err[reported & visible].to_numpy())
        false_locks += int((reported & (err > false_lock_px)).sum())
        flagged = m.status.isin(FLAGGED)
        hidden_n += int((~visible).sum())
        hidden_flagged += int((~visible & flagged).sum())
        flagged_n += int(flagged.sum())
        flagged_hidden += int((flagged & ~visible).sum())
        for _, g in m.sort_values("frame").groupby("true_marker"):
            vis = g.visible.to_numpy().astype(bool)
            ok = g.status.isin(REPORTED).to_numpy()
            for k in np.nonzero(vis[1:] & ~vis[:-1])[0] + 1:  # hidden -> visible
                reacq_total += 1
                if ok[k:k + reacquire_frames + 1].any():
                    reacq_ok += 1
    e = np.concatenate(errors) if errors else np.array([])
    return {
        "mean_error_px": float(e.mean()) if len(e) else float("nan"),
        "p95_error_px": float(np.percentile(e, 95)) if len(e) else float("nan"),
        "visible_frames_scored": int(len(e)),
        "false_locks": false_locks,
        "hidden_flagged_pct": 100.0 * hidden_flagged / hidden_n if hidden_n else float("nan"),
        "flagged_truly_hidden_pct": 100.0 * flagged_hidden / flagged_n if flagged_n else float("nan"),
        "reappearances": reacq_total,
        "reacquired_within_3_frames_pct": 100.0 * reacq_ok / reacq_total if reacq_total else float("nan"),
        "markers_matched": len(id_map),
    }


def identity_switches(points: pd.DataFrame, truth: SampleTruth, id_map: dict[int, int],
                      near_px: float = 3.0) -> dict:
    """Tracked points that sit on another marker (within `near_px` of another marker's true centre):
    an identity switch the tracker did not flag; and the share of visible frames reported tracked."""
    switches = visible_n = visible_tracked = 0
    for camera, t in truth.markers.items():
        p = points[(points.camera == camera) & points.marker.isin(list(id_map)) & (points.status == "tracked")]
        p = p.assign(true_marker=p.marker.map(id_map))
        m = p.merge(t[["frame", "marker", "x_px", "y_px"]], on="frame", suffixes=("", "_t"))
        near = np.hypot(m.x_px - m.x_px_t, m.y_px - m.y_px_t) <= near_px
        switches += int((near & (m.marker_t != m.true_marker)).groupby([m.marker, m.frame]).any().sum())
        first = {mk: int(f) for mk, f in points[points.camera == camera].groupby("marker").frame.min().items()}
        for mk, tm in id_map.items():
            if mk not in first:
                continue
            vis = t[(t.marker == tm) & t.visible.astype(bool) & (t.frame > first[mk])]
            visible_n += len(vis)
            visible_tracked += int(vis.frame.isin(p[p.marker == mk].frame).sum())
    return {"identity_switches": switches,
            "visible_tracked_pct": 100.0 * visible_tracked / visible_n if visible_n else float("nan")}


def board_points_from_corners(corners: pd.DataFrame, camera, points_m: np.ndarray, min_corners: int = 6,
                              anchors: np.ndarray | None = None) -> dict:
    """Pixels of points on a flat board (`points_m` (N, 2), board coordinates in metres) in each frame,
    from that frame's detected board corners (`corners`: frame, obj_loc_x, obj_loc_y, img_loc_x,
    img_loc_y, as Caliscope's xy.csv): a homography fitted to the undistorted corners, its points
    distorted again with `camera`'s lens. With `anchors` ((N, 2), board coordinates: e.g. the centre
    of the square a point outlines), each point is placed by the homography through the 4 detected
    corners nearest its anchor instead (local: what the lens model gets wrong far from the image's
    centre hardly enters), where those 4 span the board's plane. Frames with fewer than
    `min_corners` corners are left out. Returns {frame: (N, 2) pixels}."""
    out = {}
    pts = np.asarray(points_m, float).reshape(-1, 2)
    for frame, g in corners.groupby("frame"):
        if len(g) < min_corners:
            continue
        img = camera.undistort(g[["img_loc_x", "img_loc_y"]].to_numpy(float))
        obj = g[["obj_loc_x", "obj_loc_y"]].to_numpy(float)
        H, _ = cv2.findHomography(obj, img, 0)
        if H is None:
            continue
        und = cv2.perspectiveTransform(pts.reshape(-1, 1, 2), H).reshape(-1, 2)
        if anchors is not None:
            local = {}
            for a in np.unique(np.asarray(anchors, float), axis=0):
                Hl = local_homography(obj, img, a)
                if Hl is not None:  # (else: no corners close around it, the whole board's homography)
                    local[tuple(a)] = Hl
            for a, Hl in local.items():
                sel = (np.asarray(anchors) == np.array(a)).all(axis=1)
                und[sel] = cv2.perspectiveTransform(pts[sel].reshape(-1, 1, 2), Hl).reshape(-1, 2)
        out[int(frame)] = _distort(camera, und)
    return out


def local_homography(obj: np.ndarray, img: np.ndarray, anchor) -> np.ndarray | None:
    """Homography from board coordinates to (undistorted) pixels through the fewest detected corners
    nearest `anchor` (board coordinates) that span the plane (4 when no 3 of them are on a line), or
    None when those lie farther than 1.6 corner spacings from it."""
    if len(obj) < 4:
        return None
    spacing = float(np.median(np.sort(np.hypot(*(obj[:, None] - obj[None]).transpose(2, 0, 1)), axis=1)[:, 1]))
    dist = np.hypot(*(obj - np.asarray(anchor, float)).T)
    order = np.argsort(dist, kind="stable")
    near = next((order[:k] for k in range(4, len(order) + 1) if _spans_plane(obj[order[:k]])), None)
    if near is None or dist[near].max() > 1.6 * spacing:
        return None
    H, _ = cv2.findHomography(obj[near], img[near], 0)
    return H


def _spans_plane(p: np.ndarray) -> bool:
    """Points that can carry a homography: 4 of which no 3 lie on a line, or more not all on one
    (within a tenth of their spacing)."""
    if len(p) < 4:
        return False
    tol = 0.1 * float(np.median(np.hypot(*(p[1:] - p[0]).T)))

    def off_line(i: int, j: int, k: int) -> float:
        d = p[j] - p[i]
        return abs(d[0] * (p[k, 1] - p[i, 1]) - d[1] * (p[k, 0] - p[i, 0])) / max(float(np.hypot(*d)), 1e-12)

    if len(p) == 4:
        return all(off_line(i, j, k) > tol for i, j, k in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)))
    return np.linalg.matrix_rank(p - p.mean(axis=0), tol=tol) >= 2


def _distort(camera, und: np.ndarray) -> np.ndarray:
    K = camera.matrix
    rays = np.hstack([(und - K[:2, 2]) / np.diag(K)[:2], np.ones((len(und), 1))])
    px, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, camera.distortion)
    return px.reshape(-1, 2)


# -- 3D ------------------------------------------------------------------------------------------
def score_xyz(xyz: pd.DataFrame, truth: SampleTruth, id_map: dict[int, int], method: str) -> dict:
    """3D error of the tracked markers (rows with finite XYZ) against the true trajectories."""
    d = xyz[(xyz.method == method) & xyz.marker.isin(list(id_map))].copy()
    d["true_marker"] = d.marker.map(id_map)
    m = d.merge(truth.trajectories, left_on=["frame", "true_marker"], right_on=["frame", "marker"],
                suffixes=("", "_true"))
    err = np.linalg.norm(m[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - m[["X_mm_true", "Y_mm_true", "Z_mm_true"]]
                         .to_numpy(), axis=1)
    err = err[np.isfinite(err)]
    return {
        "mean_error_mm": float(err.mean()) if len(err) else float("nan"),
        "p95_error_mm": float(np.percentile(err, 95)) if len(err) else float("nan"),
        "points_scored": int(len(err)),
    }


def coverage_by_method(table: pd.DataFrame, truth_xyz: np.ndarray, k: float = 1.959963984540054) -> dict:
    """Per method of an XYZ table (rows aligned with `truth_xyz`), over rows with a finite XYZ, sd and
    truth: the share (%) of true errors within ±k sd per axis (k = 1.96: the 95 % interval) and how
    many rows carried an sd. Methods whose rows carry no sd are left out."""
    from .xyz import SD_COLUMNS

    out: dict = {}
    if not all(c in table.columns for c in SD_COLUMNS):
        return out
    err = table[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float) - truth_xyz
    sd = table[list(SD_COLUMNS)].to_numpy(float)
    ok = np.isfinite(err).all(axis=1) & np.isfinite(sd).all(axis=1)
    for method in dict.fromkeys(table["method"]):
        sel = ok & (table["method"] == method).to_numpy()
        if not sel.any():
            continue
        inside = np.abs(err[sel]) <= k * sd[sel]
        for i, axis in enumerate("xyz"):
            out[f"{method}_coverage95_pct_{axis}"] = float(100.0 * inside[:, i].mean())
        out[f"{method}_rows_with_sd"] = int(sel.sum())
    return out


def xyz_truth(xyz: pd.DataFrame, truth: SampleTruth, id_map: dict[int, int]) -> np.ndarray:
    """True XYZ (N, 3) of each row of a project's XYZ table (frame, marker), NaN where unknown."""
    key = pd.DataFrame({"frame": xyz["frame"].to_numpy(), "marker": xyz["marker"].map(id_map).to_numpy()})
    t = truth.trajectories[["frame", "marker", "X_mm", "Y_mm", "Z_mm"]].drop_duplicates(["frame", "marker"])
    return key.merge(t, on=["frame", "marker"], how="left")[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)


def true_points_xyz(points: pd.DataFrame, truth: SampleTruth) -> np.ndarray:
    """True world XYZ of calibration-point rows (side frame, corner_id), NaN where unknown."""
    t = truth.corners["side"][["frame", "corner_id", "X_mm", "Y_mm", "Z_mm"]]
    m = points[["frame", "corner_id"]].merge(t, on=["frame", "corner_id"], how="left")
    return m[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)


# -- calibration board detection -----------------------------------------------------------------
def board_detection(sample_dir: str | Path, camera: str, step: int = 1) -> tuple[float, np.ndarray]:
    """OpenCV's ChArUco detector on a rendered calibration video: the fraction of frames (every
    `step`-th) where the board is found, and the pixel error of every detected corner against its
    true pixel."""
    import cv2

    from .board import load_board
    from .video import FrameSource

    root = Path(sample_dir)
    detector = cv2.aruco.CharucoDetector(load_board(root / "board.toml").cv_board())
    truth = pd.read_csv(root / "ground_truth" / f"calibration_corners_{camera}.csv")
    keys = zip(truth["frame"].to_numpy(int).tolist(), truth["corner_id"].to_numpy(int).tolist(), strict=True)
    true_px = dict(zip(keys, truth[["x_px", "y_px"]].to_numpy(float), strict=True))
    n = found = 0
    errors = []
    with FrameSource(root / "calibration" / f"{camera}.mp4", cache_mb=16) as src:
        for i, img in src.iter_frames(0, len(src), step):
            n += 1
            corners, ids, _, _ = detector.detectBoard(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
            if ids is None or len(ids) < 4:
                continue
            found += 1
            errors += [float(np.hypot(*(p - true_px[(i, int(cid))])))
                       for cid, p in zip(ids.ravel(), corners.reshape(-1, 2), strict=True) if (i, int(cid)) in true_px]
    return found / max(n, 1), np.array(errors)
