"""A synthetic two-camera rig and volume-filling calibration points with exact ground truth.

Used by the regression tests and benchmark when no rendered sample data is at hand: a board is
moved through the measurement volume (as in the study), its inner corners are projected through a
known rig and get Gaussian detection noise. The world frame follows the project's convention:
X across the box, Y up (sand surface at Y = 0), Z along the tool's travel, mm.
"""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd

from ..camera import Calibration, Camera

POINT_COLUMNS = ["frame", "corner_id", "xs", "ys", "xf", "yf", "X_mm", "Y_mm", "Z_mm"]


def _look_at(centre: np.ndarray, target: np.ndarray, up=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera rotation and translation (OpenCV axes: x right, y down, z forward)."""
    z = target - centre
    z = z / np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def study_rig() -> Calibration:
    """Side and front GoPro-like cameras (1920x1080) ~0.8 m from the sand, about 90 degrees apart,
    with the intrinsics of the study's calibration. The rig frame is the side camera's frame."""
    target = np.array([0.0, 30.0, 0.0])
    Rs, ts = _look_at(np.array([-760.0, 260.0, 40.0]), target)
    Rf, tf = _look_at(np.array([30.0, 330.0, 720.0]), target)
    # front camera relative to the side camera (= rig frame)
    R_rel = Rf @ Rs.T
    t_rel = tf - R_rel @ ts
    side = Camera("side", 1920, 1080, [[915.81, 0, 944.03], [0, 919.63, 544.69], [0, 0, 1]],
                  [0.0, 0.0, 0.0, 0.0, 0.0])
    front = Camera("front", 1920, 1080, [[913.36, 0, 944.89], [0, 917.34, 550.88], [0, 0, 1]],
                   [0.01, -0.01, 0.0, -0.01, 0.0], rvec=cv2.Rodrigues(R_rel)[0].ravel(), tvec=t_rel)
    world_from_rig = np.eye(4)
    world_from_rig[:3, :3] = Rs.T
    world_from_rig[:3, 3] = -Rs.T @ ts
    return Calibration({"side": side, "front": front}, world_from_rig)


def board_corners_mm(columns: int = 11, rows: int = 8, square_mm: float = 25.0) -> np.ndarray:
    """Inner corners of a columns x rows board, centred, in the board plane (z = 0)."""
    gx, gy = np.meshgrid(np.arange(1, columns), np.arange(1, rows))
    pts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1) * square_mm
    return pts - pts.mean(axis=0)


def calibration_points(calibration: Calibration | None = None, n_points: int = 44_130, seed: int = 0,
                       noise_px: float = 0.3, volume_mm=((-200, 200), (0, 160), (-220, 220)),
                       columns: int = 11, rows: int = 8, square_mm: float = 25.0,
                       margin_px: float = 8.0) -> pd.DataFrame:
    """Points as `points.csv` (frame, corner_id, xs, ys, xf, yf, X_mm, Y_mm, Z_mm): board poses
    drawn uniformly through `volume_mm` (board centre ranges per world axis), tilted at random
    around the direction that faces both cameras; only corners seen by both cameras are kept.
    XYZ are exact; pixels carry Gaussian noise of `noise_px` per coordinate."""
    cal = calibration or study_rig()
    rng = np.random.default_rng(seed)
    corners = board_corners_mm(columns, rows, square_mm)
    cams = [cal.cameras["side"], cal.cameras["front"]]
    centres_w = [cal.to_world(c.center_mm[None])[0] for c in cams]
    lo = np.array([v[0] for v in volume_mm], float)
    hi = np.array([v[1] for v in volume_mm], float)
    chunks, total, frame = [], 0, 0
    while total < n_points:
        centre = lo + rng.random(3) * (hi - lo)
        facing = sum((c - centre) / np.linalg.norm(c - centre) for c in centres_w)
        normal = _tilt(facing / np.linalg.norm(facing), rng.uniform(0, np.radians(35)), rng)
        R = _frame_from_normal(normal, rng.uniform(0, 2 * np.pi))
        world = corners @ R.T + centre
        keep = np.ones(len(world), bool)
        pix = []
        for cam, cw in zip(cams, centres_w, strict=True):
            view = (cw - world) / np.linalg.norm(cw - world, axis=1, keepdims=True)
            keep &= view @ normal > np.cos(np.radians(78))
            px = cam.project(cal.to_rig(world))
            keep &= (px[:, 0] > margin_px) & (px[:, 0] < cam.width - margin_px)
            keep &= (px[:, 1] > margin_px) & (px[:, 1] < cam.height - margin_px)
            pix.append(px)
        idx = np.nonzero(keep)[0]
        if len(idx) < 6:
            continue
        idx = idx[: n_points - total]
        noisy = [p[idx] + rng.normal(0, noise_px, (len(idx), 2)) for p in pix]
        chunks.append(pd.DataFrame({
            "frame": frame, "corner_id": idx,
            "xs": noisy[0][:, 0], "ys": noisy[0][:, 1], "xf": noisy[1][:, 0], "yf": noisy[1][:, 1],
            "X_mm": world[idx, 0], "Y_mm": world[idx, 1], "Z_mm": world[idx, 2]}))
        total += len(idx)
        frame += 1
    return pd.concat(chunks, ignore_index=True)[POINT_COLUMNS]


def _tilt(direction: np.ndarray, angle: float, rng: np.random.Generator) -> np.ndarray:
    """Rotate a unit vector by `angle` about a random axis perpendicular to it."""
    perp = np.cross(direction, rng.normal(size=3))
    perp /= np.linalg.norm(perp)
    return np.cos(angle) * direction + np.sin(angle) * perp


def _frame_from_normal(normal: np.ndarray, spin: float) -> np.ndarray:
    """Rotation whose third column is `normal`, spun by `spin` about it."""
    a = np.array([1.0, 0, 0]) if abs(normal[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(normal, a)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    c, s = np.cos(spin), np.sin(spin)
    return np.stack([c * u + s * v, -s * u + c * v, normal], axis=1)
