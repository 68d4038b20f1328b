"""The standard deviation of a triangulated point: first-order propagation of the pixels' noise and of the
calibration's own uncertainty.

For each point and camera, J = d(distorted pixel) / d(point) at the triangulated point (the camera matrix,
the lens's local Jacobian and the perspective division). The refinement of `triangulation.triangulate` is a
weighted least-squares fit with weights ω = 1 / RMSE² per camera, so a pixel error δp moves the point by
δX = H⁻¹ Σ ω Jᵀ δp with H = Σ ω JᵀJ, and the point's covariance is the sandwich
H⁻¹ (Σ ω² Jᵀ Σp J) H⁻¹, where Σp is each camera's pixel covariance at that point:

- the pixel's own noise, diag(sd_x², sd_y²) (the tracker's estimate or a pixel table's column, the same
  along x and y; else the camera's own pixel noise per image axis from its calibration (`noise_px`, a
  calibration from known points: the residuals less the points' error that every camera shares), else its
  RMSE per axis);
- the calibration's: G Σθ Gᵀ, with Σθ the covariance of the camera's parameters from its bundle
  adjustment (`CameraUncertainty`, kept in calibration.toml; with the lens choice's spread where a
  simpler lens model was kept than the best on left-out data, calibration.model_choice) and
  G = d(pixel) / d(parameters) at the point (analytic for the translation and the camera matrix, finite
  differences for the rotation and the lens).

Where the calibration keeps its parameters' joint covariance with the world frame (`RigUncertainty`: a
calibration from videos), the calibration's part is propagated jointly instead: a parameter change δθ moves
the triangulated point by δX = -H⁻¹ Σ ω Jᵀ G δθ (rig frame) and the world frame by ψ = Ψ δθ (it is refitted
to its reference through the same cameras), so the world point moves by M δθ with M = R_w (-H⁻¹ Σ ω Jᵀ G) +
A(X) Ψ, A(X) ψ = ω × X + τ; its covariance M Σθ Mᵀ (correlations between cameras kept) plus the world
frame's own, A Σψ Aᵀ (the reference's detections). Near the reference most of a camera's error cancels.

Left out: without `RigUncertainty`, correlations between the cameras' calibration errors (each camera's
block is used alone) and the uncertainty of the rig-to-world transform; always, the board's own dimensions
or the known points' survey (a calibration from known points reports the points' own error,
`known_points_sd_mm`, for comparing a triangulated point with such a reference), and anything the
calibration residuals cannot show (a lens model that does not fit the whole image, a rig that moved after
calibrating).
"""

from __future__ import annotations

import numpy as np

from .camera import Calibration, Camera, rotate
from .jit import jit
from .lens import distort_fisheye, distort_normalised

POSE_PARAMETERS = ("rx", "ry", "rz", "tx", "ty", "tz")
MATRIX_PARAMETERS = ("fx", "fy", "cx", "cy")
_ROTATION_STEP = 1e-6
_LENS_STEP = 1e-7
_CHUNK = 65536  # rows per pass of the joint propagation (its (rows, 3, parameters) array)


def triangulation_sd(calibration: Calibration, pixels: dict[str, np.ndarray], points_rig: np.ndarray,
                     pixel_sd: dict[str, np.ndarray] | None = None, with_calibration: bool = True,
                     covariance: bool = False) -> np.ndarray:
    """(N, 3) sd per world axis (mm) of points (rig frame) triangulated from `pixels` ((N, 2) per camera,
    NaN where unseen); with `covariance`, (N, 6): the sd and the covariances XY, XZ, YZ (mm²). pixel_sd: per
    camera, a scalar, (N,) or (N, 2) px (per image axis; default: the camera's `camera_noise_px`, else 1 px).
    NaN where fewer than two cameras saw the point or a needed sd is unknown."""
    joint = calibration.rig_uncertainty if with_calibration else None
    X = np.asarray(points_rig, dtype=np.float64).reshape(-1, 3)
    n = len(X)
    cov = np.full((n, 3), np.nan)
    if joint is None:
        H, M, _, count = _accumulated(calibration, pixels, points_rig, pixel_sd, with_calibration)
        out = _world_sd(H, M, count, calibration.world_from_rig[:3, :3].copy(), cov)
        return np.hstack([out, cov]) if covariance else out
    pixels = {k: np.asarray(v, float).reshape(-1, 2) for k, v in pixels.items()}
    if pixel_sd is not None:
        pixel_sd = {k: _per_axis(v, n) for k, v in pixel_sd.items()}
    out = np.full((n, 3), np.nan)
    W = calibration.world_from_rig
    for s in range(0, n, _CHUNK):
        sl = slice(s, s + _CHUNK)
        H, M, B, count = _accumulated(calibration, {k: v[sl] for k, v in pixels.items()}, X[sl],
                                      None if pixel_sd is None else {k: v[sl] for k, v in pixel_sd.items()}, True,
                                      joint)
        Xw = X[sl] @ W[:3, :3].T + W[:3, 3]
        part = np.full((len(Xw), 3), np.nan)
        out[sl] = _world_sd_joint(H, M, B, count, W[:3, :3].copy(), np.ascontiguousarray(Xw), joint.covariance,
                                  joint.world_jacobian, joint.world_covariance, part)
        cov[sl] = part
    return np.hstack([out, cov]) if covariance else out


