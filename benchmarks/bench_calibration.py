"""Calibration benchmark: accuracy against known truth and speed.

1. Real footage (../shared/data/caliscope_4cam, 4 webcams): reprojection RMSE (px, every detected
   corner, rigid board pose per frame) and board-geometry RMSE (mm, all corner-to-corner distances
   within each frame after triangulation, against the true board), for our calibration and for
   Caliscope's stored calibration measured the same way on the same detections.
2. A rendered 1920x1080 session, 100 frames per camera (H.264 videos), through known cameras:
   focal / principal point / relative pose errors, and time (wall and CPU) including detection.
3. sample_data/ (when present): errors against ground_truth/cameras.toml and the true corners.
4. The full sample preset (when the demo has rendered it into its cache): the same figures on its
   longer calibration session (2100 frames per camera, many of them motion-blurred).
5. For 3 and 4, the session's own precision: the rig calibrated again on random halves of its
   frames (same detections; at most half as many bundle views as the full run, so each half has
   half its data); the spread of the relative-pose error over the halves, divided by sqrt(2),
   estimates the spread of a full-session estimate. `rotation_expected_err_deg` /
   `translation_expected_err_mm` are the root-mean-square length of such an error: what an
   unbiased calibration of this session would miss by, from the data's noise alone.

Run: `python benchmarks/bench_calibration.py` (prints JSON), or `run()` from benchmarks/run_all.py.
"""

from __future__ import annotations

import json
import os
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sandtrack_tui.board import load_board  # noqa: E402
from sandtrack_tui.calibration.caliscope import import_caliscope  # noqa: E402
from sandtrack_tui.calibration.pipeline import MAX_BUNDLE_FRAMES, calibrate_videos  # noqa: E402
from sandtrack_tui.calibration.report import accuracy_report, relative_pose_errors  # noqa: E402
from sandtrack_tui.calibration.rig import calibrate_rig, fit_frame_poses  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "caliscope_4cam"
SAMPLE = ROOT / "sample_data"
REFERENCE = {"caliscope_0.11.8": {"reprojection_rmse_px": 0.647, "board_rmse_mm": 0.444},
             "aniposelib_0.8.0": {"reprojection_rmse_px": 0.556, "board_rmse_mm": 0.367}}


def _timed(fn):
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t, time.process_time() - c


def real_footage() -> dict:
    if not (REAL / "cam_0.mp4").exists():
        return {"skipped": f"{REAL} absent"}
    board = load_board(REAL / "charuco.toml")
    videos = {f"cam_{i}": str(REAL / f"cam_{i}.mp4") for i in range(4)}
    res, wall, cpu = _timed(lambda: calibrate_videos(videos, board))
    r = res.report
    out = {
        "reprojection_rmse_px": r["reprojection_rmse_px"],
        "board_rmse_mm": r["board_rmse_mm"],
        "board_mean_abs_mm": r["board_mean_abs_mm"],
        "corners_detected": r["corners_detected"],
        "views_used": r["views_used"],
        "per_camera_rmse_px": {n: c["reprojection_rmse_px"] for n, c in r["per_camera"].items()},
        "per_camera_misdetected_corners": {n: [c["misdetected_corners"], c["corners_screened"]]
                                           for n, c in r["per_camera"].items()},
        "per_camera_noise_px": {n: c["noise_px"] for n, c in r["per_camera"].items()},
        "view_motion": r.get("view_motion"),
        "seconds_wall": wall,
        "seconds_cpu": cpu,
        "reference_figures": REFERENCE,
    }
    # Caliscope's stored calibration, measured the same way on the same detections
    cal = import_caliscope(REAL / "camera_array.toml")
    frames = sorted(set().union(*[set(v) for v in res.views.values()]))
    poses = fit_frame_poses(cal, res.views, board, frames)
    acc = accuracy_report(cal, res.views, board, poses)
    out["caliscope_stored_same_metric"] = {"reprojection_rmse_px": acc["reprojection_rmse_px"],
                                           "board_rmse_mm": acc["board_rmse_mm"]}
    out["beats_caliscope_and_aniposelib"] = bool(
        out["reprojection_rmse_px"] < 0.556 and out["board_rmse_mm"] < 0.367)
    out.update(lens_choice_on_the_rig(res, board))
    out["parameter_sd_split_halves"] = split_half_parameters(res, board)
    out["corners_from_the_rigid_board"] = corners_from_the_rigid_board(res, board)
    out["shared_view_error"] = shared_view_error(res, board)
    return out


