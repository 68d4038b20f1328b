"""Per-camera intrinsics from board views: view selection for coverage, OpenCV calibration (any lens
model of `lens.py`), per-view errors with the worst views dropped, a coverage report, the lens model
chosen by cross-validation over whole board views (`--lens auto`), and a guard against an over-fitted
k3 when the standard model is forced."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..board import BoardSpec
from ..errors import SandtrackError
from ..lens import LENSES, Lens, get_lens, padded
from .detect import BoardView
from .geometry import distort_project, radial_is_monotonic
from .lens_select import best_of, select_lens
from .lens_select import report as lens_report

GRID = (8, 6)  # coverage cells across, down


@dataclass
class IntrinsicsResult:
    name: str
    model: str
    size: tuple[int, int]
    K: np.ndarray
    dist: np.ndarray
    rmse_px: float
    frames: list[int]  # views used
    per_view_rmse: dict[int, float]
    poses: dict[int, tuple[np.ndarray, np.ndarray]]  # frame -> (rvec, tvec) board -> camera
    dropped: list[int] = field(default_factory=list)
    k3: str = "free"
    coverage: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    lens: str = "standard"
    lens_selection: dict | None = None  # the cross-validation of the candidates (lens "auto")
    # the candidate that did best on the left-out views where a simpler one was kept (lens "auto")
    better_fitting: str | None = None

    def report(self) -> dict:
        return {
            "model": self.model,
            "lens": self.lens,
            "rmse_px": self.rmse_px,
            "views_used": len(self.frames),
            "views_dropped": len(self.dropped),
            "fx": float(self.K[0, 0]), "fy": float(self.K[1, 1]),
            "cx": float(self.K[0, 2]), "cy": float(self.K[1, 2]),
            "distortion": self.dist.tolist(),
            "k3": self.k3,
            "worst_views": [[int(f), float(e)] for f, e in
                            sorted(self.per_view_rmse.items(), key=lambda kv: -kv[1])[:5]],
            "dropped_views": [int(f) for f in self.dropped],
            "coverage": self.coverage,
            "warnings": self.warnings,
            **({"lens_selection": self.lens_selection} if self.lens_selection else {}),
        }


def cells_of(corners: np.ndarray, size: tuple[int, int]) -> set[int]:
    w, h = size
    cx = np.clip((corners[:, 0] / w * GRID[0]).astype(int), 0, GRID[0] - 1)
    cy = np.clip((corners[:, 1] / h * GRID[1]).astype(int), 0, GRID[1] - 1)
    return set((cy * GRID[0] + cx).tolist())


def select_views(views: dict[int, BoardView], size: tuple[int, int], max_views: int) -> list[int]:
    """Greedy choice: first views that cover new image cells (most corners first), then evenly spread
    views in time for pose variety, up to max_views."""
    frames = sorted(views)
    if len(frames) <= max_views:
        return frames
    covered: set[int] = set()
    chosen: list[int] = []
    cells = {f: cells_of(views[f].corners, size) for f in frames}
    while len(chosen) < max_views:
        best, gain = None, 0
        for f in frames:
            if f in chosen:
                continue
            g = len(cells[f] - covered) * 1000 + len(views[f])
            if len(cells[f] - covered) > 0 and g > gain:
                best, gain = f, g
        if best is None:
            break
        chosen.append(best)
        covered |= cells[best]
    rest = [f for f in frames if f not in chosen]
    need = max_views - len(chosen)
    if need > 0 and rest:
        idx = np.unique(np.linspace(0, len(rest) - 1, need).round().astype(int))
        chosen += [rest[i] for i in idx]
    return sorted(chosen)


def _distinct(views: dict[int, BoardView], min_move_px: float = 3.0, lookback: int = 30) -> dict[int, BoardView]:
    """Drop views where the board sits where it was in one of the last `lookback` kept views (a board held
    still gives the same view many times over, which adds nothing but weight)."""
    if not views:
        return {}
    n_ids = 1 + max(int(v.ids.max()) for v in views.values() if len(v))
    kept: dict[int, BoardView] = {}
    recent = np.full((0, n_ids, 2), np.nan)  # corners of the last kept views, by corner id (NaN: not seen)
    for f in sorted(views):
        v = views[f]
        dense = np.full((n_ids, 2), np.nan)
        dense[v.ids] = v.corners
        if len(recent):
            d = np.linalg.norm(recent - dense[None], axis=2)  # (kept, ids), NaN where either misses a corner
            common = np.isfinite(d).sum(axis=1)
            with np.errstate(all="ignore"):
                med = np.nanmedian(np.where(common[:, None] > 0, d, 0.0), axis=1)
            if np.any((common >= 0.8 * len(v.ids)) & (med < min_move_px)):
                continue
        kept[f] = v
        recent = np.concatenate([recent, dense[None]])[-lookback:]
    return kept


def _observed_radius(corners: list[np.ndarray], K: np.ndarray) -> float:
    """Normalised radius of the farthest corner from the principal point."""
    c = np.concatenate(corners)
    return float(np.max(np.hypot((c[:, 0] - K[0, 2]) / K[0, 0], (c[:, 1] - K[1, 2]) / K[1, 1])))


def coverage_report(views: dict[int, BoardView], frames: list[int], size: tuple[int, int], K: np.ndarray,
                    poses: dict[int, tuple[np.ndarray, np.ndarray]]) -> dict:
    w, h = size
    covered: set[int] = set()
    r_max = 0.0
    for f in frames:
        c = views[f].corners
        covered |= cells_of(c, size)
        r_max = max(r_max, float(np.max(np.hypot(c[:, 0] - K[0, 2], c[:, 1] - K[1, 2]))))
    r_img = float(np.max(np.hypot(np.array([0, w]) - K[0, 2], np.array([[0], [h]]) - K[1, 2])))
    depths, tilts = [], []
    for f in frames:
        if f in poses:
            R = cv2.Rodrigues(poses[f][0])[0]
            depths.append(float(poses[f][1][2]))
            tilts.append(float(np.degrees(np.arccos(min(1.0, abs(R[2, 2]))))))
    return {
        "image_cells_covered": len(covered) / (GRID[0] * GRID[1]),
        "radial_coverage": r_max / r_img if r_img > 0 else 0.0,
        "depth_mm": [min(depths), max(depths)] if depths else None,
        "tilt_deg": [min(tilts), max(tilts)] if tilts else None,
    }


def opencv_flags(lens: Lens) -> int:
    """cv2.calibrateCamera flags that fit exactly the terms of a pinhole lens model (the distortion
    vector's length follows from them: 14 tilted, 12 thin prism, 8 rational, else 5)."""
    t = set(lens.terms)
    flags = 0
    for term, fix in (("k1", cv2.CALIB_FIX_K1), ("k2", cv2.CALIB_FIX_K2), ("k3", cv2.CALIB_FIX_K3),
                      ("p1", cv2.CALIB_ZERO_TANGENT_DIST)):
        if term not in t:
            flags |= fix
    for term, model in (("tau_x", cv2.CALIB_TILTED_MODEL), ("s1", cv2.CALIB_THIN_PRISM_MODEL),
                        ("k4", cv2.CALIB_RATIONAL_MODEL)):
        if term in t:
            flags |= model
    if lens.length >= 8 and "k4" not in t:
        flags |= cv2.CALIB_FIX_K4 | cv2.CALIB_FIX_K5 | cv2.CALIB_FIX_K6
    if lens.length >= 12 and "s1" not in t:
        flags |= cv2.CALIB_FIX_S1_S2_S3_S4
    return flags


def _calibrate(obj, img, size, lens: Lens, guess: tuple[np.ndarray, np.ndarray] | None = None):
    """(rms, K, distortion at the lens's length, rvecs, tvecs) of one camera from board views.

    OpenCV's calibration, except for the fisheye model and a tilted sensor (OpenCV's tilted model
    took 2-7 s for 30 views, against 0.03-0.09 s for the others): those start from OpenCV's fit
    without the tilt (distortion-free for the fisheye) and finish in our bundle adjustment."""
    # 100 iterations stopped short of the minimum on a wide lens (0.75 px against 0.07, focal 2 % off);
    # the tolerance ends a converged fit long before the count
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 500, 1e-9)
    obj32 = [o.astype(np.float32) for o in obj]
    img32 = [i.astype(np.float32) for i in img]
    start = _start_lens(lens)
    flags, K0, D0 = opencv_flags(start), None, None
    if guess is not None:  # a start near the answer: on subsets of a session, OpenCV's own start fell into
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS  # a false minimum (0.74 px against 0.05)
        K0 = np.array(guess[0], dtype=np.float64)
        D0 = np.zeros(start.length) if start.family != lens.family else padded(guess[1], start)
    rms, K, D, rvecs, tvecs = cv2.calibrateCamera(obj32, img32, size, K0, D0, flags=flags, criteria=crit)
    if start is lens:
        return float(rms), K, padded(np.asarray(D, dtype=np.float64).ravel(), lens), rvecs, tvecs
    from .bundle import BundleState, Observations, bundle_adjust

    n = [len(o) for o in obj]
    obs = Observations(cam=np.zeros(sum(n), int), frame=np.repeat(np.arange(len(obj)), n),
                       corner=np.zeros(sum(n), int), board_xyz=np.concatenate(obj), uv=np.concatenate(img))
    d0 = np.zeros(lens.length) if lens.family == "fisheye" else padded(np.asarray(D, float).ravel(), lens)
    state = BundleState(cam_rvec=np.zeros((1, 3)), cam_tvec=np.zeros((1, 3)), K=np.asarray(K, float)[None],
                        dist=[d0], models=[lens.family], frame_rvec=np.array([np.ravel(r) for r in rvecs]),
                        frame_tvec=np.array([np.ravel(t) for t in tvecs]), fixed_k3=[False], dist_free=[lens.free])
    state, info = bundle_adjust(state, obs, free_cameras=False, loss="linear")
    return info["rmse_px"], state.K[0], state.dist[0], list(state.frame_rvec), list(state.frame_tvec)


