"""Calibration from known correspondences (pixels in each camera + world X, Y, Z), e.g. a surveyed
3D target or a pixel/XYZ table exported by another tool.

Per camera: normalised DLT for the 3x4 projection matrix, RQ decomposition into K, R, t, then a
nonlinear fit of K, the lens model's distortion terms and the pose on the distorted reprojection
error (least squares: a robust loss changed no held-out error on the real stepped target by more
than 0.001 mm). The world frame is the points' frame.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from ..camera import Calibration, Camera, CameraUncertainty
from ..errors import SandtrackError
from ..lens import LENSES, Lens, get_lens, lens_of, padded, project
from ..xyz_pixels import camera_columns
from .bundle import BundleState
from .geometry import from_T, inv_T, larger, radial_is_monotonic, to_T
from .intrinsics import opencv_flags
from .known_point_errors import known_point_errors
from .lens_select import Candidate, choose, report, select_lens, why
from .model_choice import point_fit_spread, spread_line
from .point_uncertainty import into_rig, jackknife_covariance, parameter_names, point_fit_uncertainty
from .region import covered_pct, image_region
from .report import camera_parameters

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
    cams = camera_columns([str(c) for c in df.columns])
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


def point_groups(df: pd.DataFrame) -> tuple[np.ndarray | None, str]:
    """Groups of rows for cross-validation: the `frame` column (board poses) when it has at least 3
    values; else the planes of a stepped 3D target (the world coordinate with the fewest distinct
    values, 3 to 12, each held by 4 points or more); else None (each camera then uses blocks of its
    image, see `image_blocks`)."""
    if "frame" in df.columns:
        f = pd.to_numeric(df["frame"], errors="coerce").to_numpy(float)
        if np.isfinite(f).all() and len(np.unique(f)) >= 3:
            return np.unique(f, return_inverse=True)[1], "frames"
    X = np.round(df[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float), 3)
    planes = []
    for k in range(3):
        vals, inv, counts = np.unique(X[:, k], return_inverse=True, return_counts=True)
        if 3 <= len(vals) <= 12 and counts.min() >= 4 and np.isfinite(vals).all():
            planes.append((len(vals), k, inv))
    if planes:
        _, k, inv = min(planes, key=lambda p: p[:2])
        return inv, f"planes ({'XYZ'[k]} = const)"
    return None, ""


def image_blocks(uv: np.ndarray, k: int = 3) -> tuple[np.ndarray, str]:
    """A k x k grid over one camera's image, cut at its pixels' quantiles."""
    q = np.arange(1, k) / k
    cells = [np.searchsorted(np.quantile(uv[:, j], q), uv[:, j], side="right") for j in (0, 1)]
    return cells[1] * k + cells[0], "image blocks"


def on_two_planes(X: np.ndarray) -> bool:
    """The points lie on exactly two planes of one world coordinate (a stepped target with too few planes
    to leave one out), 4 points or more on each."""
    X = np.round(X[np.isfinite(X).all(axis=1)], 3)
    for k in range(3):
        vals, counts = np.unique(X[:, k], return_counts=True)
        if len(vals) == 2 and counts.min() >= 4:
            return True
    return False


def world_blocks(X: np.ndarray, k: int = 3) -> tuple[np.ndarray, str]:
    """A k x k grid over the points' two widest world axes, cut at their quantiles: the same blocks in every
    camera."""
    axes = np.argsort(np.nanstd(X, axis=0))[::-1][:2]
    q = np.arange(1, k) / k
    cells = [np.searchsorted(np.nanquantile(X[:, a], q), X[:, a], side="right") for a in axes]
    return cells[1] * k + cells[0], "blocks of the target"


def units_within(groups: np.ndarray, uv: np.ndarray, per_unit: int = 5) -> np.ndarray:
    """The units a lens choice compares models on (see lens_select): each group cut into blocks of
    neighbouring points, a grid over its pixels of up to 3 x 3 blocks of about `per_unit` points or
    more. One id per point, unique across groups."""
    unit = np.zeros(len(groups), dtype=int)
    for g in np.unique(groups):
        rows = np.flatnonzero(groups == g)
        k = int(np.clip(np.floor(np.sqrt(len(rows) / per_unit)), 1, 3))
        unit[rows] = g * 9 + image_blocks(uv[rows], k)[0]
    return unit


def calibrate_from_points(df: pd.DataFrame, cams: dict[str, tuple[str, str]],
                          sizes: dict[str, tuple[int, int]] | None = None,
                          lens: str | dict[str, str] = "auto", jackknife: bool = True) -> Calibration:
    """Fit every camera; rig frame = first camera's; world frame = the points' frame.

    sizes: image size per camera where known (videos, --image-size); the others are unknown and never
    used in the fit (the file gets the smallest common video size holding the pixels, flagged in the
    report). lens: one lens model name for every camera, or one per camera, or "auto". jackknife: False keeps
    no parameter covariance (for repeated fits that use no sd)."""
    X_all = df[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
    groups, kind = point_groups(df)
    in_3d = groups is None and len(cams) >= 2 and on_two_planes(X_all)
    if in_3d:  # the same left-out blocks in every camera, so that the lens choice can be judged in 3D
        groups, kind = world_blocks(X_all)
    cameras: dict[str, Camera] = {}
    reports = {}
    warnings = []
    for name, (cx, cy) in cams.items():
        uv = df[[cx, cy]].to_numpy(float)
        ok = np.isfinite(uv).all(1) & np.isfinite(X_all).all(1)
        if not ok.any():
            raise SandtrackError(f"camera {name}: no row has both its pixels and X, Y, Z")
        size = (sizes or {}).get(name)
        if size is None:
            warnings.append(f"camera {name}: image size unknown (give --image-size WxH or the videos); the "
                            "fit uses only the points, the file gets a size guessed from their extent")
        lens_name = lens.get(name, "auto") if isinstance(lens, dict) else lens
        try:
            cameras[name], reports[name] = fit_camera(name, X_all[ok], uv[ok], size, lens_name,
                                                      None if groups is None else groups[ok], kind)
        except (np.linalg.LinAlgError, ValueError) as exc:  # degenerate numbers (e.g. 1e300) the checks let through
            raise SandtrackError(f"camera {name}: cannot fit a camera to these points ({exc})") from None
        reports[name]["image_size"] = "given" if size is not None else "unknown (guessed for the file only)"
        if "warning" in reports[name]:
            warnings.append(reports[name]["warning"])
    cv = {n: r.pop("_cv") for n, r in reports.items() if "_cv" in r}
    pixels = {n: df[list(c)].to_numpy(float) for n, c in cams.items()}
    if in_3d and len(cv) >= 2:
        for name, (chosen, judged) in judge_in_3d(cv, X_all, pixels, groups).items():
            sel = reports[name]["lens_selection"]
            sel["judged_in_3d"] = judged
            sel["why"] = f"in 3D, {judged['why']} (on pixels alone, {sel['why']})"
            for row in sel["candidates"]:
                row["chosen"] = row["lens"] == chosen
            if chosen != cameras[name].lens:
                uv = pixels[name]
                ok = np.isfinite(uv).all(1) & np.isfinite(X_all).all(1)
                cam, rep = fit_camera(name, X_all[ok], uv[ok], (sizes or {}).get(name), chosen)
                cameras[name] = cam
                reports[name].update({k: v for k, v in rep.items() if k != "lens_selection"})
                reports[name]["lens_selection"]["chosen"] = chosen
    better = {}  # the better-fitting model's camera where a simpler one was kept
    for name, rep in reports.items():
        lens_b = better_fitting(rep.get("lens_selection"))
        if lens_b is not None and jackknife:
            uv = pixels[name]
            ok = np.isfinite(uv).all(1) & np.isfinite(X_all).all(1)
            try:
                better[name] = fit_camera(name, X_all[ok], uv[ok], (sizes or {}).get(name), lens_b)[0]
            except (SandtrackError, np.linalg.LinAlgError, ValueError) as exc:
                warnings.append(f"camera {name}: the lens choice's spread could not be computed ({exc})")
    first = next(iter(cameras))
    T0w = to_T(cameras[first].rvec, cameras[first].tvec)
    world_from_rig = inv_T(T0w)
    shared = known_point_errors(cameras, X_all, pixels, {n: len(parameter_names(c)) for n, c in cameras.items()})
    # The jackknife's units: blocks of neighbouring points, also where the lens choice took the dot grid's
    # columns of a two-plane target as its groups (each refit would extrapolate a whole column)
    units = groups if in_3d or not on_two_planes(X_all) else world_blocks(X_all)[0]
    uncertainty = {}
    for name, cam in cameras.items():
        uv = pixels[name]
        unc = point_fit_uncertainty(cam, X_all, uv, None if shared is None else shared["noise_px"][name])
        if unc is not None and jackknife:
            unc = _with_jackknife(unc, cam, X_all, uv, units, cv[name][1] if name in cv and units is groups else {})
            if name in better:
                try:
                    unc, moved = point_fit_spread(unc, cam, better[name], X_all)
                except (np.linalg.LinAlgError, ValueError) as exc:
                    warnings.append(f"camera {name}: the lens choice's spread could not be computed ({exc})")
                else:
                    sel = reports[name]["lens_selection"]
                    sel["spread"] = spread_line(sel.get("chosen"), better[name].lens, moved)
            uncertainty[name] = into_rig(unc, cam, world_from_rig)
        if shared is not None:
            reports[name]["noise_px"] = shared["noise_px"][name]
        r, t = from_T(to_T(cam.rvec, cam.tvec) @ world_from_rig)
        cam.rvec, cam.tvec = r, t
    rmse = float(np.sqrt(np.mean([r["rmse_px"] ** 2 for r in reports.values()])))
    fitted = {n: pixels[n][np.isfinite(pixels[n]).all(1) & np.isfinite(X_all).all(1)] for n in cameras}
    regions = {n: r for n, px in fitted.items() if (r := image_region(px)) is not None}
    for n, cam in cameras.items():
        reports[n]["calibrated_region_pct"] = covered_pct(fitted[n], (cam.width, cam.height))
    cal = Calibration(cameras=cameras, world_from_rig=world_from_rig, uncertainty=uncertainty, regions=regions)
    for name in reports:
        reports[name].update(camera_parameters(cal, name))
    # how well the fitted cameras give the known points back (triangulated from their own pixels)
    from ..triangulation import triangulate

    xyz, _ = triangulate(cal, pixels, refine=True)
    d = np.linalg.norm(xyz - X_all, axis=1)
    d = d[np.isfinite(d)]
    cal.report = {"method": "from known points", "reprojection_rmse_px": rmse, "per_camera": reports,
                  "points": int(len(df)), "xyz_rmse_mm": float(np.sqrt(np.mean(d ** 2))) if len(d) else None,
                  "xyz_mean_mm": float(np.mean(d)) if len(d) else None, "warnings": warnings}
    if shared is not None:
        cal.report["known_points_sd_mm"] = shared["sd_mm"]
        cal.report["known_points_in_two_cameras"] = shared["points"]
    return cal


def better_fitting(selection: dict | None) -> str | None:
    """The lens model that did best on the left-out points (in 3D where the choice was judged there) when a
    simpler one was kept; None otherwise."""
    if not selection:
        return None
    judged = selection.get("judged_in_3d")
    rows, key = (judged["candidates"], "cv_rmse_mm") if judged else (selection["candidates"], "cv_rmse_px")
    scored = [r for r in rows if r.get(key) is not None]
    if not scored:
        return None
    best = min(scored, key=lambda r: r[key])["lens"]
    return None if best == selection.get("chosen") else best


def _with_jackknife(unc, cam: Camera, X: np.ndarray, uv: np.ndarray, groups: np.ndarray | None, fits: dict):
    """`unc` raised, direction by direction, to the jackknife covariance over the units of points
    (`point_uncertainty`): `groups` (planes, frames, blocks of a two-plane target), else 3 x 3 blocks of
    the image. fits: the lens choice's fits without one group, (lens, group) -> state, reused when
    `groups` are its groups."""
    ok = np.isfinite(X).all(axis=1) & np.isfinite(uv).all(axis=1)
    X, uv = X[ok], uv[ok]
    units = groups[ok] if groups is not None else image_blocks(uv)[0]
    lens = get_lens(cam.lens) if cam.lens in LENSES else None
    if lens is None:
        return unc

    def refit(keep):
        if keep.sum() < MIN_POINTS:
            raise SandtrackError("too few points")
        left_out = np.unique(units[~keep])
        state = fits.get((cam.lens, int(left_out[0]))) if groups is not None and len(left_out) == 1 else None
        if state is None:
            state = _fit(X[keep], uv[keep], lens, _initial_pose(cam.name, X[keep], uv[keep]))
        return _projected(state, X)

    jk = jackknife_covariance(cam, X, uv, units, refit)
    if jk is None:
        return unc
    try:
        return CameraUncertainty(unc.parameters, larger(unc.covariance, jk.covariance), unc.sigma_px, unc.noise_px)
    except np.linalg.LinAlgError:
        return unc


def _initial_pose(name: str, X: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K (skew 0), rvec, tvec from the normalised DLT, after checking the points can fix a camera."""
    if len(X) < MIN_POINTS:
        raise SandtrackError(f"camera {name}: only {len(X)} known points; at least {MIN_POINTS} are needed")
    sv = np.linalg.svd(X - X.mean(0), compute_uv=False)
    if np.ptp(uv, axis=0).min() <= 0:
        raise SandtrackError(f"camera {name}: the pixels of the known points do not spread over the image")
    if sv[2] <= 1e-3 * sv[0]:
        raise SandtrackError(
            f"camera {name}: the known points lie on one plane; a single plane cannot fix the camera this way: "
            "use points spread in depth (several board positions or a 3D target), or calibrate with the board")
    K, R, t = decompose_projection(dlt_projection(X, uv))
    K[0, 1] = 0.0
    rvec, _ = from_T(np.vstack([np.hstack([R, t[:, None]]), [0, 0, 0, 1]]))
    return K, rvec, t


