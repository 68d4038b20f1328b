"""How the world frame moves with the calibration's parameters, and its own uncertainty.

The world frame is fitted to a reference seen through the calibrated cameras (world.py): a board lying in a
reference frame, or known points. A change of the cameras' parameters changes that fit, so the world frame
moves with them: near the reference most of a camera error cancels (the point and the reference are seen
through the same error). The world frame's motion is written ψ = (ω, τ), a world point X moving by
ω × X + τ (rad, mm). Per route:

- board in a reference frame: the board's pose is refitted to its detections with the cameras held fixed
  (rig.fit_frame_poses), so to first order dpose/dθ = -(JpᵀJp)⁻¹ Jpᵀ Jθ (Jp, Jθ: the weighted
  reprojection residuals' derivatives by the pose and by the parameters), and the pose's own covariance
  is (JpᵀJp)⁻¹ σ², σ² the reference detections' own noise (their residuals at the fit, less the share the
  cameras' stated error puts in them; whitened by each camera's corner noise), plus a shift shared by each
  camera's reference detections (SHARED_VIEW_ERROR);
- known points (Kabsch): ψ by central differences of the refit through perturbed cameras; its own
  covariance from the fit's residual, isotropic per point (the rigid fit's textbook covariance);
- no reference (world = rig): nothing moves it.
"""

from __future__ import annotations

import copy

import cv2
import numpy as np

from ..board import BoardSpec
from ..camera import Calibration, Camera, RigUncertainty
from .detect import BoardView
from .geometry import from_T, kabsch, to_T
from .world import world_from_board_pose

_POSE_STEP = np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
# A view's corners share an error (a detection bias of that view's obliquity, blur and light) that no residual
# shows, the board's pose absorbing it: allowed for as one shift of all of a camera's corners in a view, per
# image axis this many times one corner's noise (a Type B estimate: the twin's resting board, against its
# exact corners, shows 0.1-0.5 of it; benchmarks/README.md), in the reference view's detections here and in
# every corner's pixel sd (`view_shared_px`, set by the calibration from videos).
SHARED_VIEW_ERROR = 0.5
MIN_REFERENCE_DOF = 20  # residual degrees of freedom from which the reference view's own noise is measured
MIN_NOISE_FACTOR = 0.01  # its variance against the cameras' noise never below this (1/10 of their sd)


def perturbed(calibration: Calibration, parameters: list[str], delta: np.ndarray) -> Calibration:
    """A copy of `calibration` with each "CAMERA/NAME" parameter moved by `delta`."""
    out = copy.copy(calibration)
    out.cameras = {n: copy.deepcopy(c) for n, c in calibration.cameras.items()}
    for p, d in zip(parameters, np.asarray(delta, float), strict=True):
        if d != 0.0:
            camera, name = p.split("/", 1)
            _move(out.cameras[camera], name, float(d))
    return out


def _move(cam: Camera, name: str, d: float) -> None:
    if name[0] == "r":
        cam.rvec = cam.rvec + d * np.eye(3)["xyz".index(name[1])]
    elif name[0] == "t":
        cam.tvec = cam.tvec + d * np.eye(3)["xyz".index(name[1])]
    elif name[0] == "d":
        dist = cam.distortion.copy()
        dist[int(name[1:])] += d
        cam.distortion = dist
    else:
        K = cam.matrix.copy()
        K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[name]] += d
        cam.matrix = K


def psi(W: np.ndarray, W0: np.ndarray) -> np.ndarray:
    """(ω, τ) of the small motion W W0⁻¹ of a world frame (first order)."""
    D = W @ np.linalg.inv(W0)
    A = 0.5 * (D[:3, :3] - D[:3, :3].T)
    return np.array([A[2, 1], A[0, 2], A[1, 0], *D[:3, 3]])


def _steps(covariance: np.ndarray, fraction: float) -> np.ndarray:
    sd = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    return np.where(sd > 0, fraction * sd, 1e-9)


def _shared_shift_px(calibration: Calibration, name: str, noise: np.ndarray) -> np.ndarray:
    """(2,) the sd of a shift shared by a camera's corners in one view (px per image axis): the calibration's
    allowance (`view_shared_px`), else SHARED_VIEW_ERROR times the corners' noise."""
    unc = calibration.uncertainty.get(name)
    if unc is not None and unc.view_shared_px is not None:
        return np.asarray(unc.view_shared_px, float)
    return SHARED_VIEW_ERROR * np.asarray(noise, float)


def rig_frame(parameters: list[str], covariance: np.ndarray) -> RigUncertainty:
    """World = rig frame: the cameras' joint covariance alone."""
    n = len(parameters)
    return RigUncertainty(parameters, covariance, np.zeros((6, n)), np.zeros((6, 6)))