def shared_view_error(res, board, min_cameras: int = 3) -> dict:
    """Per camera, an error shared by all corners of one view: in frames seen by `min_cameras` or more, where
    the board's pose cannot absorb every camera's shift, the variance of each view's mean residual beyond what
    its corners' own scatter explains (px per image axis; the part no pose absorbed, so a lower bound)."""
    from sandtrack_tui.calibration.misdetections import cameras_per_frame
    from sandtrack_tui.calibration.report import corner_residuals

    residuals = corner_residuals(res.calibration, res.views, board, res.poses)
    seen = cameras_per_frame(residuals)
    out = {}
    for n, per_frame in residuals.items():
        parts = [r for f, r in per_frame.items() if len(r) >= 8 and seen[f] >= min_cameras]
        if not parts:
            continue
        counts = np.array([len(r) for r in parts], float)
        means = np.array([r.mean(axis=0) for r in parts])
        within = sum(((r - r.mean(axis=0)) ** 2).sum(axis=0) for r in parts) / np.sum(counts - 1)
        excess = np.mean(means ** 2, axis=0) - np.mean(within[None, :] / counts[:, None], axis=0)
        out[n] = {"views": len(parts), "within_view_sd_px": [round(float(v), 3) for v in np.sqrt(within)],
                  "shared_sd_px": [round(float(v), 3) for v in np.sqrt(np.clip(excess, 0, None))]}
    return out


def corners_from_the_rigid_board(res, board) -> dict:
    """The XYZ sd on real footage without a 3D truth: every board corner seen by two cameras or more,
    triangulated, against the rigid board fitted to that frame's corners (Kabsch); the share of the residuals
    within ±1.96 sd √(1 - 6 / 3n) (the fit takes 6 of the 3n coordinates), with the whole sd and with its
    pixel part alone. The fit absorbs whatever moves the whole board (a view's shared detection offset, the
    world frame), so this judges the sd's part that varies from corner to corner."""
    from sandtrack_tui.calibration.geometry import kabsch
    from sandtrack_tui.calibration.report import triangulated_corners
    from sandtrack_tui.regression.spread import coverage
    from sandtrack_tui.triangulation_sd import triangulation_sd

    cal = res.calibration
    pts = board.corner_points_mm()
    R = cal.world_from_rig[:3, :3]
    errs, whole, pixels = [], [], []
    for f, (ids, xyz, _) in triangulated_corners(cal, res.views, board, sorted(res.poses)).items():
        ok = np.isfinite(xyz).all(axis=1)
        ids, xyz = ids[ok], xyz[ok]
        if len(ids) < 6:
            continue
        px = {}
        for n in cal.names:
            v = res.views[n].get(f)
            where = {} if v is None else {int(i): k for k, i in enumerate(v.ids)}
            px[n] = np.array([v.corners[where[int(i)]] if int(i) in where else (np.nan, np.nan) for i in ids])
        T = kabsch(pts[ids], xyz)
        errs.append((xyz - (pts[ids] @ T[:3, :3].T + T[:3, 3])) @ R.T)
        k = np.sqrt(1 - 6 / (3 * len(ids)))
        whole.append(k * triangulation_sd(cal, px, xyz))
        pixels.append(k * triangulation_sd(cal, px, xyz, with_calibration=False))
    e, s, p = (np.concatenate(a) for a in (errs, whole, pixels))
    good = np.isfinite(s).all(axis=1) & np.isfinite(p).all(axis=1)
    e, s, p = e[good], s[good], p[good]
    return {"corners": int(len(e)), "frames": len(errs),
            "within_196_sd_pct": [round(100 * float(v), 1) for v in coverage(e, s)],
            "within_196_pixel_sd_pct": [round(100 * float(v), 1) for v in coverage(e, p)],
            "rms_residual_mm": [round(float(v), 3) for v in np.sqrt(np.mean(e ** 2, axis=0))],
            "median_sd_mm": [round(float(v), 3) for v in np.median(s, axis=0)]}


