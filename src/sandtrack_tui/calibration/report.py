"""Accuracy figures of a calibration against its own board detections.

- reprojection RMSE (px): every detected corner of every camera against the reprojection of the
  board corner under the fitted board pose of its frame (cameras fixed);
- board-geometry RMSE (mm): per frame, each corner seen by two or more cameras is triangulated,
  and the distances between all pairs of triangulated corners of that frame are compared with the
  same distances on the true board.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..board import BoardSpec
from ..camera import Calibration
from ..triangulation import triangulate
from .detect import BoardView
from .geometry import inv_T

Views = dict[str, dict[int, BoardView]]


MATRIX = ("fx", "fy", "cx", "cy")


def camera_parameters(calibration: Calibration, name: str) -> dict:
    """A calibrated camera's matrix and lens as written to the calibration file (px), with the sd of each
    matrix term from the calibration's parameter covariance (``fx_sd_px`` ...; absent without one)."""
    cam = calibration.cameras[name]
    K = cam.matrix
    out = {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2]),
           "distortion": [float(v) for v in cam.distortion]}
    unc = calibration.uncertainty.get(name)
    if unc is not None:
        sd = np.sqrt(np.clip(np.diag(unc.covariance), 0.0, None))
        out.update({f"{p}_sd_px": float(sd[unc.parameters.index(p)]) for p in MATRIX if p in unc.parameters})
    return out


def corner_residuals(calibration: Calibration, views: Views, board: BoardSpec,
                     poses: dict[int, np.ndarray]) -> dict[str, dict[int, np.ndarray]]:
    """{camera: {frame: (n, 2) detected minus projected pixel}} for the frames with a pose."""
    pts = board.corner_points_mm()
    out: dict[str, dict[int, np.ndarray]] = {}
    for n, cam in calibration.cameras.items():
        out[n] = {}
        for f, v in views.get(n, {}).items():
            T = poses.get(f)
            if T is not None and len(v):
                out[n][f] = v.corners - cam.project(pts[v.ids] @ T[:3, :3].T + T[:3, 3])
    return out


def reprojection_errors(calibration: Calibration, views: Views, board: BoardSpec,
                        poses: dict[int, np.ndarray]) -> dict[str, np.ndarray]:
    """Per camera, the pixel error of every detected corner in the frames that have a pose."""
    return {n: np.concatenate([np.linalg.norm(r, axis=1) for r in per_frame.values()]) if per_frame
            else np.zeros(0) for n, per_frame in corner_residuals(calibration, views, board, poses).items()}


def triangulated_corners(calibration: Calibration, views: Views, board: BoardSpec, frames,
                         refine: bool = True) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """{frame: (corner ids, rig-frame xyz (n, 3), residual px)} for corners seen by >= 2 cameras."""
    names = [n for n in calibration.names if n in views]
    out = {}
    batch_ids, batch_px, batch_frames = [], {n: [] for n in names}, []
    for f in frames:
        seen = [n for n in names if f in views[n]]
        if len(seen) < 2:
            continue
        ids = np.unique(np.concatenate([views[n][f].ids for n in seen]))
        for n in names:
            px = np.full((len(ids), 2), np.nan)
            v = views[n].get(f)
            if v is not None:
                px[np.searchsorted(ids, v.ids)] = v.corners
            batch_px[n].append(px)
        batch_ids.append(ids)
        batch_frames.append(f)
    if not batch_ids:
        return out
    pixels = {n: np.concatenate(batch_px[n]) for n in names}
    xyz, res = triangulate(calibration, pixels, refine=refine, world=False)
    k = 0
    for f, ids in zip(batch_frames, batch_ids, strict=True):
        sl = slice(k, k + len(ids))
        ok = np.isfinite(xyz[sl]).all(axis=1)
        if ok.sum() >= 2:
            out[f] = (ids[ok], xyz[sl][ok], res[sl][ok])
        k += len(ids)
    return out


def board_geometry_errors(tri: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]], board: BoardSpec) -> np.ndarray:
    """Errors (mm) of all corner-to-corner distances within each frame against the true board."""
    pts = board.corner_points_mm()
    errs = []
    for ids, xyz, _ in tri.values():
        i, j = np.triu_indices(len(ids), k=1)
        d = np.linalg.norm(xyz[i] - xyz[j], axis=1)
        d_true = np.linalg.norm(pts[ids[i]] - pts[ids[j]], axis=1)
        errs.append(d - d_true)
    return np.concatenate(errs) if errs else np.zeros(0)


