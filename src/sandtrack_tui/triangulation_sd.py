"""The standard deviation of a triangulated point: first-order propagation of the pixels' noise and of the
calibration's own uncertainty.

For each point and camera, J = d(distorted pixel) / d(point) at the triangulated point (the camera matrix,
the lens's local Jacobian and the perspective division). The refinement of `triangulation.triangulate` is a
weighted least-squares fit with weights ω = 1 / RMSE² per camera, so a pixel error δp moves the point by
δX = H⁻¹ Σ ω Jᵀ δp with H = Σ ω JᵀJ, and the point's covariance is the sandwich
H⁻¹ (Σ ω² Jᵀ Σp J) H⁻¹, where Σp is each camera's pixel covariance at that point:

- the pixel's own noise, sd² · I (the tracker's estimate, a pixel table's column, else the camera's RMSE);
- the calibration's: G Σθ Gᵀ, with Σθ the covariance of the camera's parameters from its bundle
  adjustment (`CameraUncertainty`, kept in calibration.toml) and G = d(pixel) / d(parameters) at the point
  (analytic for the translation and the camera matrix, finite differences for the rotation and the lens).

Left out: correlations between the cameras' calibration errors (each camera's block is used alone), the
uncertainty of the rig-to-world transform and of the board's own dimensions, and anything the calibration
residuals cannot show (a lens model that does not fit the whole image, a rig that moved after calibrating).
"""

from __future__ import annotations

import numpy as np

from .camera import Calibration, Camera, rotate
from .lens import distort_fisheye, distort_normalised

POSE_PARAMETERS = ("rx", "ry", "rz", "tx", "ty", "tz")
MATRIX_PARAMETERS = ("fx", "fy", "cx", "cy")
_ROTATION_STEP = 1e-6
_LENS_STEP = 1e-7


def triangulation_covariance(calibration: Calibration, pixels: dict[str, np.ndarray], points_rig: np.ndarray,
                             pixel_sd: dict[str, np.ndarray] | None = None,
                             with_calibration: bool = True) -> np.ndarray:
    """(N, 3, 3) covariance (mm², rig frame) of points triangulated from `pixels` ((N, 2) per camera, NaN
    where unseen). pixel_sd: per camera, a scalar or (N,) px (default: the camera's RMSE, else 1 px).
    NaN where fewer than two cameras saw the point or a needed sd is unknown."""
    X = np.asarray(points_rig, dtype=np.float64).reshape(-1, 3)
    n = len(X)
    H = np.zeros((n, 3, 3))
    M = np.zeros((n, 3, 3))
    count = np.zeros(n, dtype=int)
    ok_x = np.isfinite(X).all(axis=1)
    for name, px in pixels.items():
        cam = calibration.cameras.get(name)
        if cam is None:
            continue
        seen = np.isfinite(np.asarray(px, float).reshape(-1, 2)).all(axis=1) & ok_x
        if not seen.any():
            continue
        sigma = _camera_sigma(cam)
        sd = np.broadcast_to(np.asarray(sigma if pixel_sd is None or pixel_sd.get(name) is None
                                        else pixel_sd[name], float), (n,))[seen]
        J, G = _jacobians(cam, X[seen], calibration.uncertainty.get(name) if with_calibration else None)
        cov_p = (sd ** 2)[:, None, None] * np.eye(2)
        if G is not None:
            cov_p = cov_p + G
        w = 1.0 / sigma ** 2
        H[seen] += w * np.einsum("nki,nkj->nij", J, J)
        M[seen] += w * w * np.einsum("nki,nkl,nlj->nij", J, cov_p, J)
        count[seen] += 1
    out = np.full((n, 3, 3), np.nan)
    good = count >= 2
    if good.any():
        Hi = np.linalg.inv(H[good])
        out[good] = Hi @ M[good] @ Hi
    return out


def world_sd(calibration: Calibration, cov_rig: np.ndarray) -> np.ndarray:
    """(N, 3) sd per world axis (mm) of rig-frame covariances."""
    R = calibration.world_from_rig[:3, :3]
    var = np.einsum("ij,njk,ik->ni", R, cov_rig, R)
    return np.sqrt(np.clip(var, 0.0, None))


def _camera_sigma(cam: Camera) -> float:
    """The camera's noise level as the refinement weighs it (its RMSE, else 1 px)."""
    r = cam.rmse_px
    return float(r) if r and np.isfinite(r) and r > 0 else 1.0


def _jacobians(cam: Camera, X: np.ndarray, unc) -> tuple[np.ndarray, np.ndarray | None]:
    """d pixel / d point (n, 2, 3), and the calibration's pixel covariance G Σθ Gᵀ (n, 2, 2) or None."""
    R = cam.R
    xc = rotate(X, R) + cam.tvec
    z = xc[:, 2]
    a, b = xc[:, 0] / z, xc[:, 1] / z
    distort = distort_fisheye if cam.model == "fisheye" else distort_normalised
    xd, yd = distort(a, b, cam.distortion)
    eps = 1e-6
    xa, ya = distort(a + eps, b, cam.distortion)
    xb, yb = distort(a, b + eps, cam.distortion)
    Jd = np.empty((len(X), 2, 2))
    Jd[:, 0, 0], Jd[:, 1, 0] = (xa - xd) / eps, (ya - yd) / eps
    Jd[:, 0, 1], Jd[:, 1, 1] = (xb - xd) / eps, (yb - yd) / eps
    K = cam.matrix
    K2 = np.array([[K[0, 0], K[0, 1]], [0.0, K[1, 1]]])
    dn = np.zeros((len(X), 2, 3))  # d(a, b) / d(camera-frame point)
    dn[:, 0, 0], dn[:, 0, 2] = 1 / z, -a / z
    dn[:, 1, 1], dn[:, 1, 2] = 1 / z, -b / z
    P = np.einsum("ij,njk,nkl->nil", K2, Jd, dn)  # d pixel / d camera-frame point = d pixel / d t
    J = P @ R
    if unc is None:
        return J, None
    cols = []
    for name in unc.parameters:
        cols.append(_parameter_column(name, cam, X, xc, P, xd, yd, a, b, distort, K2))
    G = np.stack(cols, axis=2)  # (n, 2, P)
    return J, np.einsum("nip,pq,njq->nij", G, unc.covariance, G)


def _parameter_column(name: str, cam: Camera, X, xc, P, xd, yd, a, b, distort, K2) -> np.ndarray:
    n = len(X)
    if name in ("tx", "ty", "tz"):
        return P[:, :, "xyz".index(name[1])]
    if name in ("rx", "ry", "rz"):
        import cv2

        rv = cam.rvec.copy()
        rv["xyz".index(name[1])] += _ROTATION_STEP
        moved = rotate(X, cv2.Rodrigues(rv)[0]) + cam.tvec
        return np.einsum("nij,nj->ni", P, moved - xc) / _ROTATION_STEP
    out = np.zeros((n, 2))
    if name == "fx":
        out[:, 0] = xd
    elif name == "fy":
        out[:, 1] = yd
    elif name == "cx":
        out[:, 0] = 1.0
    elif name == "cy":
        out[:, 1] = 1.0
    elif name.startswith("d"):
        d = cam.distortion.copy()
        k = int(name[1:])
        if k >= len(d):
            return out
        d[k] += _LENS_STEP
        x2, y2 = distort(a, b, d)
        out = np.stack([x2 - xd, y2 - yd], axis=1) @ K2.T / _LENS_STEP
    return out
