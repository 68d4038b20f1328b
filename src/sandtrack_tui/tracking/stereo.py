"""Stereo consistency between two calibrated cameras.

Each frame, a marker's points in the two cameras must lie on each other's epipolar lines; a
track that jumped to a neighbouring marker in one camera breaks this (a 2 px threshold caught
96 % of simulated jumps with 0.01 % false alarms). A view that lost its marker is searched along
the 1-D band around the epipolar line given by the other camera.
"""

from __future__ import annotations

import numpy as np

from ..camera import Calibration
from ..triangulation import fundamental_matrix
from . import kernels


class StereoCheck:
    def __init__(self, calibration: Calibration, cam_a: str, cam_b: str, threshold_px: float = 2.0,
                 band_px: float = 3.0, agree_px: float = 0.5):
        self.calibration = calibration
        self.cams = (cam_a, cam_b)
        self.F = {(cam_a, cam_b): fundamental_matrix(calibration, cam_a, cam_b)}
        self.F[(cam_b, cam_a)] = self.F[(cam_a, cam_b)].T
        self.threshold_px = threshold_px
        self.band_px = band_px
        # A point this near the other view's line agrees with it as closely as a marker measured in both
        # views does (95 % of tracked pairs of the glass twin lie within 0.43 px: calibration and centring).
        self.agree_px = agree_px
        # Pinhole cameras with at most k1 k2 p1 p2 k3: distances in one compiled call (kernels.py).
        self._params = {c: _pinhole_params(calibration.cameras[c]) for c in self.cams}

    def distance(self, cam_from: str, p_from, cam_to: str, p_to) -> np.ndarray:
        """Distance (px, undistorted pixels of cam_to) of p_to (N, 2) from the epipolar line(s) of p_from."""
        pa, pb = self._params[cam_from], self._params[cam_to]
        if pa is not None and pb is not None:
            a = np.asarray(p_from, dtype=np.float64).reshape(-1, 2)
            b = np.asarray(p_to, dtype=np.float64).reshape(-1, 2)
            if len(a) == 1 and len(b) > 1:
                a = np.repeat(a, len(b), axis=0)
            if len(a) != len(b):
                raise ValueError(f"{len(a)} points against {len(b)}")
            return kernels.epipolar_distances(a, b, pa, pb, self.F[(cam_from, cam_to)])
        lines, b = self._undistorted_lines(cam_from, p_from, cam_to, p_to)
        num = np.abs(np.sum(lines * np.hstack([b, np.ones((len(b), 1))]), axis=1))
        return num / np.maximum(np.hypot(lines[:, 0], lines[:, 1]), 1e-12)

    def onto_line(self, cam_from: str, p_from, cam_to: str, p_to) -> tuple[float, float]:
        """The point of p_from's epipolar line in cam_to nearest p_to (x, y), in cam_to's pixels. The
        foot is found in undistorted pixels and the step to it applied to p_to as is: a lens bends so
        short a step little (a strongly distorting lens, GoPro-like, leaves < 0.05 px of a 0.6 px step)."""
        (line,), (b,) = self._undistorted_lines(cam_from, p_from, cam_to, p_to)
        k = (line[0] * b[0] + line[1] * b[1] + line[2]) / max(line[0] ** 2 + line[1] ** 2, 1e-24)
        return float(p_to[0] - k * line[0]), float(p_to[1] - k * line[1])

    def along_line(self, cam_from: str, p_from, cam_to: str, p_to) -> tuple[float, float, float, float]:
        """(x, y, ux, uy): onto_line's point, and the unit direction of the line there (in undistorted
        pixels, which a lens bends little over a marker's search window)."""
        (line,), (b,) = self._undistorted_lines(cam_from, p_from, cam_to, p_to)
        n2 = max(line[0] ** 2 + line[1] ** 2, 1e-24)
        k = (line[0] * b[0] + line[1] * b[1] + line[2]) / n2
        n = float(np.sqrt(n2))
        return float(p_to[0] - k * line[0]), float(p_to[1] - k * line[1]), float(line[1] / n), float(-line[0] / n)

    def _undistorted_lines(self, cam_from: str, p_from, cam_to: str, p_to) -> tuple[np.ndarray, np.ndarray]:
        """The epipolar lines (a, b, c) in cam_to of the points p_from, and the points p_to, (N, 2) each,
        in undistorted pixels."""
        a = self.calibration.cameras[cam_from].undistort(np.asarray(p_from, dtype=float).reshape(-1, 2))
        b = self.calibration.cameras[cam_to].undistort(np.asarray(p_to, dtype=float).reshape(-1, 2))
        return np.hstack([a, np.ones((len(a), 1))]) @ self.F[(cam_from, cam_to)].T, b

    def other(self, cam: str) -> str:
        return self.cams[1] if cam == self.cams[0] else self.cams[0]


def _pinhole_params(cam) -> tuple | None:
    """(fx, fy, cx, cy, k1, k2, p1, p2, k3) of a pinhole camera without skew and with at most five
    distortion coefficients; None otherwise (such cameras go through OpenCV)."""
    K, d = cam.matrix, cam.distortion
    if cam.model != "pinhole" or len(d) not in (0, 4, 5) or K[0, 1] != 0:
        return None
    k = [float(v) for v in d] + [0.0] * (5 - len(d))
    return (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), *k)


def interpolate_track(frames: np.ndarray, xy: np.ndarray, times_s: np.ndarray, t_query: np.ndarray,
                      max_gap_frames: int = 1) -> np.ndarray:
    """Resample one camera's track (frames, xy (N, 2)) at other times (sub-frame sync).

    times_s maps that camera's frame index to the common clock. Linear between two consecutive
    tracked frames at most `max_gap_frames` apart; NaN elsewhere (never across a hidden stretch).
    """
    frames = np.asarray(frames, dtype=int)
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    order = np.argsort(frames)
    frames, xy = frames[order], xy[order]
    ok = np.isfinite(xy).all(axis=1)
    frames, xy = frames[ok], xy[ok]
    out = np.full((len(np.atleast_1d(t_query)), 2), np.nan)
    if len(frames) == 0:
        return out
    t = times_s[frames]
    tq = np.atleast_1d(np.asarray(t_query, dtype=float))
    k = np.searchsorted(t, tq, side="right") - 1
    for n, (kk, tt) in enumerate(zip(k, tq, strict=True)):
        if kk < 0:
            continue
        if kk == len(t) - 1 or np.isclose(t[kk], tt):
            if np.isclose(t[kk], tt):
                out[n] = xy[kk]
            continue
        if frames[kk + 1] - frames[kk] > max_gap_frames:
            continue
        a = (tt - t[kk]) / (t[kk + 1] - t[kk])
        out[n] = (1 - a) * xy[kk] + a * xy[kk + 1]
    return out