def _fit(X: np.ndarray, uv: np.ndarray, lens: Lens, start) -> BundleState:
    """The camera (world -> camera pose and the intrinsics of `lens`) fitted to the points: OpenCV's
    calibration (Levenberg-Marquardt, analytic derivatives) from the DLT's intrinsics, the points
    centred (float32 inside OpenCV) and the pixels shifted when the principal point lies outside the
    pixels' range (OpenCV refuses such a start). Fisheye: scipy, from a distortion-free start."""
    K0, rvec, t = start
    if lens.family == "fisheye":
        return _fit_fisheye(X, uv, lens, start)
    centre = X.mean(axis=0)
    shift = np.maximum(0.0, 1.0 - K0[:2, 2]) + 1.0
    span = np.maximum(uv.max(axis=0), K0[:2, 2]) + shift + 1.0
    K = K0.copy()
    K[:2, 2] += shift
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    try:
        _, K, d, rv, tv = cv2.calibrateCamera(
            [(X - centre).astype(np.float32)], [(uv + shift).astype(np.float32)],
            (int(np.ceil(span[0])), int(np.ceil(span[1]))), K, np.zeros(lens.length),
            flags=cv2.CALIB_USE_INTRINSIC_GUESS | opencv_flags(lens), criteria=crit)
    except cv2.error as exc:
        raise SandtrackError(f"the {lens.name} model cannot be fitted ({str(exc).strip().splitlines()[-1]})") from None
    K = np.asarray(K, dtype=float)
    K[:2, 2] -= shift
    rv = np.asarray(rv[0], dtype=float).ravel()
    tv = np.asarray(tv[0], dtype=float).ravel() - cv2.Rodrigues(rv)[0] @ centre
    return _state(K, np.asarray(d, dtype=float).ravel(), lens, rv, tv)