def sd_holds(calibration: Calibration, cameras, pixel_sd: str = "each camera's pixel noise (its calibration)") -> str:
    """One line for the user: what the triangulation's sd of these cameras' points holds, and what it leaves
    out that a user could add (pixel_sd: where the pixels' own sd comes from)."""
    cameras = [c for c in cameras if c in calibration.cameras]
    missing = [c for c in cameras if c not in calibration.uncertainty]
    joint = calibration.rig_uncertainty
    if joint is not None:
        world = "with the world frame's" if joint.world_frame_sd() else "(world = first camera)"
        part = f"and the calibration's parameter covariance, cameras together {world}"
    elif len(missing) == len(cameras):
        return (f"triangulation sd: {pixel_sd} only: the calibration file keeps no parameter covariance "
                "(calibrate from videos or points to have it)")
    else:
        part = "and each camera's parameter covariance alone (the world frame taken as exact"
        part += f"; none for {', '.join(missing)})" if missing else ")"
    choice = [f"{c}: {u.better_lens} against the kept {calibration.cameras[c].lens}" for c in cameras
              if (u := calibration.uncertainty.get(c)) is not None and u.better_lens]
    if choice:
        part += f", and the lens choice's spread ({'; '.join(choice)})"
    return f"triangulation sd: {pixel_sd} {part}"


def camera_noise_px(calibration: Calibration, name: str) -> np.ndarray:
    """(2,) a camera's pixel noise per image axis (px): its own noise from the calibration (`noise_px`),
    else its RMSE (a 2-D distance) over √2 on both axes; with the error a view's corners share where the
    calibration allows for it (`view_shared_px`: a pixel without its own sd is taken as one board corner's,
    whose error holds its view's); NaN when neither is known."""
    unc = calibration.uncertainty.get(name)
    own = corner_noise_px(calibration, name)
    if unc is not None and unc.view_shared_px is not None:
        return np.hypot(own, np.asarray(unc.view_shared_px, float))
    return own


def corner_noise_px(calibration: Calibration, name: str) -> np.ndarray:
    """(2,) a camera's corners' own noise per image axis (px), without the error a view's corners share:
    `noise_px`, else the RMSE over √2; NaN when neither is known."""
    unc = calibration.uncertainty.get(name)
    if unc is not None and unc.noise_px is not None:
        return np.asarray(unc.noise_px, float)
    return np.full(2, calibration.cameras[name].rmse_axis_px)


def pixel_sd_axes(sd: np.ndarray, extra: np.ndarray, calibration: Calibration, name: str) -> np.ndarray:
    """(N, 2) each pixel's sd per image axis (px): its own (`sd`, NaN: unknown) on both axes, else the
    camera's (`camera_noise_px`), combined with `extra` (px; NaN: unknown, inf: no sd)."""
    sd = np.asarray(sd, float).reshape(-1, 1)
    base = np.where(np.isnan(sd), camera_noise_px(calibration, name)[None, :], sd)
    extra = np.asarray(extra, float).reshape(-1, 1)
    return np.hypot(base, extra) if extra.any() else base  # a pixels table has no extra: 0.1 s a camera per 1 M


