"""The residuals of cameras fitted to known 3D points, split into the points' own error and each camera's
pixel noise.

A known point (a surveyed or printed dot) that lies δ off its stated place is seen there by every camera: in
camera j its residual is J_j δ + ε_j, J_j = d(pixel) / d(point) and ε_j the camera's own pixel noise,
independent from camera to camera. A camera's RMSE counts both as pixel noise; triangulated, independent
pixel noise lands mostly in depth while δ is a displacement in 3D, so the two must be told apart.

For every point seen by two cameras or more: δ by least squares through the cameras' Jacobians (weights:
1 / the residuals' variance, per camera and image axis), then
- each camera's σ_px per image axis from what δ leaves, Σe² over Σ(1 − leverage), the leverage being the
  point's share of δ's fit in that camera and axis (kept per axis: on a real stepped target a camera that
  looks across the steps had 0.15 px of noise along x and 0.32 px along y, which one RMSE spreads over
  both axes and so into depth);
- σ_point per world axis from the spread of the δ less the part the pixel noise puts into them.
Both are divided by 1 − P / (2 N), the share of the residuals a camera's P parameters leave over its N
points (the fit absorbs part of every pattern in its residuals).

Left out: an error of the points common to all of them (a rigid shift or turn of the whole target: every
camera's pose takes it), and anything one camera alone sees at a point (a detection bias in that image)
counts as that camera's pixel noise.
"""

from __future__ import annotations

import numpy as np

from ..camera import Camera

_STEP_MM = 1e-3


def known_point_errors(cameras: dict[str, Camera], X: np.ndarray, pixels: dict[str, np.ndarray],
                       n_parameters: dict[str, int]) -> dict | None:
    """{"sd_mm": σ_point per axis of X's frame, "noise_px": {camera: [σ_px along x, along y]}, "points":
    points seen by two cameras or more} for cameras (pose: X's frame -> camera) fitted to the points X
    (N, 3) and pixels (N, 2) per camera (NaN: unseen). None with fewer than 2 cameras or 10 such points."""
    X = np.asarray(X, float)
    names = [n for n in pixels if n in cameras]
    r, J, seen, keep = {}, {}, {}, {}
    for n in names:
        cam, uv = cameras[n], np.asarray(pixels[n], float)
        seen[n] = np.isfinite(uv).all(axis=1) & np.isfinite(X).all(axis=1)
        Xs = np.where(seen[n][:, None], X, 0.0)
        r[n] = np.where(seen[n][:, None], uv - cam.project(Xs), 0.0)
        Jn = np.stack([(cam.project(Xs + _STEP_MM * e) - cam.project(Xs - _STEP_MM * e)) / (2 * _STEP_MM)
                       for e in np.eye(3)], axis=2)
        J[n] = np.where(seen[n][:, None, None] & np.isfinite(Jn), Jn, 0.0)
        keep[n] = max(1.0 - n_parameters.get(n, 0) / max(2 * int(seen[n].sum()), 1), 0.5)
    multi = np.sum([seen[n] for n in names], axis=0) >= 2 if names else np.zeros(len(X), bool)
    if len(names) < 2 or multi.sum() < 10:
        return None
    weights = {n: np.maximum(np.sum(r[n][seen[n]] ** 2, axis=0) / max(seen[n].sum() * keep[n], 1.0), 1e-12)
               for n in names}  # each camera's residual variance per image axis
    delta, Ai = _displacements(names, r, J, weights, multi)
    var = {}
    for n in names:
        m = seen[n][multi]
        Jn = J[n][multi][m]
        e = r[n][multi][m] - np.einsum("nki,ni->nk", Jn, delta[m])
        leverage = np.einsum("nki,nij,nkj->nk", Jn, Ai[m], Jn) / weights[n]
        dof = np.sum(1.0 - leverage, axis=0) * keep[n]
        if not (dof > 0).all():
            return None
        var[n] = np.sum(e ** 2, axis=0) / dof
    # the part of each δ the pixel noise makes: Ai (Σ Jᵀ W Σ W J) Ai, W the weights δ was fitted with
    M = np.zeros_like(Ai)
    for n in names:
        Jn = J[n][multi]
        M += np.einsum("nki,k,nkj->nij", Jn, var[n] / weights[n] ** 2, Jn)
    from_noise = np.mean(np.diagonal(np.einsum("nij,njk,nkl->nil", Ai, M, Ai), axis1=1, axis2=2), axis=0)
    shrink = float(np.mean([keep[n] for n in names]))
    point_var = (np.mean(delta ** 2, axis=0) - from_noise) / shrink
    return {"sd_mm": [float(v) for v in np.sqrt(np.clip(point_var, 0.0, None))],
            "noise_px": {n: [float(v) for v in np.sqrt(var[n])] for n in names}, "points": int(multi.sum())}


def _displacements(names, r, J, var, multi):
    """δ of every point seen twice or more (weighted least squares through the cameras' Jacobians) and the
    inverse of its normal matrix."""
    A = np.zeros((int(multi.sum()), 3, 3))
    b = np.zeros((int(multi.sum()), 3))
    for n in names:
        Jn, rn = J[n][multi], r[n][multi]
        A += np.einsum("nki,k,nkj->nij", Jn, 1.0 / var[n], Jn)
        b += np.einsum("nki,k,nk->ni", Jn, 1.0 / var[n], rn)
    Ai = np.linalg.inv(A)
    return np.einsum("nij,nj->ni", Ai, b), Ai
