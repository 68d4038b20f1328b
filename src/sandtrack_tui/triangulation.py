"""Triangulation of pixel observations from two or more calibrated cameras.

`triangulate` undistorts each camera's pixels to normalised image coordinates (every lens model),
solves the linear triangulation per point (least squares on the DLT equations of the cameras that
saw it, all points at once: one 3 x 3 system each), optionally refines by Gauss-Newton, and returns
per point the RMS reprojection residual in pixels: a large residual means the views do not see the
same point (a bad track).

The refinement minimises each camera's reprojection error in its own distorted pixels, to first
order (the normalised error mapped through the camera matrix and the lens's local Jacobian at the
observation), divided by the camera's noise level (its calibration RMSE, when known): the maximum-
likelihood point when the cameras' pixel errors are independent and Gaussian.
"""

from __future__ import annotations

import numpy as np

from .camera import Calibration, Camera
from .jit import jit
from .lens import distort_fisheye, distort_normalised


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
    cams = [calibration.cameras[n] for n in names]
    uv = np.stack([_normalised(c, obs[n]) for c, n in zip(cams, names, strict=True)])  # (C, N, 2)
    seen = np.isfinite(uv).all(axis=2)
    uv = np.where(seen[..., None], uv, 0.0)
    R = np.stack([c.R for c in cams])
    t = np.stack([c.tvec for c in cams])
    scale = max(float(np.linalg.norm(t, axis=1).max()), 1.0)
    W = np.stack([_pixel_weights(c, uv[k]) for k, c in enumerate(cams)]) if refine else np.zeros((len(cams), 0, 2, 2))
    pts = _solve_points(uv, seen, R, t, W, scale, 8 if refine else 0)
    residual = reprojection_residual(calibration, obs, pts)
    return (calibration.to_world(pts) if world else pts), residual