def board_reference(calibration: Calibration, views: dict[str, BoardView], board: BoardSpec,
                    T_rig_board: np.ndarray, origin_mm, parameters: list[str],
                    covariance: np.ndarray) -> RigUncertainty:
    """The world frame of a board lying in a reference frame (`views`: that frame's detection per camera,
    `T_rig_board`: its fitted pose), linearised at the fit."""
    from ..triangulation_sd import corner_noise_px

    pts = board.corner_points_mm()
    seen = [(n, v) for n, v in views.items() if n in calibration.cameras and len(v)]
    noise = {n: np.where(np.isfinite(s := corner_noise_px(calibration, n)) & (s > 0), s, 1.0) for n, _ in seen}

    def residuals(cal: Calibration, pose: np.ndarray) -> np.ndarray:
        R = cv2.Rodrigues(pose[:3])[0]
        out = [((cal.cameras[n].project(pts[v.ids] @ R.T + pose[3:]) - v.corners) / noise[n]).ravel()
               for n, v in seen]
        return np.concatenate(out)

    rvec, tvec = from_T(T_rig_board)
    pose0 = np.concatenate([rvec, tvec])
    Jp = np.stack([(residuals(calibration, pose0 + h * e) - residuals(calibration, pose0 - h * e)) / (2 * h)
                   for h, e in zip(_POSE_STEP, np.eye(6), strict=True)], axis=1)
    steps = _steps(covariance, 1e-3)
    Jt = np.stack([(residuals(perturbed(calibration, parameters, h * e), pose0)
                    - residuals(perturbed(calibration, parameters, -h * e), pose0)) / (2 * h)
                   for h, e in zip(steps, np.eye(len(parameters)), strict=True)], axis=1) \
        if parameters else np.zeros((len(Jp), 0))
    inv_info = np.linalg.pinv(Jp.T @ Jp)
    dpose = -inv_info @ Jp.T @ Jt
    # the reference view's own noise, from its own residuals (a board at rest is sharper than the average view
    # whose noise the cameras' figures hold), less what the cameras' own error puts in them
    r0 = residuals(calibration, pose0)
    dof = len(r0) - 6
    factor = 1.0
    if dof >= MIN_REFERENCE_DOF:
        moved = Jt - Jp @ (inv_info @ (Jp.T @ Jt))  # a parameter change's residuals once the pose refits
        cameras = float(np.einsum("ij,jk,ik->", moved, covariance, moved))
        factor = max(float(r0 @ r0) - cameras, MIN_NOISE_FACTOR * dof) / dof
    pose_cov = inv_info * factor
    # each camera's reference detections shifted together (whitened), by the calibration's allowance for it
    G = np.zeros((len(Jp), 2 * len(seen)))
    row = 0
    for k, (n, v) in enumerate(seen):
        G[row:row + 2 * len(v):2, 2 * k], G[row + 1:row + 2 * len(v):2, 2 * k + 1] = \
            _shared_shift_px(calibration, n, noise[n]) / noise[n]
        row += 2 * len(v)
    shared = inv_info @ Jp.T @ G
    pose_cov = pose_cov + shared @ shared.T
    W0 = world_from_board_pose(T_rig_board, origin_mm)
    Dpsi = np.stack([(psi(world_from_board_pose(to_T((pose0 + h * e)[:3], (pose0 + h * e)[3:]), origin_mm), W0)
                      - psi(world_from_board_pose(to_T((pose0 - h * e)[:3], (pose0 - h * e)[3:]), origin_mm), W0))
                     / (2 * h) for h, e in zip(_POSE_STEP, np.eye(6), strict=True)], axis=1)
    return RigUncertainty(parameters, covariance, Dpsi @ dpose, Dpsi @ pose_cov @ Dpsi.T)


def known_points_reference(calibration: Calibration, pixels: dict[str, np.ndarray], world_points: np.ndarray,
                           parameters: list[str], covariance: np.ndarray) -> RigUncertainty:
    """The world frame of a Kabsch fit to known points (`pixels`: their pixels per camera)."""
    from ..triangulation import triangulate

    world_points = np.asarray(world_points, float).reshape(-1, 3)

    def fitted(cal: Calibration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rig, _ = triangulate(cal, pixels, refine=True, world=False)
        ok = np.isfinite(rig).all(1) & np.isfinite(world_points).all(1)
        return kabsch(rig[ok], world_points[ok]), ok, rig

    W0, ok, rig = fitted(calibration)
    steps = _steps(covariance, 0.1)
    J = np.stack([(psi(fitted(perturbed(calibration, parameters, h * e))[0], W0)
                   - psi(fitted(perturbed(calibration, parameters, -h * e))[0], W0)) / (2 * h)
                  for h, e in zip(steps, np.eye(len(parameters)), strict=True)], axis=1) \
        if parameters else np.zeros((6, 0))
    fit = rig[ok] @ W0[:3, :3].T + W0[:3, 3]
    res = world_points[ok] - fit
    n = len(res)
    sigma2 = float(np.sum(res ** 2)) / max(3 * n - 6, 1)
    c = fit.mean(0)
    x = fit - c
    S_omega = sigma2 * np.linalg.pinv(np.sum(x * x) * np.eye(3) - x.T @ x)
    C = np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])
    # a point's motion ω × X + τ: the centroid moves by δc (σ²/n, independent of ω), so τ = δc + [c]× ω
    cov = np.zeros((6, 6))
    cov[:3, :3] = S_omega
    cov[:3, 3:] = S_omega @ C.T
    cov[3:, :3] = C @ S_omega
    cov[3:, 3:] = sigma2 / n * np.eye(3) + C @ S_omega @ C.T
    return RigUncertainty(parameters, covariance, J, cov)