def _parameter_values(cam, names: list[str]) -> np.ndarray:
    """A camera's values of the covariance's parameters (rig-frame pose, matrix, distortion terms)."""
    at = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
    return np.array([cam.rvec["xyz".index(p[1])] if p in ("rx", "ry", "rz") else
                     cam.tvec["xyz".index(p[1])] if p in ("tx", "ty", "tz") else
                     cam.matrix[at[p]] if p in at else cam.distortion[int(p[1:])] for p in names])


def _chi2_of(diffs: dict) -> dict:
    """{camera: (difference, covariance)} -> chi-square per camera and in all, with degrees of freedom."""
    out, total, dof = {}, 0.0, 0
    for n, (d, cov) in diffs.items():
        chi2 = float(d @ np.linalg.solve(cov, d))
        out[n] = [round(chi2, 1), len(d)]
        total, dof = total + chi2, dof + len(d)
    return {"per_camera_chi2_dof": out, "chi2": round(total, 1), "dof": dof, "chi2_per_dof": round(total / dof, 2)}


def split_half_parameters(res, board) -> dict:
    """The calibration's parameter covariance against the data: the session calibrated on its even and on its
    odd frames (each camera's lens fixed to the whole session's choice); each camera's parameter difference
    in units of the sum of the two halves' covariances. chi2 / dof is 1 when the stated sd are honest
    (neighbouring frames are alike, so the halves are not fully independent: a lower bound)."""
    sizes = {n: (c.width, c.height) for n, c in res.calibration.cameras.items()}
    lenses = {n: c.lens for n, c in res.calibration.cameras.items()}
    halves = [calibrate_rig({n: {f: v for f, v in views.items() if f % 2 == k} for n, views in res.views.items()},
                            board, sizes, models=lenses).calibration for k in (0, 1)]
    diffs = {}
    for n in res.calibration.names:
        a, b = (h.uncertainty.get(n) for h in halves)
        if a is None or b is None or a.parameters != b.parameters:
            continue
        diffs[n] = (_parameter_values(halves[0].cameras[n], a.parameters)
                    - _parameter_values(halves[1].cameras[n], a.parameters), a.covariance + b.covariance)
    return _chi2_of(diffs)


def parameters_against_truth(res, truth) -> dict:
    """The estimated cameras' parameters minus the true ones (rig frame = the first camera's, as the truth's)
    in units of the stated covariance: chi2 / dof 1 when the stated sd are honest."""
    diffs = {}
    for n, unc in res.calibration.uncertainty.items():
        diffs[n] = (_parameter_values(res.calibration.cameras[n], unc.parameters)
                    - _parameter_values(truth.cameras[n], unc.parameters), unc.covariance)
    return _chi2_of(diffs)