def _fit_fisheye(X: np.ndarray, uv: np.ndarray, lens: Lens, start) -> BundleState:
    K0, rvec, t = start
    x0 = np.concatenate([rvec, t, [K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2]], np.zeros(4)])

    def unpack(x):
        return np.array([[x[6], 0, x[8]], [0, x[7], x[9]], [0, 0, 1.0]]), x[10:]

    def fun(x):
        K, d = unpack(x)
        return (project(X @ cv2.Rodrigues(x[:3])[0].T + x[3:6], K, d, "fisheye") - uv).ravel()

    with np.errstate(all="ignore"):
        sol = least_squares(fun, x0, x_scale="jac", method="lm", max_nfev=40 * (len(x0) + 1))
    if not np.isfinite(sol.x).all():
        raise SandtrackError("the fisheye fit did not converge")
    K, d = unpack(sol.x)
    return _state(K, d, lens, sol.x[:3], sol.x[3:6])


def _state(K, d, lens: Lens, rvec, tvec) -> BundleState:
    return BundleState(cam_rvec=np.zeros((1, 3)), cam_tvec=np.zeros((1, 3)), K=np.asarray(K, float)[None],
                       dist=[padded(d, lens)], models=[lens.family], frame_rvec=np.array([rvec], float),
                       frame_tvec=np.array([tvec], float), fixed_k3=[False], dist_free=[lens.free])