def _camera_sigma(cam: Camera) -> float:
    """The camera's noise level as the refinement weighs it (its RMSE, else 1 px)."""
    r = cam.rmse_px
    return float(r) if r and np.isfinite(r) and r > 0 else 1.0


def _accumulated(calibration, pixels, points_rig, pixel_sd, with_calibration, joint=None):
    """H = Σ ω JᵀJ and M = Σ ω² Jᵀ Σp J per point over the cameras that saw it, and their count. Without
    `joint`, Σp holds each camera's calibration part (its own covariance block; none without
    `with_calibration`) and B is None; with `joint` (a `RigUncertainty`), Σp is the pixels' alone and B =
    Σ ω Jᵀ G (n, 3, P) over the joint parameters."""
    X = np.ascontiguousarray(np.asarray(points_rig, dtype=np.float64).reshape(-1, 3))
    n = len(X)
    H = np.zeros((n, 3, 3))
    M = np.zeros((n, 3, 3))
    B = np.zeros((n, 3, len(joint.parameters))) if joint is not None else np.zeros((0, 3, 0))
    count = np.zeros(n, dtype=np.int64)
    ok_x = np.isfinite(X).all(axis=1)
    for name, px in pixels.items():
        cam = calibration.cameras.get(name)
        if cam is None:
            continue
        seen = np.isfinite(np.asarray(px, float).reshape(-1, 2)).all(axis=1) & ok_x
        if not seen.any():
            continue
        if joint is not None:
            names, cols = joint.camera_parameters(name)
            cov = np.zeros((0, 0))
        else:
            unc = calibration.uncertainty.get(name) if with_calibration else None
            names = list(unc.parameters) if unc is not None else []
            cols = np.zeros(0, dtype=np.int64)
            cov = np.ascontiguousarray(unc.covariance) if unc is not None else np.zeros((0, 0))
        idx = np.nonzero(seen)[0]
        _accumulate(H, M, B, count, idx, _camera_pixel_sd(calibration, name, pixel_sd, n),
                    1.0 / _camera_sigma(cam) ** 2, *_camera_parts(cam, X[idx], names), cov, cols)
    return H, M, (B if joint is not None else None), count


def _camera_pixel_sd(calibration, name, pixel_sd, n) -> np.ndarray:
    given = None if pixel_sd is None else pixel_sd.get(name)
    if given is None:
        own = camera_noise_px(calibration, name)
        return _per_axis(np.where(np.isnan(own), 1.0, own)[None, :], n)
    return _per_axis(given, n)


def _camera_parts(cam: Camera, X: np.ndarray, names: list[str]) -> tuple:
    """What the kernel needs of one camera at points X: normalised point (a, b), depth z, the lens's
    Jacobian, the distorted normalised point, K's 2 x 2 part, R, and for the calibration part the kinds
    of the parameters `names`, the rotation's and the lens terms' finite differences."""
    R = cam.R
    xc = rotate(X, R) + cam.tvec
    z = xc[:, 2].copy()  # contiguous and writable, as every array the kernels take: one compiled version
    a, b = xc[:, 0] / z, xc[:, 1] / z
    distort = distort_fisheye if cam.model == "fisheye" else distort_normalised
    xd, yd = distort(a, b, cam.distortion)
    eps = 1e-6
    xa, ya = distort(a + eps, b, cam.distortion)
    xb, yb = distort(a, b + eps, cam.distortion)
    Jd = np.stack([(xa - xd) / eps, (xb - xd) / eps, (ya - yd) / eps, (yb - yd) / eps], axis=1)
    K = cam.matrix
    K2 = np.array([[K[0, 0], K[0, 1]], [0.0, K[1, 1]]])
    n = len(X)
    kinds = np.array([_KINDS.get(p, -1) if not p.startswith("d") else 100 + int(p[1:]) for p in names],
                     dtype=np.int64)
    drot = np.zeros((n, 3, 3))
    if np.any((kinds >= 0) & (kinds < 3)):
        import cv2

        for k in range(3):
            rv = cam.rvec.copy()
            rv[k] += _ROTATION_STEP
            drot[:, k] = (rotate(X, cv2.Rodrigues(rv)[0]) + cam.tvec - xc) / _ROTATION_STEP
    lens_terms = [int(k) - 100 for k in kinds if k >= 100]
    dlens = np.zeros((n, len(lens_terms), 2))
    for j, k in enumerate(lens_terms):
        if k < len(cam.distortion):
            d = cam.distortion.copy()
            d[k] += _LENS_STEP
            x2, y2 = distort(a, b, d)
            dlens[:, j, 0], dlens[:, j, 1] = (x2 - xd) / _LENS_STEP, (y2 - yd) / _LENS_STEP
    return (a, b, z, Jd, xd, yd, K2, R, kinds, drot, dlens)


