"""Geometry of the rendered rig: the sand box, the two cameras, the light.

World frame (mm): origin at the box's inner corner on the floor; X across the box width (0..500),
Y up (gravity -Y, floor at 0, undisturbed sand surface at Y = 240), Z along the box length and the
tool's travel (0..1500). Cameras follow the OpenCV convention ``x_cam = R @ X_world + t``.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.interpolate import RectBivariateSpline

from ..camera import Calibration, Camera

BOX_MM = (500.0, 500.0, 1500.0)  # X width, Y height, Z length
SAND_Y = 240.0
WIDTH, HEIGHT = 1920, 1080
FPS = 50.0
TOOL_X = 250.0  # tool path, centre of the box width
LIGHT_DIR = np.array([-0.35, 1.0, 0.3]) / np.linalg.norm([-0.35, 1.0, 0.3])  # towards the lamp

INTRINSICS = {
    # GoPro Hero 8 Black, linear lens, 1920x1080 (values from the study)
    "side": dict(fx=915.81, fy=919.63, cx=944.03, cy=544.69, dist=[0.0, 0.0, 0.0, 0.0, 0.0]),
    "front": dict(fx=913.36, fy=917.34, cx=944.89, cy=550.88, dist=[0.01, -0.01, 0.0, -0.01, 0.0]),
}

# Camera centres, look-at targets and roll (deg) in the world frame (mm).
PLACEMENT = {
    "side": dict(center=(20.0, 620.0, 610.0), target=(285.0, 240.0, 610.0), roll_deg=1.2),
    "front": dict(center=(340.0, 560.0, 1000.0), target=(268.0, 240.0, 585.0), roll_deg=-0.8),
}


def look_at(center, target, roll_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera (R, t) for a camera at `center` looking at `target`, world +Y up."""
    c = np.asarray(center, float)
    f = np.asarray(target, float) - c
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 1.0, 0.0])
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    R = np.stack([r, d, f])
    a = np.radians(roll_deg)
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    R = Rz @ R
    return R, -R @ c


def world_cameras() -> dict[str, Camera]:
    """The true cameras with extrinsics relative to the WORLD frame."""
    cams = {}
    for name, k in INTRINSICS.items():
        R, t = look_at(**PLACEMENT[name])
        K = np.array([[k["fx"], 0, k["cx"]], [0, k["fy"], k["cy"]], [0, 0, 1.0]])
        cams[name] = Camera(name, WIDTH, HEIGHT, K, np.array(k["dist"], float), cv2.Rodrigues(R)[0].ravel(), t)
    return cams


def true_calibration() -> Calibration:
    """The true rig in the project's calibration format: rig frame = side camera frame."""
    wc = world_cameras()
    Rs, ts = wc["side"].R, wc["side"].tvec
    world_from_rig = np.eye(4)
    world_from_rig[:3, :3] = Rs.T
    world_from_rig[:3, 3] = -Rs.T @ ts
    cams = {}
    for name, c in wc.items():
        R = c.R @ Rs.T
        t = c.tvec - R @ ts
        if name == "side":
            R, t = np.eye(3), np.zeros(3)
        cams[name] = Camera(name, c.width, c.height, c.matrix, c.distortion, cv2.Rodrigues(R)[0].ravel(), t)
    return Calibration(cams, world_from_rig, report={"source": "sandtrack sample: true rig (ground truth)"})


def _normalized(cam: Camera, pts: np.ndarray) -> np.ndarray:
    """Undistorted normalized image coordinates (N, 2) of distorted pixels (N, 2)."""
    if not np.any(cam.distortion):
        return (pts - cam.matrix[:2, 2]) / np.diag(cam.matrix)[:2]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)
    return cv2.undistortPoints(pts.reshape(-1, 1, 2), cam.matrix, cam.distortion, criteria=crit).reshape(-1, 2)


def pixel_rays(cam: Camera, xs: np.ndarray | None = None, ys: np.ndarray | None = None):
    """Unit ray directions in the WORLD frame for distorted pixel centres (full image by default).

    Returns (origin (3,), dirs (H, W, 3) float64) for the full grid, or dirs (N, 3) for given xs/ys.
    The full grid is undistorted exactly every 8 px and interpolated bicubically in between (the
    distortion is smooth: the rays stay within 1e-4 px of the exact ones).
    """
    if xs is None:
        step = 8
        gy = np.arange(0, cam.height + step, step, dtype=np.float64)
        gx = np.arange(0, cam.width + step, step, dtype=np.float64)
        gyy, gxx = np.meshgrid(gy, gx, indexing="ij")
        coarse = _normalized(cam, np.stack([gxx.ravel(), gyy.ravel()], axis=1)).reshape(len(gy), len(gx), 2)
        fy = np.arange(cam.height, dtype=np.float64)
        fx = np.arange(cam.width, dtype=np.float64)
        n = np.empty((cam.height, cam.width, 2))
        for c in range(2):
            spline = RectBivariateSpline(gy, gx, coarse[..., c], kx=3, ky=3)
            n[..., c] = spline(fy, fx, grid=True)
        n = n.reshape(-1, 2)
        shape = (cam.height, cam.width, 3)
    else:
        n = _normalized(cam, np.stack([np.ravel(xs), np.ravel(ys)], axis=1).astype(np.float64))
        shape = (len(n), 3)
    d_cam = np.concatenate([n, np.ones((len(n), 1))], axis=1)
    d = d_cam @ cam.R  # R^T applied to row vectors: camera -> world directions
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return cam.center_mm, d.reshape(shape)