def _start_lens(lens: Lens) -> Lens:
    """The model OpenCV fits first: the lens itself, or without its tilt, or none for the fisheye."""
    if lens.family == "fisheye":
        return LENSES["none"]
    if "tau_x" not in lens.terms:
        return lens
    terms = set(lens.terms) - {"tau_x", "tau_y"}
    return next(m for m in LENSES.values() if m.family == "pinhole" and set(m.terms) == terms)


def _view_rmse(obj, img, K, D, rvec, tvec, model) -> float:
    R = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))[0]
    proj = distort_project(obj @ R.T + np.ravel(tvec), K, D, model)
    return float(np.sqrt(np.mean(np.sum((proj - img) ** 2, axis=1))))


def calibrate_intrinsics(name: str, views: dict[int, BoardView], board: BoardSpec, size: tuple[int, int],
                         model: str = "auto", max_views: int = 30, min_views: int = 4,
                         n_folds: int = 3) -> IntrinsicsResult:
    """Calibrate one camera from its board views (frame -> BoardView).

    model: a lens model name (`lens.LENSES`; "pinhole" means "standard"), or "auto": every candidate
    is cross-validated over whole board views and the simplest not significantly worse than the best
    is kept (lens_select)."""
    lens_name = "standard" if model == "pinhole" else model
    if lens_name != "auto":
        get_lens(lens_name)
    if len(views) < min_views:
        raise SandtrackError(
            f"camera {name}: the board was found in only {len(views)} frame(s); record at least 10 sharp views "
            "of the whole board at different angles (tilted 20-45 degrees) and distances, covering the image")
    pts3d = board.corner_points_mm()
    sharp = np.array([views[f].sharpness for f in views])
    cut = 0.3 * np.nanmedian(sharp) if np.isfinite(sharp).any() else 0.0
    usable = {f: v for f, v in views.items() if not v.sharpness < cut}
    blurred = len(views) - len(usable)
    # Views with few corners make OpenCV's closed-form start unstable; keep them for the bundle only.
    rich = {f: v for f, v in usable.items() if len(v) >= max(6, 0.3 * board.n_corners)}
    if len(rich) >= min_views:
        usable = rich
    usable = _distinct(usable)
    if len(usable) < min_views:
        raise SandtrackError(
            f"camera {name}: only {len(usable)} distinct view(s) of the board (it hardly moved); record at least 10 "
            "views at different angles (tilted 20-45 degrees) and distances, covering the image")
    frames = select_views(usable, size, max_views)
    warnings: list[str] = []
    family = "fisheye" if lens_name == "fisheye" else "pinhole"

    def fit(fr, lens: Lens, guess=None):
        return _calibrate([pts3d[usable[f].ids] for f in fr], [usable[f].corners for f in fr], size, lens, guess)

    selection, better_fitting = None, None
    try:
        base = LENSES["fisheye" if family == "fisheye" else "tangential"]
        rms, K, D, rv, tv = fit(frames, base)
        # Drop the worst views once (wrong detections, motion blur), then refit.
        errs = [_view_rmse(pts3d[usable[f].ids], usable[f].corners, K, D, r, t, family)
                for f, r, t in zip(frames, rv, tv, strict=True)]
        med = float(np.median(errs))
        bad = [f for f, e in zip(frames, errs, strict=True) if e > max(3.0 * med, 0.5)]
        bad = sorted(bad, key=lambda f: -errs[frames.index(f)])[: max(0, len(frames) // 5)]
        dropped = list(bad)
        if bad:
            frames = [f for f in frames if f not in bad]
            rms, K, D, rv, tv = fit(frames, base)
        # Face-on views leave the focal length undetermined: refuse before any other model is fitted to them.
        _refuse_face_on(name, coverage_report(usable, frames, size, K, _poses(frames, rv, tv))["tilt_deg"])
        lens = base
        k3 = "n/a (fisheye k1..k4)" if family == "fisheye" else "fixed at 0"
        radial = coverage_report(usable, frames, size, K, {})["radial_coverage"]
        if lens_name == "standard":
            rms3, K3, D3, rv3, tv3 = fit(frames, LENSES["standard"])
            if not radial_is_monotonic(D3, K3, size):
                k3 = "fixed at 0: a free k3 folded the image edge back (over-fitting)"
                warnings.append(f"camera {name}: free k3 rejected (non-monotonic distortion); "
                                "record views with the board near the image corners")
            elif radial < 0.6:
                k3 = "fixed at 0: the board did not reach the image corners"
                warnings.append(f"camera {name}: board reached only {radial:.0%} of the image radius; k3 fixed")
            elif rms3 < rms * 0.995:
                k3 = "free"
                lens = LENSES["standard"]
                rms, K, D, rv, tv = rms3, K3, D3, rv3, tv3
        elif lens_name == "auto":
            on_all: dict[str, tuple] = {}  # each candidate's fit on every view: the folds start from it

            def fit_views(lname, train):
                sub = [f for f in frames if f in set(train.tolist())]
                if len(sub) == len(frames):
                    on_all[lname] = fit(frames, LENSES[lname])
                    return LENSES[lname], on_all[lname]
                return LENSES[lname], fit(sub, LENSES[lname], on_all[lname][1:3])

            def score(fitted, test):
                lens_c, (_, Kf, Df, _, _) = fitted
                sse, cnt = [], []
                for f in test:
                    v = usable[f]
                    pose = board_pose(v, board, Kf, Df, lens_c.family)
                    e = np.nan if pose is None else _view_rmse(pts3d[v.ids], v.corners, Kf, Df, *pose, lens_c.family)
                    sse.append(e * e * len(v))
                    cnt.append(len(v))
                return np.array(sse), np.array(cnt)

            def check(lname, fitted):
                lens_c, (_, Kf, Df, _, _) = fitted
                if lens_c.family == "pinhole" and not radial_is_monotonic(Df, Kf, None, radius=_observed_radius(
                        [usable[f].corners for f in frames], Kf)):
                    return "its radial distortion folds back within the board's reach"
                if radial < 0.6 and {"k3", "k4"} & set(lens_c.terms):
                    return f"the board reached only {radial:.0%} of the image radius (k3 and beyond unconstrained)"
                return None

            folds = len(frames) if len(frames) <= 10 else n_folds
            cands, chosen = select_lens(frames, fit_views, score, n_folds=folds, check=check)
            selection = lens_report(cands, "board views", len(frames), folds, "left-out board views")
            lens, (rms, K, D, rv, tv) = chosen.fitted
            best = best_of(cands)
            better_fitting = None if best is chosen else best.lens
            k3 = "free" if "k3" in lens.terms else "fixed at 0 (cross-validation)"
        elif lens_name != base.name:
            lens = LENSES[lens_name]
            rms, K, D, rv, tv = fit(frames, lens)
            k3 = "free" if "k3" in lens.terms else "fixed at 0"
            if lens.family == "pinhole" and not radial_is_monotonic(D, K, size):
                warnings.append(f"camera {name}: the {lens.name} lens model folds the image edge back "
                                "(over-fitting); use a simpler --lens or --lens auto")
    except cv2.error as exc:
        raise SandtrackError(f"camera {name}: calibration failed ({str(exc).strip().splitlines()[-1]}); "
                             "record more varied views of the board") from None
    poses = _poses(frames, rv, tv)
    per_view = {f: _view_rmse(pts3d[usable[f].ids], usable[f].corners, K, D, *poses[f], family) for f in frames}
    cov = coverage_report(usable, frames, size, K, poses)
    cov["blurred_views_skipped"] = blurred
    if cov["image_cells_covered"] < 0.5:
        warnings.append(f"camera {name}: the board covered only {cov['image_cells_covered']:.0%} of the image; "
                        "move it into the corners and edges too")
    _refuse_face_on(name, cov.get("tilt_deg"))
    return IntrinsicsResult(name=name, model=lens.family, size=size, K=K, dist=D, rmse_px=rms, frames=list(frames),
                            per_view_rmse=per_view, poses=poses, dropped=dropped, k3=k3, coverage=cov,
                            warnings=warnings, lens=lens.name, lens_selection=selection,
                            better_fitting=better_fitting)


def _poses(frames, rv, tv) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    return {f: (np.asarray(r, float).ravel(), np.asarray(t, float).ravel()) for f, r, t in zip(frames, rv, tv,
                                                                                              strict=True)}


def _refuse_face_on(name: str, tilt: list[float] | None) -> None:
    if tilt is not None and tilt[1] - tilt[0] < 5.0 and tilt[1] < 10.0:
        raise SandtrackError(
            f"camera {name}: every view shows the board nearly face-on (tilt {tilt[0]:.0f}-{tilt[1]:.0f} deg), "
            "so the focal length cannot be found; record views tilted 20-45 degrees in different directions")


def board_pose(view: BoardView, board: BoardSpec, K: np.ndarray, D: np.ndarray,
               model: str = "pinhole") -> tuple[np.ndarray, np.ndarray] | None:
    """Board -> camera pose of one view (IPPE for the planar board, then Levenberg-Marquardt)."""
    obj = board.corner_points_mm()[view.ids]
    img = view.corners
    if model == "fisheye":
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
        img = cv2.fisheye.undistortPoints(img.reshape(-1, 1, 2), K, D, P=K, criteria=crit).reshape(-1, 2)
        D = np.zeros(5)
    try:
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, D, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            return None
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, D, rvec, tvec)
    except cv2.error:
        return None
    return rvec.ravel(), tvec.ravel()