def _projected(st: BundleState, X: np.ndarray) -> np.ndarray:
    R = cv2.Rodrigues(st.frame_rvec[0])[0]
    return project(X @ R.T + st.frame_tvec[0], st.K[0], st.dist[0], st.models[0])


def _data_radius(st: BundleState, uv: np.ndarray) -> float:
    """Normalised radius of the farthest observed point (stands for the image corner without a size)."""
    K = st.K[0]
    return float(np.max(np.hypot((uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1])))


def fit_camera(name: str, X: np.ndarray, uv: np.ndarray, size: tuple[int, int] | None, lens: str = "auto",
               groups: np.ndarray | None = None, groups_kind: str = "groups") -> tuple[Camera, dict]:
    """Camera with pose world -> camera from correspondences. `size`: the image size when known (None:
    unknown; only the points' own extent is then used). lens: a name of `lens.LENSES`, or "auto": chosen
    by cross-validation over `groups` (one id per point; whole groups are left out)."""
    start = _initial_pose(name, X, uv)
    info: dict = {}
    if lens == "auto":
        chosen, info["lens_selection"], info["_cv"] = _select(name, X, uv, size, start, groups, groups_kind)
        state = chosen
    else:
        model = get_lens(lens)
        state = _fit(X, uv, model, start)
        if not _monotonic(state, size, uv):
            if model.name == "standard":
                state = _fit(X, uv, get_lens("tangential"), start)
                info["k3"] = "fixed at 0 (a free k3 folded the image edge back)"
            else:
                info["warning"] = (f"camera {name}: the {model.name} lens model folds the image edge back "
                                   "(over-fitting where the points do not reach); use a simpler --lens or --lens auto")
    Kp, d = state.K[0], state.dist[0]
    err = np.linalg.norm(_projected(state, X) - uv, axis=1)
    rmse = float(np.sqrt(np.mean(err ** 2)))
    w, h = size if size is not None else _standard_size(
        (int(np.ceil(np.max(uv[:, 0]) + 1)), int(np.ceil(np.max(uv[:, 1]) + 1))))
    cam = Camera(name=name, width=w, height=h, matrix=Kp, distortion=d, rvec=state.frame_rvec[0],
                 tvec=state.frame_tvec[0], model=state.models[0], rmse_px=rmse, lens=lens_of(d, state.models[0]).name
                 if lens == "auto" or "k3" in info else lens)
    return cam, {"rmse_px": rmse, "points": int(len(X)), "lens": cam.lens, **info,
                 "fx": float(Kp[0, 0]), "fy": float(Kp[1, 1]), "cx": float(Kp[0, 2]), "cy": float(Kp[1, 2]),
                 "distortion": [float(v) for v in d]}


