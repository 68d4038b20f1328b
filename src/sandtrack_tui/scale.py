"""Millimetres from one camera: the px -> mm scale of 2D tracking.

A project with one camera measures in the image: a marker's position in mm is its pixel position
(undistorted first when the project has a calibration of that camera) times a scale in mm per px,
with the image's axes (x right, y down, origin at the top-left corner). The scale comes from a
known length (two image points and the distance between them in mm) or, without one, from a
calibration: the depth of the world frame's origin (where the reference board lay) in that camera
over its focal length. Either holds for markers moving in a plane facing the camera at that depth.

Stored in the project setting ``scale`` as {camera: {"mm_per_px": s, "source": text}}; a known
length, once set, wins over the calibration.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import SandtrackError

SETTING = "scale"


def from_length(p1, p2, length_mm: float, camera=None) -> float:
    """mm per px from two image points `length_mm` apart (pixels undistorted through `camera`, a
    calibrated Camera, when given)."""
    if not (np.isfinite(length_mm) and length_mm > 0):
        raise SandtrackError(f"the known length must be a positive number of mm, not {length_mm}")
    pts = _undistorted(np.array([p1, p2], dtype=float), camera)
    px = float(np.hypot(*(pts[1] - pts[0])))
    if not px >= 2.0:
        raise SandtrackError(f"the two ends are {px:.1f} px apart: put them at least 2 px apart "
                             "(zoom in for a short length)")
    return float(length_mm) / px


def from_calibration(calibration, camera: str) -> float:
    """mm per px at the depth of the world origin in `camera` (pinhole: depth / focal length)."""
    if calibration is None or camera not in calibration.cameras:
        raise SandtrackError(f"the calibration has no camera {camera!r}")
    cam = calibration.cameras[camera]
    origin = calibration.to_rig(np.zeros((1, 3)))[0]
    depth = float((cam.R @ origin + cam.tvec)[2])
    if not depth > 0:
        raise SandtrackError(f"the world origin lies behind camera {camera}: no scale from this calibration")
    focal = 0.5 * (cam.matrix[0, 0] + cam.matrix[1, 1])
    return depth / focal


def set_scale(project, camera: str, mm_per_px: float, source: str) -> None:
    """Store a camera's scale (one undoable edit)."""
    if not (math.isfinite(mm_per_px) and mm_per_px > 0):
        raise SandtrackError(f"a scale must be a positive number of mm per px, not {mm_per_px}")
    scales = dict(project.get(SETTING, {}) or {})
    scales[camera] = {"mm_per_px": float(mm_per_px), "source": source}
    project.set(SETTING, scales, f"scale of {camera}: {mm_per_px:.5g} mm/px ({source})")


def project_scale(project, camera: str, calibration=None) -> tuple[float, str] | None:
    """(mm per px, where it came from) for `camera`: the stored one, else from the calibration,
    else None."""
    stored = (project.get(SETTING, {}) or {}).get(camera)
    if isinstance(stored, dict) and isinstance(stored.get("mm_per_px"), (int, float)) and stored["mm_per_px"] > 0:
        return float(stored["mm_per_px"]), str(stored.get("source", "stored"))
    if calibration is not None and camera in calibration.cameras:
        try:
            return from_calibration(calibration, camera), "calibration (depth of the world origin)"
        except SandtrackError:
            return None
    return None


def to_mm(pixels, mm_per_px: float, camera=None) -> np.ndarray:
    """(N, 2) pixels -> (N, 2) mm in the image's axes (undistorted through `camera` when given)."""
    pts = np.asarray(pixels, dtype=float).reshape(-1, 2)
    ok = np.isfinite(pts).all(axis=1)
    out = np.full_like(pts, np.nan)
    if ok.any():
        out[ok] = _undistorted(pts[ok], camera) * mm_per_px
    return out


def _undistorted(pts: np.ndarray, camera) -> np.ndarray:
    return pts if camera is None else camera.undistort(pts)