def rms(a: np.ndarray) -> float:
    a = np.asarray(a, dtype=float)
    return float(np.sqrt(np.mean(a ** 2))) if len(a) else float("nan")


def accuracy_report(calibration: Calibration, views: Views, board: BoardSpec, poses: dict[int, np.ndarray]) -> dict:
    reproj = reprojection_errors(calibration, views, board, poses)
    tri = triangulated_corners(calibration, views, board, sorted(poses))
    geo = board_geometry_errors(tri, board)
    allr = np.concatenate(list(reproj.values())) if reproj else np.zeros(0)
    # distance of each triangulated corner from the corner of the fitted rigid board pose
    pts = board.corner_points_mm()
    dev = [np.linalg.norm(xyz - (pts[ids] @ poses[f][:3, :3].T + poses[f][:3, 3]), axis=1)
           for f, (ids, xyz, _) in tri.items() if f in poses]
    dev = np.concatenate(dev) if dev else np.zeros(0)
    return {
        "reprojection_rmse_px": rms(allr),
        "board_rmse_mm": rms(geo),
        "board_mean_abs_mm": float(np.mean(np.abs(geo))) if len(geo) else float("nan"),
        "board_pairs": int(len(geo)),
        "corner_to_board_mean_mm": float(np.mean(dev)) if len(dev) else float("nan"),
        "corners_detected": int(len(allr)),
        "corners_triangulated": int(sum(len(t[0]) for t in tri.values())),
        "per_camera_reprojection_rmse_px": {n: rms(e) for n, e in reproj.items()},
    }


def relative_pose_errors(est: Calibration, truth: Calibration) -> dict:
    """Compare cameras of two calibrations (same names): focal, principal point, relative rotation and
    translation of every camera against the first one."""
    names = [n for n in truth.names if n in est.cameras]
    out = {"per_camera": {}}
    ref = names[0]
    Te0 = _T(est.cameras[ref])
    Tt0 = _T(truth.cameras[ref])
    worst_rot = worst_t = 0.0
    for n in names:
        e, t = est.cameras[n], truth.cameras[n]
        d = {
            "focal_rel_err": float(max(abs(e.matrix[0, 0] / t.matrix[0, 0] - 1),
                                       abs(e.matrix[1, 1] / t.matrix[1, 1] - 1))),
            "principal_point_err_px": float(np.hypot(e.matrix[0, 2] - t.matrix[0, 2], e.matrix[1, 2] - t.matrix[1, 2])),
        }
        if n != ref:
            Re = _T(e) @ inv_T(Te0)
            Rt = _T(t) @ inv_T(Tt0)
            c = (np.trace(Re[:3, :3] @ Rt[:3, :3].T) - 1) / 2
            d["rotation_err_deg"] = float(np.degrees(np.arccos(np.clip(c, -1, 1))))
            d["translation_err_mm"] = float(np.linalg.norm(Re[:3, 3] - Rt[:3, 3]))
            # the same errors as vectors (rotation vector of est * truth^-1, in degrees; rig-frame mm)
            d["rotation_err_vec_deg"] = np.degrees(cv2.Rodrigues(Re[:3, :3] @ Rt[:3, :3].T)[0].ravel()).tolist()
            d["translation_err_vec_mm"] = (Re[:3, 3] - Rt[:3, 3]).tolist()
            worst_rot = max(worst_rot, d["rotation_err_deg"])
            worst_t = max(worst_t, d["translation_err_mm"])
        out["per_camera"][n] = d
    out["rotation_err_deg"] = worst_rot
    out["translation_err_mm"] = worst_t
    out["focal_rel_err"] = max(v["focal_rel_err"] for v in out["per_camera"].values())
    out["principal_point_err_px"] = max(v["principal_point_err_px"] for v in out["per_camera"].values())
    return out


def _T(cam) -> np.ndarray:
    from .geometry import to_T

    return to_T(cam.rvec, cam.tvec)