def _per_axis(sd, n: int) -> np.ndarray:
    """(n, 2) from a scalar, (n,) (the same on both axes), (1, 2) or (n, 2) sd."""
    a = np.asarray(sd, float)
    if a.ndim == 1:
        a = a[:, None]
    return np.array(np.broadcast_to(a, (n, 2)), dtype=np.float64, order="C")


_KINDS = {"rx": 0, "ry": 1, "rz": 2, "tx": 3, "ty": 4, "tz": 5, "fx": 6, "fy": 7, "cx": 8, "cy": 9}


@jit
def _jacobians(q, a, b, z, Jd, K2, R, P, J):
    """P = d pixel / d camera-frame point and J = d pixel / d rig point of point q."""
    iz = 1.0 / z[q]
    a00 = K2[0, 0] * Jd[q, 0] + K2[0, 1] * Jd[q, 2]
    a01 = K2[0, 0] * Jd[q, 1] + K2[0, 1] * Jd[q, 3]
    a10 = K2[1, 1] * Jd[q, 2]
    a11 = K2[1, 1] * Jd[q, 3]
    # d pixel / d camera-frame point: A @ [[1/z, 0, -a/z], [0, 1/z, -b/z]]
    P[0, 0], P[0, 1], P[0, 2] = a00 * iz, a01 * iz, -(a00 * a[q] + a01 * b[q]) * iz
    P[1, 0], P[1, 1], P[1, 2] = a10 * iz, a11 * iz, -(a10 * a[q] + a11 * b[q]) * iz
    for r in range(2):
        for c in range(3):
            J[r, c] = P[r, 0] * R[0, c] + P[r, 1] * R[1, c] + P[r, 2] * R[2, c]


@jit
def _gradient(q, P, xd, yd, K2, kinds, drot, dlens, G):
    """G = d pixel / d parameters of point q."""
    lens = 0
    for p in range(len(kinds)):
        k = kinds[p]
        g0, g1 = 0.0, 0.0
        if k < 3 and k >= 0:
            for c in range(3):
                g0 += P[0, c] * drot[q, k, c]
                g1 += P[1, c] * drot[q, k, c]
        elif k < 6 and k >= 3:
            g0, g1 = P[0, k - 3], P[1, k - 3]
        elif k == 6:
            g0 = xd[q]
        elif k == 7:
            g1 = yd[q]
        elif k == 8:
            g0 = 1.0
        elif k == 9:
            g1 = 1.0
        elif k >= 100:
            dx, dy = dlens[q, lens, 0], dlens[q, lens, 1]
            g0, g1 = K2[0, 0] * dx + K2[0, 1] * dy, K2[1, 1] * dy
            lens += 1
        G[0, p], G[1, p] = g0, g1


@jit
def _add_point(H, M, i, w, J, S):
    for u in range(3):
        for v in range(3):
            H[i, u, v] += w * (J[0, u] * J[0, v] + J[1, u] * J[1, v])
            M[i, u, v] += w * w * (J[0, u] * (S[0, 0] * J[0, v] + S[0, 1] * J[1, v])
                                   + J[1, u] * (S[1, 0] * J[0, v] + S[1, 1] * J[1, v]))


