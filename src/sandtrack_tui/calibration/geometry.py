"""Vectorised pose and projection maths shared by the calibration modules (numpy, no OpenCV loops).

Poses are 4x4 matrices `T_a_b` mapping b-frame points into frame a, or (rvec, tvec) pairs in the
OpenCV convention. Projection is `lens.project` (OpenCV's pinhole model with up to 14 distortion terms, or its fisheye
model), matching `cv2.projectPoints` to float precision.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..lens import project, radial_factor


def rodrigues(rvecs: np.ndarray) -> np.ndarray:
    """(N, 3) rotation vectors -> (N, 3, 3) matrices."""
    r = np.asarray(rvecs, dtype=np.float64).reshape(-1, 3)
    theta = np.linalg.norm(r, axis=1)
    small = theta < 1e-12
    safe = np.where(small, 1.0, theta)
    k = r / safe[:, None]
    K = np.zeros((len(r), 3, 3))
    K[:, 0, 1], K[:, 0, 2] = -k[:, 2], k[:, 1]
    K[:, 1, 0], K[:, 1, 2] = k[:, 2], -k[:, 0]
    K[:, 2, 0], K[:, 2, 1] = -k[:, 1], k[:, 0]
    s = np.sin(theta)[:, None, None]
    c = (1 - np.cos(theta))[:, None, None]
    R = np.eye(3)[None] + s * K + c * (K @ K)
    R[small] = np.eye(3)
    return R


def to_T(rvec, tvec) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, dtype=np.float64).ravel()
    return T


def from_T(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return cv2.Rodrigues(np.ascontiguousarray(T[:3, :3]))[0].ravel(), T[:3, 3].copy()


def inv_T(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def rotation_angle_deg(R: np.ndarray) -> float:
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotation matrices (projection of the arithmetic mean onto SO(3))."""
    U, _, Vt = np.linalg.svd(np.sum(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def distort_project(xc: np.ndarray, K: np.ndarray, dist: np.ndarray, model: str = "pinhole") -> np.ndarray:
    """Camera-frame points (N, 3) -> distorted pixels (N, 2), every lens model (see `lens.project`)."""
    return project(xc, K, dist, model)


def radial_is_monotonic(dist: np.ndarray, K: np.ndarray, size: tuple[int, int] | None, model: str = "pinhole",
                        radius: float | None = None) -> bool:
    """True if the distorted radius keeps growing with the undistorted radius over the whole image
    (a fitted k3 that folds the image back on itself is over-fitting). Without a known image size,
    `radius` (normalised, e.g. the farthest observed point) stands for the image corner."""
    if model == "fisheye":
        return True
    if size is not None:
        w, h = size
        corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], dtype=float)
        r_img = np.max(np.hypot((corners[:, 0] - K[0, 2]) / K[0, 0], (corners[:, 1] - K[1, 2]) / K[1, 1]))
    else:
        r_img = float(radius)
    r = np.linspace(0, 4 * r_img, 4000)
    rd = r * radial_factor(r, dist)
    falling = np.nonzero((np.diff(rd) <= 0) | ~np.isfinite(rd[1:]) | (rd[1:] < 0))[0]
    reach = rd[: falling[0] + 1].max() if len(falling) else rd.max()
    # The distorted radius must reach the image corner before the curve turns back.
    return bool(reach >= 1.02 * r_img)


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Rigid 4x4 T with dst ~ R @ src + t (least squares, no scale). src, dst: (N, 3), N >= 3."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = cd - R @ cs
    return T


def larger(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The covariance that is, in every direction, the larger of a (positive definite) and b: a's
    Cholesky factor L, the eigenvalues λ of L⁻¹ b L⁻ᵀ raised to at least 1."""
    L = np.linalg.cholesky(a)
    Li = np.linalg.inv(L)
    lam, V = np.linalg.eigh(Li @ b @ Li.T)
    return L @ V @ np.diag(np.maximum(lam, 1.0)) @ V.T @ L.T