def lens_choice_on_the_rig(res, board) -> dict:
    """Why the automatic lens choice and the forced standard model differ on the webcams, from the same
    detections: each camera's lens and its error alone (board views, pose per view) against its error
    in the rig; the rig with the standard model forced; the spread of the cameras' capture times
    (timestamps.csv); and a cross-validation of the whole rig over left-out frames (3 folds: the rig
    fitted on the others, each left-out frame's board pose fitted with the cameras held, its corners'
    error) for the automatic choice, the standard model and the simplest radial ones."""
    from sandtrack_tui.calibration.lens_select import Candidate, compare

    names = list(res.views)
    sizes = {n: (c.width, c.height) for n, c in res.calibration.cameras.items()}
    per = res.report["per_camera"]
    out = {"lens_auto": {n: per[n]["lens"] for n in names},
           "single_camera_rmse_px": {n: round(per[n]["rmse_px"], 4) for n in names},
           "rig_rmse_px": {n: round(per[n]["reprojection_rmse_px"], 4) for n in names}}
    stamps = REAL / "timestamps.csv"
    if stamps.exists():
        import pandas as pd

        t = pd.read_csv(stamps).groupby("sync_index")["frame_time"]
        spread = (t.max() - t.min()).to_numpy() * 1000
        out["capture_spread_ms_median_max"] = [round(float(np.median(spread)), 1), round(float(spread.max()), 1)]
    assignments = {"auto": None, "standard": "standard", "radial2": "radial2", "radial1": "radial1"}
    cands = []
    for label, lens in assignments.items():
        models = None if lens is None else dict.fromkeys(names, lens)
        rig = calibrate_rig(res.views, board, sizes, models=models)
        if lens is not None:
            frames = sorted(set().union(*[set(v) for v in res.views.values()]))
            poses = fit_frame_poses(rig.calibration, res.views, board, frames,
                                    {f: rig.frame_pose(f) for f in rig.frames})
            acc = accuracy_report(rig.calibration, res.views, board, poses)
            out[f"forced_{lens}"] = {"reprojection_rmse_px": round(acc["reprojection_rmse_px"], 4),
                                     "board_rmse_mm": round(acc["board_rmse_mm"], 4)}
        sse, cnt = _left_out_frames(rig)
        cands.append(Candidate(lens=label, parameters=0, sse=sse, count=cnt,
                               cv_rmse_px=float(np.sqrt(sse.sum() / cnt.sum()))))
    best = min(cands, key=lambda c: c.cv_rmse_px)
    out["rig_cross_validation_px"] = {c.lens: round(c.cv_rmse_px, 4) for c in cands}
    out["rig_cross_validation_within_noise_of_best"] = {  # the rule of the automatic choice
        c.lens: not compare(c, best).significant for c in cands}
    out["rig_cross_validation_best"] = best.lens
    return out


