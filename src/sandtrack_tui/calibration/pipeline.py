"""`calibrate_videos`: videos (or image folders) of a moving board -> Calibration, report and the
calibration points. Used by the CLI, the demo and the TUI.

Detection first runs on a subsample of the frames (at most `detect_budget` per camera); when that
gives too few views seen by two cameras, the frames in between are added. The calibration points
need every frame, so they trigger detection of the rest.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ..board import BoardSpec
from ..camera import Calibration
from ..errors import SandtrackError
from .detect import BoardView, detect_in_sources, detection_stride, frame_pairing, open_source
from .misdetections import screen_corners
from .model_choice import spread_line
from .points import calibration_points
from .region import covered_pct, image_region
from .report import accuracy_report, camera_parameters
from .rig import calibrate_rig, fit_frame_poses
from .world import describe, world_from_board_pose, world_from_known_points
from .world_uncertainty import SHARED_VIEW_ERROR, board_reference, known_points_reference, rig_frame

ProgressFn = Callable[[str, int, int], None]
MIN_SHARED_VIEWS = 12
MAX_RMSE_PX = 3.0
MAX_BUNDLE_FRAMES = 200  # board frames in the bundle adjustment at most (spread evenly over the session)


def _offsets(videos, sources, given: dict[str, float] | None, warnings: list[str]) -> tuple[dict, dict]:
    """Start offsets of the cameras against the first one: as given, else from the audio (or the
    video fallback) of `sandtrack_tui.sync`, else 0 with a warning."""
    names = list(videos)
    offsets = dict(given or {})
    info: dict = {n: {"offset_s": offsets[n], "method": "given"} for n in offsets}
    for n in names[1:]:
        if n in offsets:
            continue
        if sources[names[0]].is_folder or sources[n].is_folder:
            offsets[n] = 0.0
            info[n] = {"offset_s": 0.0, "method": "image folders: taken as simultaneous"}
            continue
        try:
            res, weak = _audio_offset(videos[names[0]], videos[n])
            offsets[n] = float(res.offset_s)
            info[n] = {"offset_s": offsets[n], "method": res.method + (" (weak)" if weak else ""),
                       "confidence": float(res.confidence)}
            if weak:
                warnings.append(f"the clap was heard only weakly in {n} (sync confidence {res.confidence:.2f}): its "
                                f"best guess, {1000 * offsets[n]:+.1f} ms, is used; check the reprojection error, or "
                                "give the offset (--offset-s)")
        except SandtrackError as exc:
            offsets[n] = 0.0
            info[n] = {"offset_s": 0.0, "method": "none"}
            warnings.append(f"could not synchronise {n} with {names[0]} ({exc}); assuming they started together")
    return offsets, info


def _audio_offset(reference, other):
    """(SyncResult, weak) from the clap: a clap heard, not clearly, gives its best guess (weak), which the
    board's reprojection error checks (a wrong offset makes the cameras disagree), rather than no offset."""
    from ..sync import LowConfidence, estimate_offset

    try:
        return estimate_offset(reference, other, method="audio"), False
    except LowConfidence:
        return estimate_offset(reference, other, method="audio", min_confidence=0.0), True


@dataclass
class CalibrationResult:
    calibration: Calibration
    report: dict
    views: dict[str, dict[int, BoardView]]
    poses: dict[int, np.ndarray]  # board -> rig per frame
    points: pd.DataFrame | None = None
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        r = self.report
        return {k: r.get(k) for k in ("reprojection_rmse_px", "board_rmse_mm", "per_camera", "views_used", "points",
                                      "seconds", "frames_detected", "world", "warnings")}


def _shared_count(views, names) -> int:
    frames = set().union(*[set(views[n]) for n in names])
    return sum(1 for f in frames if sum(f in views[n] for n in names) >= 2)


def fitted_corners(views: dict[str, dict[int, BoardView]], frames: list[int]) -> dict[str, np.ndarray]:
    """Per camera, the pixels of its corners in the bundle adjustment's frames (N, 2)."""
    return {n: np.vstack([vs[f].corners for f in frames if f in vs] or [np.zeros((0, 2))]) for n, vs in views.items()}


