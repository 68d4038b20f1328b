"""Multi-camera calibration from board detections: intrinsics per camera, relative poses from
shared views (a spanning tree over the cameras, robust averages), then bundle adjustment."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..board import BoardSpec
from ..camera import Calibration, Camera, CameraUncertainty
from ..errors import SandtrackError
from ..lens import LENSES, padded
from .bundle import (
    BundleState,
    Observations,
    bundle_adjust,
    camera_covariances,
    parameter_covariance,
    residuals,
    view_weights,
)
from .detect import BoardView
from .geometry import from_T, inv_T, mean_rotation, rotation_angle_deg, to_T
from .intrinsics import IntrinsicsResult, board_pose, calibrate_intrinsics
from .model_choice import lens_choice_spread

Views = dict[str, dict[int, BoardView]]


@dataclass
class RigResult:
    calibration: Calibration
    intrinsics: dict[str, IntrinsicsResult]
    state: BundleState
    frames: list[int]  # reference frames in the bundle adjustment (index = bundle frame index)
    obs: Observations
    bundle: dict = field(default_factory=dict)
    skipped_duplicates: int = 0
    skipped_blurred: int = 0  # camera views left out of the calibration as blurred
    warnings: list[str] = field(default_factory=list)
    # every camera's parameters ("CAMERA/NAME") and their joint covariance from the bundle adjustment
    joint_parameters: list[str] = field(default_factory=list)
    joint_covariance: np.ndarray | None = None

    def frame_pose(self, frame: int) -> np.ndarray | None:
        """Board -> rig 4x4 of a bundle-adjusted frame."""
        if frame not in self.frames:
            return None
        i = self.frames.index(frame)
        return to_T(self.state.frame_rvec[i], self.state.frame_tvec[i])


def make_observations(views: Views, names: list[str], frames: list[int], board: BoardSpec) -> Observations:
    pts = board.corner_points_mm()
    cam, frm, cid, uv = [], [], [], []
    for ci, n in enumerate(names):
        for fi, f in enumerate(frames):
            v = views[n].get(f)
            if v is None:
                continue
            cam.append(np.full(len(v), ci))
            frm.append(np.full(len(v), fi))
            cid.append(v.ids)
            uv.append(v.corners)
    if not cam:
        return Observations(np.zeros(0, int), np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 2)))
    cid = np.concatenate(cid)
    return Observations(np.concatenate(cam), np.concatenate(frm), cid, pts[cid], np.concatenate(uv))


def _drop_blurred(views: Views, fraction: float, min_keep: int) -> tuple[Views, int]:
    """Per camera with more than `min_keep` views, drop those less sharp than `fraction` of its median
    sharpness, keeping at least the `min_keep` sharpest. Motion blur shifts detected corners along the
    motion: a bias that more views do not average out and that the bundle absorbs into the principal
    point and tangential distortion. With few views every view counts, so they are all kept."""
    out: Views = {}
    dropped = 0
    for n, vs in views.items():
        sharp = np.array([v.sharpness for v in vs.values()], dtype=float)
        if fraction <= 0 or len(vs) <= min_keep or not np.isfinite(sharp).all():
            out[n] = vs
            continue
        order = np.argsort(-sharp)
        n_keep = max(min_keep, int(np.sum(sharp >= fraction * float(np.median(sharp)))))
        frames = list(vs)
        out[n] = {frames[i]: vs[frames[i]] for i in sorted(order[:n_keep])}
        dropped += len(vs) - n_keep
    return out, dropped


def _drop_near_duplicates(views: Views, frames: list[int], names: list[str], min_move_px: float) -> list[int]:
    """Skip frames where the board has not moved (by more than min_move_px on average) in any camera
    since the last kept frame."""
    kept: list[int] = []
    last: dict[str, BoardView] = {}
    for f in frames:
        moved = False
        for n in names:
            v = views[n].get(f)
            if v is None:
                continue
            prev = last.get(n)
            if prev is None:
                moved = True
                continue
            common, ia, ib = np.intersect1d(v.ids, prev.ids, return_indices=True)
            if len(common) < 4 or np.mean(np.linalg.norm(v.corners[ia] - prev.corners[ib], axis=1)) > min_move_px:
                moved = True
        if moved:
            kept.append(f)
            for n in names:
                if f in views[n]:
                    last[n] = views[n][f]
    return kept


def _relative_pose(poses_a: dict[int, np.ndarray], poses_b: dict[int, np.ndarray]) -> tuple[np.ndarray, int]:
    """Robust T_b_a from board poses seen by both cameras (medoid rotation, inliers averaged)."""
    common = sorted(set(poses_a) & set(poses_b))
    Ts = np.array([poses_b[f] @ inv_T(poses_a[f]) for f in common])
    Rs = Ts[:, :3, :3]
    ang = np.array([[rotation_angle_deg(Ri @ Rj.T) for Rj in Rs] for Ri in Rs])
    medoid = int(np.argmin(np.median(ang, axis=1)))
    t_med = np.median(Ts[:, :3, 3], axis=0)
    scale = max(np.linalg.norm(t_med), 1.0)
    inl = (ang[medoid] < max(3 * np.median(ang[medoid]), 2.0)) & (
        np.linalg.norm(Ts[:, :3, 3] - t_med, axis=1) < 0.2 * scale)
    if inl.sum() < 1:
        inl[medoid] = True
    T = np.eye(4)
    T[:3, :3] = mean_rotation(Rs[inl])
    T[:3, 3] = np.median(Ts[inl, :3, 3], axis=0)
    return T, len(common)


def calibrate_rig(views: Views, board: BoardSpec, sizes: dict[str, tuple[int, int]],
                  models: dict[str, str] | None = None, fixed_intrinsics: dict[str, Camera] | None = None,
                  max_frames: int = 200, max_intrinsic_views: int = 30, min_move_px: float = 1.5,
                  min_sharpness: float = 0.8, min_sharp_views: int = 100, reweight_rounds: int = 2,
                  progress: Callable[[str, int, int], None] | None = None, workers: int = 2) -> RigResult:
    names = list(views)
    models = models or {}
    if len(names) < 2:
        raise SandtrackError("calibration needs at least two cameras")
    for n in names:
        if not views[n]:
            raise SandtrackError(
                f"no board found in camera {n}: check the board file (columns, rows, dictionary, inverted) matches "
                "the printed board, and record it sharp, well lit and filling a good part of the image")
    many = np.array([len(views[n]) > min_sharp_views for n in names])  # before blurred views are dropped
    views, blurred = _drop_blurred(views, min_sharpness, min_sharp_views)
    # 1. intrinsics, two cameras at a time (OpenCV's calibration runs without the interpreter lock)
    intr: dict[str, IntrinsicsResult] = {}

    def intrinsics(n: str) -> IntrinsicsResult:
        if fixed_intrinsics and n in fixed_intrinsics:
            cam = fixed_intrinsics[n]
            return IntrinsicsResult(name=n, model=cam.model, size=(cam.width, cam.height), K=cam.matrix.copy(),
                                    dist=padded(cam.distortion, LENSES[cam.lens]), rmse_px=float("nan"),
                                    frames=[], per_view_rmse={}, poses={}, k3="given", lens=cam.lens)
        return calibrate_intrinsics(n, views[n], board, sizes[n], models.get(n, "auto"),
                                    max_views=max_intrinsic_views)

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        for k, (n, result) in enumerate(zip(names, pool.map(intrinsics, names), strict=True)):
            intr[n] = result
            if progress:
                progress("intrinsics", k + 1, len(names))
    # 2. frames for the bundle: multi-camera frames first, near duplicates skipped
    all_frames = sorted(set().union(*[set(views[n]) for n in names]))
    shared = [f for f in all_frames if sum(f in views[n] for n in names) >= 2]
    if not shared:
        raise SandtrackError(
            f"the board is never seen by two cameras at once ({', '.join(names)}): record it where the cameras' "
            "views overlap, moving it slowly through the shared space")
    frames = _drop_near_duplicates(views, all_frames, names, min_move_px)
    skipped = len(all_frames) - len(frames)
    multi = [f for f in frames if sum(f in views[n] for n in names) >= 2]
    single = [f for f in frames if f not in set(multi)]
    if len(multi) > max_frames:
        multi = [multi[i] for i in np.unique(np.linspace(0, len(multi) - 1, max_frames).round().astype(int))]
        single = []
    room = max_frames - len(multi)
    if len(single) > room:
        single = [single[i] for i in np.unique(np.linspace(0, len(single) - 1, room).round().astype(int))] \
            if room > 0 else []
    frames = sorted(multi + single)
    # 3. board -> camera poses for every view in the bundle
    cam_poses: dict[str, dict[int, np.ndarray]] = {n: {} for n in names}
    for n in names:
        r = intr[n]
        for f in frames:
            v = views[n].get(f)
            if v is None:
                continue
            p = board_pose(v, board, r.K, r.dist, r.model)
            if p is not None:
                cam_poses[n][f] = to_T(*p)
    # 4. relative poses along a maximum spanning tree rooted at the first camera
    T_cam_rig = {names[0]: np.eye(4)}
    while len(T_cam_rig) < len(names):
        best = None
        for a in T_cam_rig:
            for b in names:
                if b in T_cam_rig:
                    continue
                n_common = len(set(cam_poses[a]) & set(cam_poses[b]))
                if n_common and (best is None or n_common > best[2]):
                    best = (a, b, n_common)
        if best is None:
            missing = [b for b in names if b not in T_cam_rig]
            raise SandtrackError(
                f"camera(s) {', '.join(missing)} never see the board at the same time as {names[0]} (or a camera "
                "linked to it): record the board where those views overlap")
        a, b, _ = best
        T_ba, _ = _relative_pose(cam_poses[a], cam_poses[b])
        T_cam_rig[b] = T_ba @ T_cam_rig[a]
    # 5. board -> rig per frame, from the camera that sees most corners
    frame_T = []
    keep = []
    for f in frames:
        seen = [(len(views[n][f]), n) for n in names if f in cam_poses[n]]
        if not seen:
            continue
        _, n = max(seen)
        frame_T.append(inv_T(T_cam_rig[n]) @ cam_poses[n][f])
        keep.append(f)
    frames = keep
    frame_rt = [from_T(T) for T in frame_T]
    cam_rt = [from_T(T_cam_rig[n]) for n in names]
    state = BundleState(
        cam_rvec=np.array([r for r, _ in cam_rt]), cam_tvec=np.array([t for _, t in cam_rt]),
        K=np.array([intr[n].K for n in names]), dist=[intr[n].dist.copy() for n in names],
        models=[intr[n].model for n in names],
        frame_rvec=np.array([r for r, _ in frame_rt]), frame_tvec=np.array([t for _, t in frame_rt]),
        fixed_k3=[intr[n].k3.startswith("fixed") for n in names],
        dist_free=[LENSES[intr[n].lens].free for n in names])
    obs = make_observations(views, names, frames, board)
    if progress:
        progress("bundle", 0, 2)
    free_intr = not fixed_intrinsics
    state, info1 = bundle_adjust(state, obs, free_intrinsics=False)
    if progress:
        progress("bundle", 1, 2)
    state, info = bundle_adjust(state, obs, free_intrinsics=free_intr) if free_intr else (state, info1)
    # Views differ in noise (motion blur, focus, distance): in cameras with many views (the long sessions
    # where blur is common), weight each view by its estimated inverse noise variance.
    weights = None
    for _ in range(reweight_rounds if many.any() else 0):
        weights = np.where(many[obs.cam], view_weights(residuals(state, obs), obs), 1.0)
        state, info = bundle_adjust(state, obs, free_intrinsics=free_intr, weights=weights)
    info["initial_rmse_px"] = info1["initial_rmse_px"]
    if weights is not None:
        w = weights[many[obs.cam]]
        info["view_weights"] = {"cameras": [n for n, m in zip(names, many, strict=True) if m],
                                "min": float(w.min()), "median": float(np.median(w)), "max": float(w.max())}
    if progress:
        progress("bundle", 2, 2)
    labels, joint = parameter_covariance(state, obs, free_intr, weights=weights, details=info)
    better = {ci: intr[n].better_fitting for ci, n in enumerate(names) if free_intr and intr[n].better_fitting}
    not_spread = []
    if better:
        try:
            spread = lens_choice_spread(state, obs, labels, joint, better, names, weights,
                                        kept={ci: intr[names[ci]].lens for ci in better})
        except (np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            not_spread.append(f"the lens choice's spread could not be computed ({exc}): the sd holds the kept lens "
                              "models' covariance alone")
            better = {}
        else:
            labels, joint, state = spread.labels, spread.covariance, spread.state
            info["lens_choice_spread"] = spread.report
    res = residuals(state, obs)
    err = np.linalg.norm(res, axis=1)
    cameras = {}
    for ci, n in enumerate(names):
        m = obs.cam == ci
        cameras[n] = Camera(name=n, width=sizes[n][0], height=sizes[n][1], matrix=state.K[ci],
                            distortion=state.dist[ci],
                            rvec=state.cam_rvec[ci], tvec=state.cam_tvec[ci], model=state.models[ci],
                            rmse_px=float(np.sqrt(np.mean(err[m] ** 2))) if m.any() else None,
                            lens=intr[n].lens)
    warnings = [w for n in names for w in intr[n].warnings] + not_spread
    uncertainty = {names[c]: CameraUncertainty(p, cov, info["rmse_px"], better_lens=better.get(c))
                   for c, (p, cov) in camera_covariances(labels, joint).items()}
    return RigResult(calibration=Calibration(cameras=cameras, uncertainty=uncertainty), intrinsics=intr, state=state,
                     frames=frames, obs=obs, joint_parameters=[f"{names[c]}/{p}" for c, p in labels],
                     joint_covariance=joint,
                     bundle=info, skipped_duplicates=skipped, skipped_blurred=blurred,
                     warnings=warnings)


def fit_frame_poses(calibration: Calibration, views: Views, board: BoardSpec, frames: list[int],
                    initial: dict[int, np.ndarray] | None = None) -> dict[int, np.ndarray]:
    """Board -> rig pose of each frame with the cameras held fixed (every camera that sees it).
    Returns {frame: 4x4}."""
    names = [n for n in calibration.names if n in views]
    cams = [calibration.cameras[n] for n in names]
    T0, ok_frames = [], []
    for f in frames:
        if initial and f in initial:
            T0.append(initial[f])
            ok_frames.append(f)
            continue
        best = None
        for n, cam in zip(names, cams, strict=True):
            v = views[n].get(f)
            if v is None or (best is not None and len(v) <= best[0]):
                continue
            p = board_pose(v, board, cam.matrix, cam.distortion, cam.model)
            if p is not None:
                best = (len(v), inv_T(to_T(cam.rvec, cam.tvec)) @ to_T(*p))
        if best is not None:
            T0.append(best[1])
            ok_frames.append(f)
    if not ok_frames:
        return {}
    rt = [from_T(T) for T in T0]
    state = BundleState(
        cam_rvec=np.array([c.rvec for c in cams]), cam_tvec=np.array([c.tvec for c in cams]),
        K=np.array([c.matrix for c in cams]), dist=[c.distortion.copy() for c in cams], models=[c.model for c in cams],
        frame_rvec=np.array([r for r, _ in rt]), frame_tvec=np.array([t for _, t in rt]),
        fixed_k3=[False] * len(cams))
    obs = make_observations({n: views[n] for n in names}, names, ok_frames, board)
    state, _ = bundle_adjust(state, obs, free_intrinsics=False, free_cameras=False)
    return {f: to_T(state.frame_rvec[i], state.frame_tvec[i]) for i, f in enumerate(ok_frames)}