def _monotonic(st: BundleState, size, uv) -> bool:
    return radial_is_monotonic(st.dist[0], st.K[0], size, st.models[0], radius=_data_radius(st, uv))


def _select(name, X, uv, size, start, groups, groups_kind) -> tuple[BundleState, dict]:
    if groups is None:
        groups, groups_kind = image_blocks(uv)
    ids = np.unique(groups)

    folds = {}  # (lens, the one group left out) -> the fit without it, for judging the choice in 3D

    def fit(lens_name, train):
        m = np.isin(groups, train)
        if len(train) < 2 or m.sum() < MIN_POINTS:
            raise SandtrackError("too few points left to fit")
        state = _fit(X[m], uv[m], get_lens(lens_name), start if m.all() else _initial_pose(name, X[m], uv[m]))
        left_out = np.setdiff1d(ids, train)
        if len(left_out) == 1:
            folds[(lens_name, int(left_out[0]))] = state
        return state

    units = units_within(groups, uv)

    def score(st, test):
        e2 = np.sum((_projected(st, X) - uv) ** 2, axis=1)
        ids = [u for g in test for u in np.unique(units[groups == g])]
        return np.array([np.sum(e2[units == u]) for u in ids]), np.array([np.sum(units == u) for u in ids])

    def check(lens_name, st):
        return None if _monotonic(st, size, uv) else "its radial distortion folds the image edge back"

    n_folds = len(ids) if len(ids) <= 10 else 5
    cands, chosen = select_lens(ids, fit, score, n_folds=n_folds, check=check)
    return (chosen.fitted, report(cands, groups_kind, len(ids), n_folds, "blocks of neighbouring points"),
            (cands, folds, chosen.lens))


