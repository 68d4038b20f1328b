"""The epipolar curve of a pixel: where the point seen at pixel p in camera a can appear in camera b.

With lens distortion this is a curve, not a line, so it is sampled: points along camera a's ray
through p at depths from `near_mm` to `far_mm` are projected into camera b (distorted pixels).
"""

from __future__ import annotations

import numpy as np

from .camera import Calibration


def epipolar_curve(calibration: Calibration, cam_a: str, px_a, cam_b: str, near_mm: float = 50.0,
                   far_mm: float = 20_000.0, samples: int = 400) -> np.ndarray:
    """(N, 2) distorted pixels of camera b along the epipolar curve of `px_a` (one pixel of camera a),
    ordered by depth in camera a; only points in front of camera b."""
    a, b = calibration.cameras[cam_a], calibration.cameras[cam_b]
    u = a.undistort(np.asarray(px_a, dtype=float).reshape(1, 2))[0]
    ray = np.linalg.inv(a.matrix) @ np.array([u[0], u[1], 1.0])
    depths = np.geomspace(near_mm, far_mm, samples)
    pts_cam_a = depths[:, None] * ray[None, :]
    pts_rig = (pts_cam_a - a.tvec) @ a.R  # R^T (x - t), row-wise
    z_b = pts_rig @ b.R.T[:, 2] + b.tvec[2]
    pts_rig = pts_rig[z_b > 1.0]
    if len(pts_rig) < 2:
        return np.zeros((0, 2))
    return b.project(pts_rig)
