"""Board corners the detector misplaced, found from their residuals against the fitted board poses.

A corner's reprojection residual (detected pixel minus the fitted board pose's corner through the calibrated
camera) is mostly detection noise of a few hundredths of a pixel, with rare corners misplaced by tenths of a
pixel to a few pixels (a marker edge taken for a square's, a blurred crossing): a heavy tail that a pooled RMS
turns into a noise level too large for the bulk and too small for the tail. A corner is misdetected when its
residual, each image axis in units of the camera's robust sd (1.4826 x the median absolute deviation), lies
farther than `LIMIT_SD` from zero (a Gaussian corner does so once in some 270,000). The camera's pixel noise is
then the other corners' residual RMS per image axis over the residuals' degrees of freedom (each frame's board
pose, fitted to them, takes 3 per image axis, shared by the cameras that see the frame), and the misdetected
corners stay out of the calibration points, whose known board position would otherwise be paired with a wrong
pixel.

Left out, because no residual against the view's own pose can show it: an error shared by all corners of one
view (a detection bias of an oblique or blurred board, a camera's timing), which that pose absorbs; the
calibration's covariance measures it from the views of one frame (view_pose_error), and the world frame's term
allows for it at its reference view (world_uncertainty.SHARED_VIEW_ERROR).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..board import BoardSpec
from ..camera import Calibration
from .detect import BoardView
from .report import corner_residuals
from .rig import fit_frame_poses

Views = dict[str, dict[int, BoardView]]

LIMIT_SD = 5.0
MAD_TO_SD = 1.4826


@dataclass
class CornerScreen:
    """The views without their misdetected corners, and per camera what was found."""

    kept: Views
    poses: dict[int, np.ndarray]  # the board poses, those of the frames that lost a corner fitted again
    misdetected: dict[str, int]  # corners left out
    corners: dict[str, int]  # corners screened (those of frames with a board pose)
    robust_sd_px: dict[str, np.ndarray]  # (2,) per image axis
    noise_px: dict[str, np.ndarray]  # (2,) the kept corners' noise per image axis (see the module's doc)
    frames_changed: list[int]  # frames that lost a corner in some camera
    limit_sd: float = LIMIT_SD

    def summary(self, name: str) -> dict:
        return {"misdetected_corners": self.misdetected[name], "corners_screened": self.corners[name],
                "misdetection_limit_sd": self.limit_sd,
                "robust_sd_px": [float(v) for v in self.robust_sd_px[name]],
                "noise_px": [float(v) for v in self.noise_px[name]]}


def screen_corners(calibration: Calibration, views: Views, board: BoardSpec, poses: dict[int, np.ndarray],
                   limit_sd: float = LIMIT_SD, rounds: int = 2) -> CornerScreen:
    """Flag each camera's misdetected corners (see the module's doc), fit again the board poses of the frames
    that lost one, and measure each camera's noise without them. A misdetected corner pulls its view's pose
    and so the residuals of the others: the flagging is repeated (`rounds`) against the poses fitted without
    the corners flagged before. A camera with too few residuals to judge (under 20) keeps every corner."""
    poses = dict(poses)
    changed: set[int] = set()
    for _ in range(max(1, rounds)):
        kept, misdetected, corners, robust, flagged = _flagged(calibration, views, board, poses, limit_sd)
        refit = sorted(flagged | changed)
        changed |= flagged
        if refit:
            poses.update(fit_frame_poses(calibration, kept, board, refit, {f: poses[f] for f in refit}))
    noise = _noise(corner_residuals(calibration, kept, board, poses))
    return CornerScreen(kept, poses, misdetected, corners, robust, noise, sorted(changed), limit_sd)


def _flagged(calibration, views, board, poses, limit_sd):
    residuals = corner_residuals(calibration, views, board, poses)
    kept: Views = {n: dict(vs) for n, vs in views.items()}
    misdetected, corners, robust = {}, {}, {}
    flagged: set[int] = set()
    for n, per_frame in residuals.items():
        allr = np.vstack(list(per_frame.values())) if per_frame else np.zeros((0, 2))
        corners[n], misdetected[n] = len(allr), 0
        if len(allr) < 20:
            robust[n] = np.sqrt(np.mean(allr ** 2, axis=0)) if len(allr) else np.full(2, np.nan)
            continue
        sd = np.maximum(MAD_TO_SD * np.median(np.abs(allr - np.median(allr, axis=0)), axis=0), 1e-6)
        robust[n] = sd
        for f, r in per_frame.items():
            ok = np.hypot(*(r / sd).T) <= limit_sd
            if not ok.all():
                v = views[n][f]
                kept[n][f] = replace(v, ids=v.ids[ok], corners=v.corners[ok])
                misdetected[n] += int((~ok).sum())
                flagged.add(f)
    return kept, misdetected, corners, robust, flagged


def _noise(residuals: dict[str, dict[int, np.ndarray]]) -> dict[str, np.ndarray]:
    """Per camera (2,): RMS residual per image axis over its degrees of freedom (a frame's pose takes 3 per
    axis, shared by the cameras that see it); NaN without residuals."""
    cameras_of = cameras_per_frame(residuals)
    out = {}
    for n, per_frame in residuals.items():
        ss = sum((np.sum(r ** 2, axis=0) for r in per_frame.values()), np.zeros(2))
        dof = sum(len(r) - 3.0 / cameras_of[f] for f, r in per_frame.items())
        out[n] = np.sqrt(ss / dof) if dof >= 1 else np.full(2, np.nan)
    return out


def cameras_per_frame(residuals: dict[str, dict[int, np.ndarray]]) -> dict[int, int]:
    """{frame: how many cameras have residuals there}."""
    out: dict[int, int] = {}
    for per_frame in residuals.values():
        for f in per_frame:
            out[f] = out.get(f, 0) + 1
    return out