def judge_in_3d(cv: dict, X: np.ndarray, pixels: dict[str, np.ndarray], groups: np.ndarray) -> dict:
    """The lens choice judged where it matters, on the left-out points' 3D error: camera by camera, each of
    its candidates (fitted without a block of the target) with the other cameras' current choices (fitted
    without the same block), the block's points triangulated; the simplest candidate not significantly
    worse than the best (`lens_select.choose`, units: blocks of neighbouring points within the left-out
    blocks). Pixels alone favoured terms that fit the image inside the fitted planes but not the space
    between or beyond them. cv: per camera (its candidates, their fits per left-out group, its choice).
    Returns per camera (the lens chosen, its report)."""
    axes = np.argsort(np.nanstd(X, axis=0))[::-1][:2]
    units = units_within(groups, X[:, axes])
    current = {n: c[2] for n, c in cv.items()}
    ids = np.unique(groups)
    out = {}
    for name, (cands, _, _) in cv.items():
        errors = {}
        for cand in cands:
            if cand.cv_rmse_px is not None:
                e = _block_errors(cv, {name: cand.lens, **{n: v for n, v in current.items() if n != name}}, X,
                                  pixels, groups, ids)
                if e is not None:
                    errors[cand.lens] = e
        if len(errors) < 2:
            continue
        common = np.all([np.isfinite(e) for e in errors.values()], axis=0)  # every candidate on the same points
        judged = []
        for cand in cands:
            if cand.lens in errors:
                c3 = Candidate(lens=cand.lens, parameters=cand.parameters, train_rmse_px=cand.train_rmse_px)
                e = np.where(common, errors[cand.lens], 0.0)
                c3.sse = np.array([np.sum(e[units == u]) for u in np.unique(units)])
                c3.count = np.array([np.sum(common[units == u]) for u in np.unique(units)])
                c3.cv_rmse_px = float(np.sqrt(np.sum(c3.sse) / max(np.sum(c3.count), 1)))  # here mm
                judged.append(c3)
        chosen = choose(judged)
        current[name] = chosen.lens
        out[name] = (chosen.lens, {
            "chosen": chosen.lens, "compared": "3D error (mm) of the left-out blocks' points, triangulated with "
            "the other cameras' choices", "why": why(chosen, judged),
            "candidates": [{**c.row(), "cv_rmse_mm": c.cv_rmse_px} for c in judged]})
    return out


def _block_errors(cv: dict, lenses: dict[str, str], X: np.ndarray, pixels: dict, groups: np.ndarray,
                  ids: np.ndarray) -> np.ndarray | None:
    """Squared 3D error (mm²) of every point, triangulated by the cameras fitted without its block (a
    camera without such a fit, one that does not see the block, left out); None when the first camera of
    `lenses`, the one judged, has no fit without a block it sees."""
    from ..triangulation import triangulate

    err = np.full(len(X), np.nan)
    judged = next(iter(lenses))
    for g in ids:
        rows = groups == g
        cams = {}
        for n, lens in lenses.items():
            state = cv[n][1].get((lens, int(g)))
            if state is None:
                if n == judged and np.isfinite(pixels[n][rows]).all(axis=1).any():
                    return None
                continue
            cams[n] = Camera(name=n, width=4096, height=4096, matrix=state.K[0], distortion=state.dist[0],
                             rvec=state.frame_rvec[0], tvec=state.frame_tvec[0], model=state.models[0],
                             rmse_px=next(c.train_rmse_px for c in cv[n][0] if c.lens == lens))
        if len(cams) >= 2:
            xyz, _ = triangulate(Calibration(cameras=cams), {n: pixels[n][rows] for n in cams}, refine=True)
            err[rows] = np.sum((xyz - X[rows]) ** 2, axis=1)
    return err


def _standard_size(size: tuple[int, int]) -> tuple[int, int]:
    """Smallest common video size holding all pixels (the table has no image size)."""
    for w, h in [(640, 480), (1280, 720), (1920, 1080), (2704, 1520), (3840, 2160), (4000, 3000), (5312, 2988)]:
        if size[0] <= w and size[1] <= h:
            return w, h
    return size