def _normalised(cam: Camera, px: np.ndarray) -> np.ndarray:
    """Undistorted normalised coordinates (x/z, y/z) of distorted pixels; NaN where missing."""
    out = np.full_like(px, np.nan)
    ok = np.isfinite(px).all(axis=1)
    if ok.any():
        und = cam.undistort(px[ok])
        K = cam.matrix
        y = (und[:, 1] - K[1, 2]) / K[1, 1]
        out[ok] = np.stack([(und[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0], y], axis=1)
    return out


def _pixel_weights(cam: Camera, uv: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """(N, 2, 2): d(distorted pixel) / d(normalised point) at each observation (camera matrix times the
    lens's Jacobian, by finite differences), divided by the camera's noise level (its RMSE, else 1 px)."""
    distort = distort_fisheye if cam.model == "fisheye" else distort_normalised
    x, y = uv[:, 0], uv[:, 1]
    x0, y0 = distort(x, y, cam.distortion)
    xa, ya = distort(x + eps, y, cam.distortion)
    xb, yb = distort(x, y + eps, cam.distortion)
    sigma = cam.rmse_px if cam.rmse_px and np.isfinite(cam.rmse_px) and cam.rmse_px > 0 else 1.0
    fx, s, fy = cam.matrix[0, 0] / sigma, cam.matrix[0, 1] / sigma, cam.matrix[1, 1] / sigma
    jxx, jyx, jxy, jyy = (xa - x0) / eps, (ya - y0) / eps, (xb - x0) / eps, (yb - y0) / eps
    W = np.empty((len(uv), 2, 2))
    W[:, 0, 0], W[:, 0, 1] = fx * jxx + s * jyx, fx * jxy + s * jyy
    W[:, 1, 0], W[:, 1, 1] = fy * jyx, fy * jyy
    return np.nan_to_num(W)


@jit
def _solve3(A, b):
    """x with A x = b for a 3 x 3 A (Cramer's rule); NaN when A is singular."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    out = np.empty(3)
    if not abs(det) > 1e-300:
        out[:] = np.nan
        return out
    c10 = A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]
    c11 = A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]
    c12 = A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]
    c20 = A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]
    c21 = A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]
    c22 = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    out[0] = (c00 * b[0] + c10 * b[1] + c20 * b[2]) / det
    out[1] = (c01 * b[0] + c11 * b[1] + c21 * b[2]) / det
    out[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det
    return out


@jit(nogil=True)
def _solve_points(uv, seen, R, t, W, scale, iterations):
    """Per point: least squares on the DLT equations of the cameras that saw it (normalised
    coordinates, translations divided by `scale`), then `iterations` Gauss-Newton steps on the
    weighted reprojection errors W (dn), stopping when a step is below 1e-6 mm."""
    n_cam, n_pts = seen.shape
    out = np.full((n_pts, 3), np.nan)
    A = np.empty((3, 3))
    b = np.empty(3)
    row = np.empty(4)
    jac = np.empty((2, 3))
    for i in range(n_pts):
        A[:] = 0.0
        b[:] = 0.0
        count = 0
        for c in range(n_cam):
            if not seen[c, i]:
                continue
            count += 1
            for k in range(2):
                w = uv[c, i, k]
                for j in range(3):
                    row[j] = w * R[c, 2, j] - R[c, k, j]
                row[3] = (w * t[c, 2] - t[c, k]) / scale
                for j in range(3):
                    b[j] -= row[j] * row[3]
                    for m in range(3):
                        A[j, m] += row[j] * row[m]
        if count < 2:
            continue
        X = _solve3(A, b) * scale
        for _ in range(iterations):
            A[:] = 0.0
            b[:] = 0.0
            for c in range(n_cam):
                if not seen[c, i]:
                    continue
                xc0 = R[c, 0, 0] * X[0] + R[c, 0, 1] * X[1] + R[c, 0, 2] * X[2] + t[c, 0]
                xc1 = R[c, 1, 0] * X[0] + R[c, 1, 1] * X[1] + R[c, 1, 2] * X[2] + t[c, 1]
                z = R[c, 2, 0] * X[0] + R[c, 2, 1] * X[1] + R[c, 2, 2] * X[2] + t[c, 2]
                if not z > 1e-9:  # on or behind the camera (mismatched views): no refinement
                    A[:] = np.nan
                    break
                px, py = xc0 / z, xc1 / z
                ex, ey = px - uv[c, i, 0], py - uv[c, i, 1]
                w00, w01, w10, w11 = W[c, i, 0, 0], W[c, i, 0, 1], W[c, i, 1, 0], W[c, i, 1, 1]
                r0, r1 = w00 * ex + w01 * ey, w10 * ex + w11 * ey
                for j in range(3):  # the weighted Jacobian W d(proj)/dX, rows 0 and 1
                    d0 = (R[c, 0, j] - px * R[c, 2, j]) / z
                    d1 = (R[c, 1, j] - py * R[c, 2, j]) / z
                    jac[0, j] = w00 * d0 + w01 * d1
                    jac[1, j] = w10 * d0 + w11 * d1
                for j in range(3):
                    b[j] -= jac[0, j] * r0 + jac[1, j] * r1
                    for m in range(3):
                        A[j, m] += jac[0, j] * jac[0, m] + jac[1, j] * jac[1, m]
            step = _solve3(A, b)
            if not np.isfinite(step).all():
                break
            X = X + step
            if max(abs(step[0]), abs(step[1]), abs(step[2])) < 1e-6:
                break
        out[i] = X
    return out


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


def warm_up_rig() -> tuple[Calibration, np.ndarray]:
    """Two small cameras and two points they both see (mm): what the kernels' warm-ups run on."""
    cams = {n: Camera(n, 640, 480, [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]], [-0.1, 0.01, 0, 0, 0],
                      rvec=[0.0, ry, 0.0], tvec=[tx, 0.0, 0.0], rmse_px=0.1)
            for n, ry, tx in (("a", 0.0, 0.0), ("b", -0.3, -200))}
    return Calibration(cameras=cams), np.array([[10.0, 5.0, 900.0], [-40.0, 20.0, 1100.0]])


def warm_up() -> None:
    """Compile (or load) the triangulation kernels once, on two cameras and a few points: run after
    installing, so the first `sandtrack xyz` does not pay the compilation (a few seconds)."""
    cal, X = warm_up_rig()
    for refine in (False, True):
        triangulate(cal, {n: c.project(X) for n, c in cal.cameras.items()}, refine=refine)


if __name__ == "__main__":
    warm_up()