@jit(nogil=True)
def _accumulate(H, M, B, count, idx, sd, w, a, b, z, Jd, xd, yd, K2, R, kinds, drot, dlens, cov, cols):
    """Add one camera's terms at the points idx to H = Σ ω JᵀJ and M = Σ ω² Jᵀ Σp J, Σp the pixel's
    covariance plus, with `cov` (this camera's parameters), G cov Gᵀ; with a non-empty B instead, add
    ω Jᵀ G to B's columns `cols` (the joint parameters)."""
    n_par = len(kinds)
    joint = B.shape[0] > 0
    P = np.empty((2, 3))
    J = np.empty((2, 3))
    G = np.empty((2, n_par))
    S = np.empty((2, 2))
    for q in range(len(idx)):
        i = idx[q]
        _jacobians(q, a, b, z, Jd, K2, R, P, J)
        S[0, 0], S[0, 1], S[1, 0], S[1, 1] = sd[i, 0] * sd[i, 0], 0.0, 0.0, sd[i, 1] * sd[i, 1]
        if n_par:
            _gradient(q, P, xd, yd, K2, kinds, drot, dlens, G)
            if joint:
                for u in range(3):
                    for p in range(n_par):
                        B[i, u, cols[p]] += w * (J[0, u] * G[0, p] + J[1, u] * G[1, p])
            else:
                for r in range(2):
                    for c in range(2):
                        acc = 0.0
                        for p in range(n_par):
                            gp = G[r, p]
                            if gp != 0.0:
                                for m in range(n_par):
                                    acc += gp * cov[p, m] * G[c, m]
                        S[r, c] += acc
        _add_point(H, M, i, w, J, S)
        count[i] += 1


@jit
def _inv3(h, Hi) -> bool:
    c00 = h[1, 1] * h[2, 2] - h[1, 2] * h[2, 1]
    c01 = h[1, 2] * h[2, 0] - h[1, 0] * h[2, 2]
    c02 = h[1, 0] * h[2, 1] - h[1, 1] * h[2, 0]
    det = h[0, 0] * c00 + h[0, 1] * c01 + h[0, 2] * c02
    if not abs(det) > 1e-300:
        return False
    Hi[0, 0], Hi[1, 0], Hi[2, 0] = c00 / det, c01 / det, c02 / det
    Hi[0, 1] = (h[0, 2] * h[2, 1] - h[0, 1] * h[2, 2]) / det
    Hi[1, 1] = (h[0, 0] * h[2, 2] - h[0, 2] * h[2, 0]) / det
    Hi[2, 1] = (h[0, 1] * h[2, 0] - h[0, 0] * h[2, 1]) / det
    Hi[0, 2] = (h[0, 1] * h[1, 2] - h[0, 2] * h[1, 1]) / det
    Hi[1, 2] = (h[0, 2] * h[1, 0] - h[0, 0] * h[1, 2]) / det
    Hi[2, 2] = (h[0, 0] * h[1, 1] - h[0, 1] * h[1, 0]) / det
    return True


@jit
def _mul3(A, B, out, b_transposed):
    """out = A @ B (or A @ Bᵀ), 3 x 3."""
    for u in range(3):
        for v in range(3):
            acc = 0.0
            for k in range(3):
                acc += A[u, k] * (B[v, k] if b_transposed else B[k, v])
            out[u, v] = acc


@jit
def _sandwich_world(Hi, Mi, Rw, C):
    """C = Rw Hi Mi Hi Rwᵀ."""
    T = np.empty((3, 3))
    U = np.empty((3, 3))
    _mul3(Hi, Mi, T, False)
    _mul3(T, Hi, U, False)
    _mul3(Rw, U, T, False)
    _mul3(T, Rw, C, True)


@jit(nogil=True)
def _world_sd(H, M, count, Rw, cov_out):
    """sd per world axis of the sandwich H⁻¹ M H⁻¹ rotated into the world frame, and (into `cov_out`, (n, 3))
    its covariances XY, XZ, YZ; NaN below two cameras."""
    n = len(H)
    out = np.full((n, 3), np.nan)
    Hi = np.empty((3, 3))
    C = np.empty((3, 3))
    for i in range(n):
        if count[i] < 2 or not _inv3(H[i], Hi):
            continue
        _sandwich_world(Hi, M[i], Rw, C)
        _store(C, out, cov_out, i)
    return out


@jit
def _store(C, out, cov_out, i):
    """sd (√ of the diagonal, NaN if not finite) and the off-diagonal XY, XZ, YZ of C into row i."""
    for ax in range(3):
        var = C[ax, ax]
        out[i, ax] = np.sqrt(max(var, 0.0)) if np.isfinite(var) else np.nan
    cov_out[i, 0], cov_out[i, 1], cov_out[i, 2] = C[0, 1], C[0, 2], C[1, 2]


