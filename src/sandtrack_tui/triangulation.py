"""Triangulation of pixel observations from two or more calibrated cameras.

`triangulate` undistorts each camera's pixels, solves the linear DLT (homogeneous least squares,
SVD) per point, optionally refines by Gauss-Newton on the distorted reprojection error, and
returns per point the RMS reprojection residual in pixels: a large residual means the two
views do not see the same point (a bad track).
"""

from __future__ import annotations

import numpy as np

from .camera import Calibration


def triangulate(calibration: Calibration, pixels: dict[str, np.ndarray], refine: bool = False,
                world: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate N points seen by the cameras named in `pixels` ((N, 2) distorted pixels each,
    NaN where a camera did not see the point).

    Returns (points (N, 3) mm in the world frame, or the rig frame if world=False;
    residual_px (N,) RMS reprojection error over the cameras used). Points seen by fewer than
    two cameras are NaN.
    """
    names = [n for n in pixels if n in calibration.cameras]
    if len(names) < 2:
        raise ValueError("triangulation needs pixels from at least two calibrated cameras")
    obs = {n: np.asarray(pixels[n], dtype=np.float64).reshape(-1, 2) for n in names}
    n_pts = len(next(iter(obs.values())))
    und = {}
    for n in names:
        und[n] = np.full((n_pts, 2), np.nan)
        ok = np.isfinite(obs[n]).all(axis=1)
        if ok.any():
            und[n][ok] = calibration.cameras[n].undistort(obs[n][ok])
    # DLT in normalised camera coordinates, lengths scaled to ~1, for conditioning.
    scale = max(max(np.linalg.norm(calibration.cameras[n].tvec) for n in names), 1.0)
    P = {}
    for n in names:
        cam = calibration.cameras[n]
        P[n] = np.hstack([cam.R, cam.tvec[:, None] / scale])
        ok = np.isfinite(und[n]).all(axis=1)
        norm = np.full_like(und[n], np.nan)
        norm[ok] = (np.linalg.inv(cam.matrix) @ np.vstack([und[n][ok].T, np.ones(ok.sum())]))[:2].T
        und[n] = norm

    pts = np.full((n_pts, 3), np.nan)
    valid = np.stack([np.isfinite(und[n]).all(axis=1) for n in names], axis=1)  # (N, C)
    for pattern in {tuple(v) for v in valid}:
        cams = [n for n, used in zip(names, pattern, strict=True) if used]
        if len(cams) < 2:
            continue
        idx = np.nonzero((valid == np.array(pattern)).all(axis=1))[0]
        pts[idx] = scale * _dlt(np.stack([und[c][idx] for c in cams]), np.stack([P[c] for c in cams]))
    if refine:
        pts = _refine(calibration, names, obs, pts)
    residual = reprojection_residual(calibration, obs, pts)
    return (calibration.to_world(pts) if world else pts), residual


def _dlt(uv: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Vectorised DLT. uv: (C, N, 2) normalised image points, P: (C, 3, 4) -> (N, 3)."""
    C, N, _ = uv.shape
    A = np.empty((N, 2 * C, 4))
    for c in range(C):
        A[:, 2 * c] = uv[c, :, 0:1] * P[c, 2] - P[c, 0]
        A[:, 2 * c + 1] = uv[c, :, 1:2] * P[c, 2] - P[c, 1]
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1]
    return X[:, :3] / X[:, 3:4]


def _refine(calibration: Calibration, names, obs, pts: np.ndarray, iterations: int = 5) -> np.ndarray:
    """Gauss-Newton on the distorted reprojection error with a numeric Jacobian (3 params/point)."""
    out = pts.copy()
    ok = np.isfinite(out).all(axis=1)
    if not ok.any():
        return out
    x = out[ok]
    eps = 1e-3
    for _ in range(iterations):
        r0 = _stacked_residuals(calibration, names, obs, x, ok)
        J = np.empty(r0.shape + (3,))
        for k in range(3):
            dx = x.copy()
            dx[:, k] += eps
            J[..., k] = (_stacked_residuals(calibration, names, obs, dx, ok) - r0) / eps
        J = np.nan_to_num(J)
        r = np.nan_to_num(r0)
        JtJ = np.einsum("nik,nil->nkl", J, J) + 1e-9 * np.eye(3)
        Jtr = np.einsum("nik,ni->nk", J, r)
        try:
            step = np.linalg.solve(JtJ, -Jtr[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a point with no usable view in one camera: least-norm step
            step = -np.einsum("nkl,nl->nk", np.linalg.pinv(JtJ), Jtr)
        x = x + step
        if np.nanmax(np.abs(step)) < 1e-6:
            break
    out[ok] = x
    return out


def _stacked_residuals(calibration, names, obs, x, ok) -> np.ndarray:
    res = []
    for n in names:
        proj = calibration.cameras[n].project(x)
        res.append(proj - obs[n][ok])
    return np.concatenate(res, axis=1)  # (M, 2C), NaN where unobserved


def reprojection_residual(calibration: Calibration, obs: dict[str, np.ndarray], pts_rig: np.ndarray) -> np.ndarray:
    """RMS over cameras of the pixel distance between observation and reprojection (NaN-aware)."""
    n_pts = len(pts_rig)
    sq = np.zeros(n_pts)
    cnt = np.zeros(n_pts)
    ok = np.isfinite(pts_rig).all(axis=1)
    for n, px in obs.items():
        proj = np.full((n_pts, 2), np.nan)
        if ok.any():
            proj[ok] = calibration.cameras[n].project(pts_rig[ok])
        d2 = np.sum((proj - px) ** 2, axis=1)
        seen = np.isfinite(d2)
        sq[seen] += d2[seen]
        cnt[seen] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt >= 2, np.sqrt(sq / np.maximum(cnt, 1)), np.nan)


def epipolar_distance(calibration: Calibration, cam_a: str, px_a: np.ndarray, cam_b: str,
                      px_b: np.ndarray) -> np.ndarray:
    """Distance (px, in undistorted pixels of camera b) of px_b from the epipolar line of px_a."""
    F = fundamental_matrix(calibration, cam_a, cam_b)
    a = calibration.cameras[cam_a].undistort(np.asarray(px_a, dtype=float).reshape(-1, 2))
    b = calibration.cameras[cam_b].undistort(np.asarray(px_b, dtype=float).reshape(-1, 2))
    ah = np.hstack([a, np.ones((len(a), 1))])
    bh = np.hstack([b, np.ones((len(b), 1))])
    lines = ah @ F.T  # l_b = F a
    return np.abs(np.sum(lines * bh, axis=1)) / np.hypot(lines[:, 0], lines[:, 1])


def fundamental_matrix(calibration: Calibration, cam_a: str, cam_b: str) -> np.ndarray:
    """F with x_b^T F x_a = 0 for undistorted pixels."""
    A, B = calibration.cameras[cam_a], calibration.cameras[cam_b]
    R = B.R @ A.R.T
    t = B.tvec - R @ A.tvec
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R
    return np.linalg.inv(B.matrix).T @ E @ np.linalg.inv(A.matrix)
