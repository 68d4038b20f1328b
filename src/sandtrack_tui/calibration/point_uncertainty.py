"""The covariance of a camera fitted to known 3D points (`from_points`), the pose block carried into the rig
frame (the first camera's) through the fixed world -> rig transform.

Two estimates, and in every direction of parameter space the larger of the two (`larger`):
- (GᵀG)⁻¹ Gᵀ Σ G (GᵀG)⁻¹ at the fit, G = d(pixel) / d(parameters) by central differences, Σ the camera's
  own pixel noise per image axis (`known_point_errors`: the residuals less the known points' error that
  every camera shares, which moves the cameras together rather than one against the other), else σ² I
  with σ² the residuals' sum of squares over the degrees of freedom. It holds when the pixel errors are
  independent from point to point and the lens model fits the whole image.
- a jackknife over units of points (whole planes or frames when there are three or more, 3 x 3 blocks of
  a two-plane target, also where the lens choice left out its dot columns, else a 3 x 3 grid of blocks of
  the image): the camera refitted
  with each unit left out, each refit's change of the pixels of all points mapped back to the parameters
  through G (linearised: a poorly fixed lens term that moves no pixel moves no parameter), covariance
  (g - 1) / g Σ δθ δθᵀ. Errors shared by neighbouring points (a
  dot's detection bias over a region, a lens model that misfits part of the image) move the fit from
  unit to unit although (GᵀG)⁻¹ σ² cannot see them: on a real stepped target fitted on two of its planes
  the held-out plane's X, Y errors were 2x the sd without it."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ..camera import Camera, CameraUncertainty, rotate
from ..errors import SandtrackError
from ..lens import LENSES, project
from .geometry import from_T, to_T

_STEPS = {"r": 1e-6, "t": 1e-4, "f": 1e-3, "c": 1e-3, "d": 1e-6}


def parameter_names(cam: Camera) -> list[str]:
    """The camera's fitted parameters: pose, camera matrix and its lens model's free distortion terms."""
    free = np.nonzero(LENSES[cam.lens].free)[0] if cam.lens in LENSES else np.arange(len(cam.distortion))
    return ["rx", "ry", "rz", "tx", "ty", "tz", "fx", "fy", "cx", "cy",
            *(f"d{k}" for k in free if k < len(cam.distortion))]


def point_fit_uncertainty(cam: Camera, X: np.ndarray, uv: np.ndarray,
                          noise_px: list[float] | None = None) -> CameraUncertainty | None:
    """Covariance of `cam`'s parameters (pose world -> camera) fitted to world points X and pixels uv; None
    when the points cannot fix them (fewer residuals than parameters, a singular G). noise_px: the camera's
    own pixel noise per image axis (x, y) where known, kept in the result."""
    names = parameter_names(cam)
    ok = np.isfinite(X).all(axis=1) & np.isfinite(uv).all(axis=1)
    X, uv = X[ok], uv[ok]
    dof = 2 * len(X) - len(names)
    if dof <= 0:
        return None
    r = (cam.project(X) - uv).ravel()
    G = pixel_jacobian(cam, names, X)
    sigma2 = float(np.sum(r ** 2)) / dof
    try:
        Gi = np.linalg.inv(G.T @ G)
    except np.linalg.LinAlgError:
        return None
    if noise_px is None:
        cov = Gi * sigma2
    else:
        s2 = np.tile(np.asarray(noise_px, float) ** 2, len(X))
        cov = Gi @ (G.T * s2) @ G @ Gi
    return (CameraUncertainty(names, cov, float(np.sqrt(sigma2)), noise_px) if np.isfinite(cov).all()
            else None)


def jackknife_covariance(cam: Camera, X: np.ndarray, uv: np.ndarray, units: np.ndarray,
                         refit) -> CameraUncertainty | None:
    """The jackknife covariance (module docstring) of `cam`'s parameters; `refit(keep)` returns the pixels
    of all X by the camera refitted to the rows `keep` (bool mask). None with fewer than 3 units or when a
    refit fails."""
    ids = np.unique(units)
    if len(ids) < 3:
        return None
    names = parameter_names(cam)
    G = pixel_jacobian(cam, names, X)
    base = cam.project(X)
    deltas = []
    for u in ids:
        try:
            moved = refit(units != u)
        except (SandtrackError, np.linalg.LinAlgError, ValueError):
            return None
        d = (moved - base).ravel()
        if not np.isfinite(d).all():
            return None
        deltas.append(np.linalg.lstsq(G, d, rcond=None)[0])
    dev = np.array(deltas) - np.mean(deltas, axis=0)
    g = len(ids)
    return CameraUncertainty(names, (g - 1) / g * dev.T @ dev, None)



def into_rig(unc: CameraUncertainty, cam_world: Camera, world_from_rig: np.ndarray) -> CameraUncertainty:
    """The same covariance for the camera's rig-frame pose (T_rig = T_world @ world_from_rig, the transform
    held fixed): the pose block through the numerical Jacobian of that map."""
    def rig_pose(v):
        r, t = from_T(to_T(v[:3], v[3:]) @ world_from_rig)
        return np.concatenate([r, t])

    v0 = np.concatenate([cam_world.rvec, cam_world.tvec])
    A = np.eye(len(unc.parameters))
    for k in range(6):
        h = 1e-4 if k < 3 else _STEPS["t"]  # cv2.Rodrigues returns 0 for rotations below ~1e-5 rad
        e = np.zeros(6)
        e[k] = h
        A[:6, k] = (rig_pose(v0 + e) - rig_pose(v0 - e)) / (2 * h)
    return dataclasses.replace(unc, covariance=A @ unc.covariance @ A.T)


def pixel_jacobian(cam: Camera, names: list[str], X: np.ndarray) -> np.ndarray:
    """(2N, P) d(pixel) / d(parameter), central differences."""
    return np.stack([(_moved(cam, p, +1, X) - _moved(cam, p, -1, X)).ravel() / (2 * _step(p)) for p in names],
                    axis=1)


def _step(p: str) -> float:
    return _STEPS[p[0]]


def _moved(cam: Camera, p: str, sign: int, X: np.ndarray) -> np.ndarray:
    """The pixels of X with parameter p moved by sign steps."""
    h = sign * _step(p)
    rvec, tvec, K, d = cam.rvec.copy(), cam.tvec.copy(), cam.matrix.copy(), cam.distortion.copy()
    if p[0] == "r":
        rvec["xyz".index(p[1])] += h
    elif p[0] == "t":
        tvec["xyz".index(p[1])] += h
    elif p in ("fx", "fy", "cx", "cy"):
        K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[p]] += h
    else:
        d[int(p[1:])] += h
    return project(rotate(X, cv2.Rodrigues(rvec)[0]) + tvec, K, d, cam.model)