@jit(nogil=True)
def _world_sd_joint(H, M, B, count, Rw, Xw, cov, Psi, Spsi, cov_out):
    """sd per world axis of the pixels' sandwich plus the joint calibration part M Σθ Mᵀ, M = Rw (-H⁻¹ B) +
    A(X) Ψ, plus the world frame's own A Σψ Aᵀ (A(X) ψ = ω × X + τ), and (into `cov_out`) the covariances
    XY, XZ, YZ of that sum; NaN below two cameras."""
    n = len(H)
    n_par = cov.shape[0]
    out = np.full((n, 3), np.nan)
    Hi = np.empty((3, 3))
    C = np.empty((3, 3))
    A = np.zeros((3, 6))
    L = np.empty((3, n_par))
    Mw = np.empty((3, n_par))
    T = np.empty((n_par, 3))
    for i in range(n):
        if count[i] < 2 or not _inv3(H[i], Hi):
            continue
        _sandwich_world(Hi, M[i], Rw, C)
        x, y, z = Xw[i, 0], Xw[i, 1], Xw[i, 2]
        # ω × X = -[X]× ω
        A[0, 0], A[0, 1], A[0, 2] = 0.0, z, -y
        A[1, 0], A[1, 1], A[1, 2] = -z, 0.0, x
        A[2, 0], A[2, 1], A[2, 2] = y, -x, 0.0
        A[0, 3], A[1, 4], A[2, 5] = 1.0, 1.0, 1.0
        for u in range(3):
            for p in range(n_par):
                L[u, p] = -(Hi[u, 0] * B[i, 0, p] + Hi[u, 1] * B[i, 1, p] + Hi[u, 2] * B[i, 2, p])
        for u in range(3):
            for p in range(n_par):
                acc = Rw[u, 0] * L[0, p] + Rw[u, 1] * L[1, p] + Rw[u, 2] * L[2, p]
                for k in range(6):
                    acc += A[u, k] * Psi[k, p]
                Mw[u, p] = acc
        # T = Σθ Mwᵀ once, then every entry of Mw Σθ Mwᵀ is a dot product (the covariances cost no more)
        for p in range(n_par):
            t0 = t1 = t2 = 0.0
            for m in range(n_par):
                c = cov[p, m]
                t0 += c * Mw[0, m]
                t1 += c * Mw[1, m]
                t2 += c * Mw[2, m]
            T[p, 0], T[p, 1], T[p, 2] = t0, t1, t2
        for a in range(3):
            for b in range(a, 3):
                acc = 0.0
                for p in range(n_par):
                    acc += Mw[a, p] * T[p, b]
                for k in range(6):
                    inner = 0.0
                    for m in range(6):
                        inner += Spsi[k, m] * A[b, m]
                    acc += A[a, k] * inner
                C[a, b] += acc
                if b != a:
                    C[b, a] = C[a, b]
        _store(C, out, cov_out, i)
    return out


def warm_up() -> None:
    """Compile (or load) the kernels once, for each camera's own covariance and for the joint one, with
    the pixels' sd given and not: run after installing, so the first `sandtrack xyz` with sd does not pay
    the compilation (several seconds)."""
    from .camera import CameraUncertainty, RigUncertainty
    from .triangulation import triangulate, warm_up_rig

    cal, X = warm_up_rig()
    cams = cal.cameras
    names = [*POSE_PARAMETERS, *MATRIX_PARAMETERS, "d0", "d1"]
    cal.uncertainty = {n: CameraUncertainty(names, np.eye(len(names)) * 1e-8) for n in cams}
    pixels = {n: c.project(X) for n, c in cams.items()}
    rig, _ = triangulate(cal, pixels, world=False)
    joint = RigUncertainty([f"{c}/{p}" for c in cams for p in names], np.eye(2 * len(names)) * 1e-8,
                           np.zeros((6, 2 * len(names))), np.eye(6) * 1e-8)
    for rig_uncertainty in (None, joint):
        cal.rig_uncertainty = rig_uncertainty
        for sd in (None, {n: np.full(len(X), 0.2) for n in cams}):
            triangulation_sd(cal, pixels, rig, pixel_sd=sd)
    triangulation_sd(cal, pixels, rig, with_calibration=False)


if __name__ == "__main__":
    warm_up()