def _left_out_frames(rig, n_folds: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Squared corner errors summed per bundle frame and corner count, each frame left out once."""
    from sandtrack_tui.calibration.bundle import Observations, bundle_adjust, residuals

    st, obs = rig.state, rig.obs
    n = len(st.frame_rvec)
    sse, cnt = np.zeros(n), np.zeros(n)

    def part(frames):
        m = np.isin(obs.frame, frames)
        index = np.full(n, -1)
        index[frames] = np.arange(len(frames))
        sub = Observations(obs.cam[m], index[obs.frame[m]], obs.corner[m], obs.board_xyz[m], obs.uv[m])
        state = st.copy()
        state.frame_rvec, state.frame_tvec = st.frame_rvec[frames], st.frame_tvec[frames]
        return sub, state

    for k in range(n_folds):
        test = np.arange(k, n, n_folds)
        sub, state = part(np.setdiff1d(np.arange(n), test))
        fitted, _ = bundle_adjust(state, sub, max_iter=20)
        sub, state = part(test)
        state.cam_rvec, state.cam_tvec, state.K, state.dist = fitted.cam_rvec, fitted.cam_tvec, fitted.K, fitted.dist
        state, _ = bundle_adjust(state, sub, free_intrinsics=False, free_cameras=False, max_iter=20)
        e2 = np.sum(residuals(state, sub) ** 2, axis=1)
        sse[test] += np.bincount(sub.frame, weights=e2, minlength=len(test))
        cnt[test] += np.bincount(sub.frame, minlength=len(test))
    return sse, cnt


def _synthetic_session(n_frames: int = 100, size=(1920, 1080), seed: int = 7) -> dict:
    from sandtrack_tui.calibration.synthetic import write_session

    cache = Path(tempfile.gettempdir()) / f"sandtrack_bench_calib_{size[0]}x{size[1]}_{n_frames}_{seed}"
    meta = cache / "session.pkl"
    if meta.exists():
        with open(meta, "rb") as fh:
            return pickle.load(fh)
    cache.mkdir(parents=True, exist_ok=True)
    s = write_session(cache, n_frames, size=size, video_fps=50, seed=seed)
    with open(meta, "wb") as fh:
        pickle.dump(s, fh)
    return s


def synthetic_speed() -> dict:
    s = _synthetic_session()
    res, wall, cpu = _timed(lambda: calibrate_videos(s["videos"], s["board"], reference_frame=0))
    err = relative_pose_errors(res.calibration, s["truth"])
    r = res.report
    return {
        "frames_per_camera": 100, "size": "1920x1080",
        "seconds_wall": wall, "seconds_cpu": cpu,
        "seconds_detect_wall": r["seconds_detect"], "seconds_calibrate_wall": r["seconds_calibrate"],
        "frames_detected": r["frames_detected"], "views_used": r["views_used"],
        "reprojection_rmse_px": r["reprojection_rmse_px"], "board_rmse_mm": r["board_rmse_mm"],
        "focal_rel_err": err["focal_rel_err"], "principal_point_err_px": err["principal_point_err_px"],
        "rotation_err_deg": err["rotation_err_deg"], "translation_err_mm": err["translation_err_mm"],
        "load_average": os.getloadavg()[0],
    }


def run() -> dict:
    return {"real_footage_caliscope_4cam": real_footage(), "synthetic_1080p_100_frames": synthetic_speed(),
            "sample_data": sample_data_figures(), "full_preset": full_preset_figures()}


def full_preset_figures() -> dict:
    """The full preset's calibration session, when `sandtrack demo` has rendered it (else skipped)."""
    from sandtrack_tui.demo import cache_dir

    found = sorted(cache_dir().glob("sample-full-seed0-*/ground_truth/cameras.toml"))
    if not found:
        return {"skipped": "full preset not rendered (run `sandtrack demo` once)"}
    return sample_data_figures(found[-1].parents[1], with_points=False)


def sample_data_figures(folder: Path = SAMPLE, with_points: bool = True) -> dict:
    """Against a rendered sample preset's true cameras (skipped when the folder is absent)."""
    cal_dir = folder / "calibration"
    truth_file = folder / "ground_truth" / "cameras.toml"
    if not (cal_dir / "side.mp4").exists() or not truth_file.exists():
        return {"skipped": f"{folder} absent"}
    from sandtrack_tui.calibration.world import load_reference
    from sandtrack_tui.camera import Calibration

    board = load_board(folder / "board.toml")
    ref_frame, origin = (None, (0.0, 0.0, 0.0))
    if (cal_dir / "reference.toml").exists():
        ref_frame, origin = load_reference(cal_dir / "reference.toml")
    videos = {"side": str(cal_dir / "side.mp4"), "front": str(cal_dir / "front.mp4")}
    res, wall, cpu = _timed(lambda: calibrate_videos(videos, board, reference_frame=ref_frame, origin_mm=origin,
                                                     with_points=with_points))
    truth = Calibration.load(truth_file)
    err = relative_pose_errors(res.calibration, truth)
    tag = "with_points" if with_points else "without_points"
    out = {
        f"seconds_wall_{tag}": wall, f"seconds_cpu_{tag}": cpu,
        "seconds_detect_wall": res.report["seconds_detect"],
        "reprojection_rmse_px": res.report["reprojection_rmse_px"], "board_rmse_mm": res.report["board_rmse_mm"],
        "focal_rel_err": err["focal_rel_err"], "principal_point_err_px": err["principal_point_err_px"],
        "rotation_err_deg": err["rotation_err_deg"], "translation_err_mm": err["translation_err_mm"],
        "frames_detected": res.report["frames_detected"], "views_used": res.report["views_used"],
        "blurred_views_skipped": res.report["blurred_views_skipped"],
    }
    if res.points is not None:
        out["points_rows"] = int(len(res.points))
        out.update(_points_vs_truth(res, truth, folder))
    out.update(_corners_vs_truth(res, folder))
    out.update(half_sample_precision(res, board, truth))
    out["parameter_sd_against_truth"] = parameters_against_truth(res, truth)
    out["view_motion"] = res.report.get("view_motion")
    return out


def _corners_vs_truth(res, folder: Path) -> dict:
    """Every detected corner against its true pixel (the rendered cameras start whole frames apart, so no
    view is interpolated between two frames)."""
    import pandas as pd

    out = {}
    for cam, views in res.views.items():
        gt = pd.read_csv(folder / "ground_truth" / f"calibration_corners_{cam}.csv")
        truth = {(int(f), int(c)): (x, y) for f, c, x, y in gt[["frame", "corner_id", "x_px", "y_px"]].to_numpy()}
        err = [np.hypot(*(p - truth[(v.source_frame, int(c))])) for v in views.values() if v.source_frame >= 0
               for c, p in zip(v.ids, v.corners, strict=True) if (v.source_frame, int(c)) in truth]
        err = np.array(err)
        out[f"{cam}_corner_err_px_median_rms"] = [round(float(np.median(err)), 3),
                                                   round(float(np.sqrt(np.mean(err ** 2))), 3)]
    return out


def half_sample_precision(res, board, truth, halves: int = 16, seed: int = 1) -> dict:
    """Spread of the relative pose over calibrations on random halves of the session's frames."""
    views = res.views
    names = list(views)
    sizes = {n: (res.calibration.cameras[n].width, res.calibration.cameras[n].height) for n in names}
    frames = np.array(sorted(set().union(*[set(v) for v in views.values()])))
    rng = np.random.default_rng(seed)
    rot, trans = [], []
    for _ in range(halves):
        half = set(rng.choice(frames, len(frames) // 2, replace=False).tolist())
        part = {n: {f: v for f, v in views[n].items() if f in half} for n in names}
        rig = calibrate_rig(part, board, sizes, max_frames=MAX_BUNDLE_FRAMES // 2)
        second = relative_pose_errors(rig.calibration, truth)["per_camera"][truth.names[1]]
        rot.append(second["rotation_err_vec_deg"])
        trans.append(second["translation_err_vec_mm"])
    sd_r = np.std(rot, axis=0, ddof=1) / np.sqrt(2)
    sd_t = np.std(trans, axis=0, ddof=1) / np.sqrt(2)
    return {"precision_halves": halves, "rotation_sd_deg_per_axis": [round(float(v), 4) for v in sd_r],
            "rotation_expected_err_deg": float(np.sqrt(np.sum(sd_r ** 2))),
            "translation_sd_mm_per_axis": [round(float(v), 3) for v in sd_t],
            "translation_expected_err_mm": float(np.sqrt(np.sum(sd_t ** 2)))}


def _points_vs_truth(res, truth, folder: Path = SAMPLE) -> dict:
    """Mean distance of the points table's XYZ (and of triangulated pixels) from the true world
    corners, using the true cameras to place the truth when no corner table is available."""
    from sandtrack_tui.triangulation import triangulate

    pts = res.points
    if pts is None or not len(pts):
        return {}
    px = {"side": pts[["xs", "ys"]].to_numpy(float), "front": pts[["xf", "yf"]].to_numpy(float)}
    xyz_est, _ = triangulate(res.calibration, px, refine=True)
    xyz_true, _ = triangulate(truth, px, refine=True)
    table = pts[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
    out = {
        "triangulated_vs_true_cameras_mean_mm": float(np.nanmean(np.linalg.norm(xyz_est - xyz_true, axis=1))),
        "points_table_vs_true_cameras_mean_mm": float(np.nanmean(np.linalg.norm(table - xyz_true, axis=1))),
    }
    corners_csv = folder / "ground_truth" / "calibration_corners_side.csv"
    if corners_csv.exists():
        import pandas as pd

        gt = pd.read_csv(corners_csv).set_index(["frame", "corner_id"])
        keys = list(zip(pts.frame, pts.corner_id, strict=True))
        ok = np.array([k in gt.index for k in keys])
        true_xyz = gt.loc[[k for k, o in zip(keys, ok, strict=True) if o], ["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
        out["triangulated_corners_vs_truth_mean_mm"] = float(np.nanmean(np.linalg.norm(xyz_est[ok] - true_xyz, axis=1)))
        out["triangulated_corners_true_calibration_mean_mm"] = float(
            np.nanmean(np.linalg.norm(xyz_true[ok] - true_xyz, axis=1)))
        out["points_table_vs_truth_mean_mm"] = float(np.nanmean(np.linalg.norm(table[ok] - true_xyz, axis=1)))
    return out


if __name__ == "__main__":
    print(json.dumps(run(), indent=2, default=float))