def calibrate_videos(videos: dict[str, str | Path], board: BoardSpec, *, offsets_s: dict[str, float] | None = None,
                     reference_frame: int | None = None, origin_mm=(0.0, 0.0, 0.0),
                     known_points: pd.DataFrame | None = None, with_points: bool = False,
                     models: dict[str, str] | None = None, detect_budget: int = 400,
                     max_bundle_frames: int = MAX_BUNDLE_FRAMES, progress: ProgressFn | None = None,
                     workers: int = 2) -> CalibrationResult:
    """Calibrate the cameras of `videos` ({name: path}, first = reference/rig camera).

    reference_frame: a frame (of the first camera) where the board lies flat on the sand; defines
    the world frame (see world.py) with the board origin at `origin_mm`. known_points: a table of
    `X_mm, Y_mm, Z_mm` plus pixel columns per camera (x_NAME, y_NAME or xs, ys / xf, yf) for a
    Kabsch world frame instead. Without either, world = rig frame (first camera)."""
    t0 = time.perf_counter()
    if len(videos) < 2:
        raise SandtrackError("calibration needs videos from at least two cameras")
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:  # each opening reads the whole file's index
        sources = dict(zip(videos, pool.map(open_source, videos.values()), strict=True))
    names = list(sources)
    warnings: list[str] = []
    offsets_s, sync_info = _offsets(videos, sources, offsets_s, warnings)
    pairing = frame_pairing(sources, offsets_s)
    n_ref = len(sources[names[0]])
    if reference_frame is not None and not 0 <= reference_frame < n_ref:
        raise SandtrackError(f"reference frame {reference_frame} is outside the video (0..{n_ref - 1})")
    stride = detection_stride(n_ref, detect_budget)
    first = set(range(0, n_ref, stride))
    if reference_frame is not None:
        first.add(reference_frame)
    views = detect_in_sources(sources, board, sorted(first), pairing, progress, workers=workers)
    detected = set(first)
    step = stride
    # add the frames in between only when every camera has seen the board at all
    while all(views[n] for n in names) and _shared_count(views, names) < MIN_SHARED_VIEWS and step > 1:
        step = max(1, step // 2)
        more = sorted(set(range(0, n_ref, step)) - detected)
        extra = detect_in_sources(sources, board, more, pairing, progress, workers=workers)
        for n in names:
            views[n].update(extra[n])
        detected |= set(more)
    t_detect = time.perf_counter() - t0
    for n in names:
        if not views[n]:
            raise SandtrackError(
                f"no board found in camera {n} ({videos[n]}, {len(detected)} frames searched): check that the board "
                "file (columns, rows, dictionary, inverted) matches the printed board, and record it sharp, well lit "
                "and filling a good part of the image")
    sizes = {n: (s.width, s.height) for n, s in sources.items()}
    rig = calibrate_rig(views, board, sizes, models=models, max_frames=max_bundle_frames, progress=progress,
                        workers=workers)
    t_calib = time.perf_counter() - t0 - t_detect
    if with_points:
        rest = sorted(set(range(n_ref)) - detected)
        if rest:
            extra = detect_in_sources(sources, board, rest, pairing, progress, workers=workers)
            for n in names:
                views[n].update(extra[n])
            detected |= set(rest)
    calibration = rig.calibration
    all_frames = sorted(set().union(*[set(views[n]) for n in names]))
    initial = {f: rig.frame_pose(f) for f in rig.frames}
    poses = fit_frame_poses(calibration, views, board, all_frames, initial)
    screen = screen_corners(calibration, views, board, poses)
    # the report's figures keep their usual meaning (every corner, each pose fitted to all of its corners);
    # the points and the world frame take the poses fitted without the misdetected corners
    poses_all = poses
    kept, poses = screen.kept, screen.poses
    for n, unc in calibration.uncertainty.items():
        if np.isfinite(screen.noise_px[n]).all():
            unc.noise_px = [float(v) for v in screen.noise_px[n]]
            # each view's pose absorbed what its corners share, so no residual shows it: a Type B allowance
            unc.view_shared_px = [SHARED_VIEW_ERROR * float(v) for v in screen.noise_px[n]]
    # world frame
    world: dict = {"method": "rig frame (no reference given)"}
    warnings += rig.warnings
    joint = (rig.joint_parameters, rig.joint_covariance) if rig.joint_covariance is not None else None
    if joint is not None:
        calibration.rig_uncertainty = rig_frame(*joint)
    if known_points is not None:
        from ..triangulation import triangulate
        from .points import pixel_columns

        cols = pixel_columns(names)
        px = {n: known_points[list(cols[n])].to_numpy(float) for n in names if set(cols[n]) <= set(known_points)}
        xyz, _ = triangulate(calibration, px, refine=True, world=False)
        T, res = world_from_known_points(xyz, known_points[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float))
        calibration.world_from_rig = T
        world = {"method": "known points (Kabsch)", "points": int(len(known_points)), "rmse_mm": res}
        if joint is not None:
            calibration.rig_uncertainty = known_points_reference(
                calibration, px, known_points[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float), *joint)
    elif reference_frame is not None:
        if reference_frame not in poses:
            raise SandtrackError(
                f"the board was not found in reference frame {reference_frame}: pick a frame where the board lies "
                "flat on the sand and is fully visible")
        calibration.world_from_rig = world_from_board_pose(poses[reference_frame], origin_mm)
        if joint is not None:
            calibration.rig_uncertainty = board_reference(
                calibration, {n: kept[n][reference_frame] for n in names if reference_frame in kept[n]}, board,
                poses[reference_frame], origin_mm, *joint)
        world = {"method": "board lying flat in a reference frame", "frame": int(reference_frame),
                 "origin_mm": [float(v) for v in origin_mm]}
    else:
        warnings.append("no reference frame: the world frame is the first camera's frame")
    world.update(describe(calibration.world_from_rig))
    if calibration.rig_uncertainty is not None:
        world.update(calibration.rig_uncertainty.world_frame_sd() or {})
    acc = accuracy_report(calibration, views, board, poses_all)
    points = calibration_points(calibration, kept, board, poses, names[:2]) if with_points else None
    per_camera = {}
    fitted = fitted_corners(views, rig.frames)
    for n in names:
        r = rig.intrinsics[n].report()
        # the single-camera fit (its RMSE: rmse_px) that started the bundle adjustment, apart from the
        # cameras the calibration file holds
        r["single_camera_fit"] = {k: r.pop(k) for k in ("fx", "fy", "cx", "cy", "distortion")}
        r.update(camera_parameters(calibration, n))
        r["reprojection_rmse_px"] = acc["per_camera_reprojection_rmse_px"].get(n)
        r.update(screen.summary(n))
        if (unc := calibration.uncertainty.get(n)) is not None and unc.view_shared_px is not None:
            r["view_shared_px"] = list(unc.view_shared_px)
        r["frames_with_board"] = len(views[n])
        r["mirrored_views"] = sum(v.mirrored for v in views[n].values())
        r["calibrated_region_pct"] = covered_pct(fitted[n], sizes[n])
        spread = rig.bundle.get("lens_choice_spread", {}).get(n)
        if spread and r.get("lens_selection"):
            r["lens_selection"]["spread"] = spread_line(spread["kept"], spread["better_fitting"],
                                                        spread["shift_of_better_fitting"])
        per_camera[n] = r
    view_motion = rig.bundle.pop("view_motion", None)
    report = {
        "reprojection_rmse_px": acc["reprojection_rmse_px"],
        "board_rmse_mm": acc["board_rmse_mm"],
        "board_mean_abs_mm": acc["board_mean_abs_mm"],
        "corner_to_board_mean_mm": acc["corner_to_board_mean_mm"],
        "corners_detected": acc["corners_detected"],
        "per_camera": per_camera,
        "views_used": len(rig.frames),
        "frames_detected": len(detected),
        "frames_with_board": len(all_frames),
        "near_duplicates_skipped": rig.skipped_duplicates,
        "blurred_views_skipped": rig.skipped_blurred,
        "bundle": rig.bundle,
        "view_motion": view_motion,
        "board": board.to_json_dict(),
        "sync": sync_info,
        "world": world,
        "points": int(len(points)) if points is not None else 0,
        "seconds": time.perf_counter() - t0,
        "seconds_detect": t_detect,
        "seconds_calibrate": t_calib,
        "warnings": warnings,
    }
    calibration.report = report
    calibration.regions = {n: r for n, px in fitted.items() if (r := image_region(px)) is not None}
    if report["reprojection_rmse_px"] > MAX_RMSE_PX:
        raise SandtrackError(
            f"the cameras disagree (reprojection RMSE {report['reprojection_rmse_px']:.1f} px): the videos are "
            "probably not in sync; give the offset (--offset-s, see `sandtrack sync`) or record a clap at the start")
    return CalibrationResult(calibration=calibration, report=report, views=views, poses=poses, points=points,
                             warnings=warnings)
