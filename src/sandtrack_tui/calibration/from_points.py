"""Calibration from known correspondences (pixels in each camera + world X, Y, Z), e.g. a surveyed
3D target or a pixel/XYZ table exported by another tool.

Per camera: normalised DLT for the 3x4 projection matrix, RQ decomposition into K, R, t, then a
nonlinear fit of K, the full distortion (k1, k2, p1, p2, k3) and the pose on the distorted
reprojection error (robust loss). The world frame is the points' frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..camera import Calibration, Camera
from ..errors import SandtrackError
from .bundle import BundleState, Observations, bundle_adjust, residuals
from .geometry import from_T, inv_T, radial_is_monotonic, to_T

MIN_POINTS = 12


def read_points_table(path: str | Path) -> tuple[pd.DataFrame, dict[str, tuple[str, str]]]:
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"points file not found: {p}")
    try:
        df = pd.read_csv(p)
    except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError) as exc:
        raise SandtrackError(f"{p}: not a readable CSV ({str(exc).strip().splitlines()[0]})") from None
    missing = [c for c in ("X_mm", "Y_mm", "Z_mm") if c not in df.columns]
    if missing:
        raise SandtrackError(f"{p}: missing columns {missing} (need X_mm, Y_mm, Z_mm and pixel columns)")
    cams: dict[str, tuple[str, str]] = {}
    if {"xs", "ys"} <= set(df.columns):
        cams["side"] = ("xs", "ys")
    if {"xf", "yf"} <= set(df.columns):
        cams["front"] = ("xf", "yf")
    for c in df.columns:
        if c.startswith("x_") and f"y_{c[2:]}" in df.columns:
            cams[c[2:]] = (c, f"y_{c[2:]}")
    if len(cams) < 1:
        raise SandtrackError(f"{p}: no pixel columns (xs, ys / xf, yf, or x_NAME, y_NAME)")
    # numbers only; anything else (text, inf) counts as missing
    for c in ["X_mm", "Y_mm", "Z_mm", *(col for xy in cams.values() for col in xy)]:
        df[c] = pd.to_numeric(df[c], errors="coerce").astype(float).where(lambda v: np.isfinite(v))
    return df, cams


def dlt_projection(X: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Normalised DLT: 3x4 P with uv ~ P [X, 1]."""
    mx, sx = X.mean(0), np.sqrt(3) / np.mean(np.linalg.norm(X - X.mean(0), axis=1))
    mu, su = uv.mean(0), np.sqrt(2) / np.mean(np.linalg.norm(uv - uv.mean(0), axis=1))
    Tx = np.diag([sx, sx, sx, 1.0])
    Tx[:3, 3] = -sx * mx
    Tu = np.diag([su, su, 1.0])
    Tu[:2, 2] = -su * mu
    Xn = (X - mx) * sx
    un = (uv - mu) * su
    n = len(X)
    A = np.zeros((2 * n, 12))
    Xh = np.hstack([Xn, np.ones((n, 1))])
    A[0::2, 0:4] = Xh
    A[0::2, 8:12] = -un[:, :1] * Xh
    A[1::2, 4:8] = Xh
    A[1::2, 8:12] = -un[:, 1:] * Xh
    # smallest eigenvector of A^T A (12 x 12): the same solution as the SVD of A, without the tall SVD
    P = np.linalg.eigh(A.T @ A)[1][:, 0].reshape(3, 4)
    return np.linalg.inv(Tu) @ P @ Tx


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P -> K (positive diagonal), R (det +1), t."""
    M = P[:, :3]
    if np.linalg.det(M) < 0:
        P = -P
        M = -M
    # RQ via QR of the flipped transpose
    flip = np.eye(3)[::-1]
    Q, R = np.linalg.qr((flip @ M).T)
    K = flip @ R.T @ flip
    Rot = flip @ Q.T
    S = np.diag(np.sign(np.diag(K)))
    K, Rot = K @ S, S @ Rot
    t = np.linalg.solve(K, P[:, 3])
    scale = K[2, 2]
    return K / scale, Rot, t


def fit_camera(name: str, X: np.ndarray, uv: np.ndarray, size: tuple[int, int]) -> tuple[Camera, dict]:
    """Camera with pose world -> camera from correspondences."""
    if len(X) < MIN_POINTS:
        raise SandtrackError(f"camera {name}: only {len(X)} known points; at least {MIN_POINTS} are needed")
    centred = X - X.mean(0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if np.ptp(uv, axis=0).min() <= 0:
        raise SandtrackError(f"camera {name}: the pixels of the known points do not spread over the image")
    if sv[2] <= 1e-3 * sv[0]:
        raise SandtrackError(
            f"camera {name}: the known points lie on one plane; a single plane cannot fix the camera this way: "
            "use points spread in depth (several board positions or a 3D target), or calibrate with the board")
    K, R, t = decompose_projection(dlt_projection(X, uv))
    K[0, 1] = 0.0
    rvec, _ = from_T(np.vstack([np.hstack([R, t[:, None]]), [0, 0, 0, 1]]))

    # The points play the part of one rigid "board" whose pose is the camera's world -> camera pose.
    obs = Observations(cam=np.zeros(len(X), int), frame=np.zeros(len(X), int), corner=np.zeros(len(X), int),
                       board_xyz=X, uv=uv)

    def fit(mask, start: BundleState | None = None):
        st = start.copy() if start is not None else BundleState(
            cam_rvec=np.zeros((1, 3)), cam_tvec=np.zeros((1, 3)), K=K[None].copy(), dist=[np.zeros(5)],
            models=["pinhole"], frame_rvec=rvec[None].copy(), frame_tvec=t[None].copy(), fixed_k3=[False])
        st.dist_free = [np.asarray(mask, bool)]
        st.dist[0] = np.where(st.dist_free[0], st.dist[0], 0.0)
        st, _ = bundle_adjust(st, obs, free_intrinsics=False, free_cameras=False)  # pose first
        return bundle_adjust(st, obs, free_cameras=False, f_scale=2.0)

    state, info = fit([1, 1, 1, 1, 1])
    k3_note = "free"
    if not radial_is_monotonic(state.dist[0], state.K[0], size):
        state, info = fit([1, 1, 1, 1, 0], state)
        k3_note = "fixed at 0 (a free k3 folded the image edge back)"
    Kp, d = state.K[0], state.dist[0]
    rv, tv = state.frame_rvec[0], state.frame_tvec[0]
    err = np.linalg.norm(residuals(state, obs), axis=1)
    rmse = float(np.sqrt(np.mean(err ** 2)))
    cam = Camera(name=name, width=size[0], height=size[1], matrix=Kp, distortion=d, rvec=rv, tvec=tv, rmse_px=rmse)
    return cam, {"rmse_px": rmse, "points": int(len(X)), "k3": k3_note,
                 "fx": float(Kp[0, 0]), "fy": float(Kp[1, 1]), "cx": float(Kp[0, 2]), "cy": float(Kp[1, 2])}


def calibrate_from_points(df: pd.DataFrame, cams: dict[str, tuple[str, str]],
                          sizes: dict[str, tuple[int, int]] | None = None) -> Calibration:
    """Fit every camera; rig frame = first camera's; world frame = the points' frame."""
    X_all = df[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
    cameras: dict[str, Camera] = {}
    reports = {}
    for name, (cx, cy) in cams.items():
        uv = df[[cx, cy]].to_numpy(float)
        ok = np.isfinite(uv).all(1) & np.isfinite(X_all).all(1)
        if sizes and name in sizes:
            size = sizes[name]
        elif not ok.any():
            raise SandtrackError(f"camera {name}: no row has both its pixels and X, Y, Z")
        else:
            size = (int(np.ceil(np.max(uv[ok, 0]) + 1)), int(np.ceil(np.max(uv[ok, 1]) + 1)))
            size = _standard_size(size)
        try:
            cameras[name], reports[name] = fit_camera(name, X_all[ok], uv[ok], size)
        except (np.linalg.LinAlgError, ValueError) as exc:  # degenerate numbers (e.g. 1e300) the checks let through
            raise SandtrackError(f"camera {name}: cannot fit a camera to these points ({exc})") from None
    first = next(iter(cameras))
    T0w = to_T(cameras[first].rvec, cameras[first].tvec)
    world_from_rig = inv_T(T0w)
    for cam in cameras.values():
        r, t = from_T(to_T(cam.rvec, cam.tvec) @ world_from_rig)
        cam.rvec, cam.tvec = r, t
    rmse = float(np.sqrt(np.mean([r["rmse_px"] ** 2 for r in reports.values()])))
    cal = Calibration(cameras=cameras, world_from_rig=world_from_rig)
    # how well the fitted cameras give the known points back (triangulated from their own pixels)
    from ..triangulation import triangulate

    xyz, _ = triangulate(cal, {n: df[list(c)].to_numpy(float) for n, c in cams.items()}, refine=True)
    d = np.linalg.norm(xyz - X_all, axis=1)
    d = d[np.isfinite(d)]
    cal.report = {"method": "from known points", "reprojection_rmse_px": rmse, "per_camera": reports,
                  "points": int(len(df)), "xyz_rmse_mm": float(np.sqrt(np.mean(d ** 2))) if len(d) else None,
                  "xyz_mean_mm": float(np.mean(d)) if len(d) else None}
    return cal


def _standard_size(size: tuple[int, int]) -> tuple[int, int]:
    """Smallest common video size holding all pixels (the table has no image size)."""
    for w, h in [(640, 480), (1280, 720), (1920, 1080), (2704, 1520), (3840, 2160), (4000, 3000), (5312, 2988)]:
        if size[0] <= w and size[1] <= h:
            return w, h
    return size
