"""Bundle adjustment over all cameras and board poses (scipy least_squares, robust loss, sparse
Jacobian).

Unknowns: each camera's pose in the rig frame (the first camera defines the rig frame and stays
fixed), optionally each camera's intrinsics (fx, fy, cx, cy and distortion), and one rigid board
pose per frame. Residuals: distorted reprojection error of every observed corner, in pixels.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csc_matrix, csr_matrix, lil_matrix

from .geometry import distort_project, larger, rodrigues
from .view_pose_error import view_groups, view_motion_summary, view_pose_error

# frames (views) needed to estimate the per-view sandwich covariance (and at least two per parameter: with
# fewer clusters than parameters it is singular)
MIN_CLUSTERS = 20


@dataclass
class Observations:
    """Flat corner observations: camera index, frame index (0..F-1), board point (mm), pixel."""

    cam: np.ndarray  # (M,) int
    frame: np.ndarray  # (M,) int
    corner: np.ndarray  # (M,) int corner id
    board_xyz: np.ndarray  # (M, 3)
    uv: np.ndarray  # (M, 2)

    def __len__(self) -> int:
        return len(self.cam)


@dataclass
class BundleState:
    cam_rvec: np.ndarray  # (C, 3) rig -> camera
    cam_tvec: np.ndarray  # (C, 3)
    K: np.ndarray  # (C, 3, 3)
    dist: list[np.ndarray]  # per camera (5,) pinhole or (4,) fisheye
    models: list[str]
    frame_rvec: np.ndarray  # (F, 3) board -> rig
    frame_tvec: np.ndarray  # (F, 3)
    fixed_k3: list[bool] = field(default_factory=list)
    dist_free: list[np.ndarray] | None = None  # per camera, which distortion terms are fitted

    def copy(self) -> BundleState:
        return BundleState(self.cam_rvec.copy(), self.cam_tvec.copy(), self.K.copy(), [d.copy() for d in self.dist],
                           list(self.models), self.frame_rvec.copy(), self.frame_tvec.copy(), list(self.fixed_k3),
                           None if self.dist_free is None else [m.copy() for m in self.dist_free])

    def free_mask(self, c: int) -> np.ndarray:
        if self.dist_free is not None:
            return np.asarray(self.dist_free[c], dtype=bool)
        n = len(self.dist[c])
        m = np.ones(n, dtype=bool)
        if self.models[c] != "fisheye" and n > 4 and self.fixed_k3 and self.fixed_k3[c]:
            m[4:] = False
        return m


class _Layout:
    def __init__(self, state: BundleState, free_intrinsics: bool, free_cameras: bool, free_frames: bool):
        C = len(state.models)
        F = len(state.frame_rvec)
        self.C, self.F = C, F
        self.free_intr = free_intrinsics
        off = 0
        self.cam_pose = {}
        if free_cameras:
            for c in range(1, C):
                self.cam_pose[c] = off
                off += 6
        self.intr = {}
        if free_intrinsics:
            for c in range(C):
                mask = state.free_mask(c)
                self.intr[c] = (off, 4 + int(mask.sum()), mask)
                off += self.intr[c][1]
        self.frame0 = off if free_frames else None
        if free_frames:
            off += 6 * F
        self.n = off

    def pack(self, s: BundleState) -> np.ndarray:
        x = np.zeros(self.n)
        for c, o in self.cam_pose.items():
            x[o:o + 3], x[o + 3:o + 6] = s.cam_rvec[c], s.cam_tvec[c]
        for c, (o, n, mask) in self.intr.items():
            K = s.K[c]
            x[o:o + 4] = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
            x[o + 4:o + n] = s.dist[c][mask]
        if self.frame0 is not None:
            f = self.frame0
            x[f:f + 6 * self.F] = np.hstack([s.frame_rvec, s.frame_tvec]).ravel()
        return x

    def unpack(self, x: np.ndarray, base: BundleState) -> BundleState:
        s = base.copy()
        for c, o in self.cam_pose.items():
            s.cam_rvec[c], s.cam_tvec[c] = x[o:o + 3], x[o + 3:o + 6]
        for c, (o, n, mask) in self.intr.items():
            s.K[c] = np.array([[x[o], 0, x[o + 2]], [0, x[o + 1], x[o + 3]], [0, 0, 1]])
            d = s.dist[c].copy()
            d[mask] = x[o + 4:o + n]
            s.dist[c] = d
        if self.frame0 is not None:
            p = x[self.frame0:self.frame0 + 6 * self.F].reshape(self.F, 6)
            s.frame_rvec, s.frame_tvec = p[:, :3].copy(), p[:, 3:].copy()
        return s

    def sparsity(self, obs: Observations):
        M = len(obs)
        S = lil_matrix((2 * M, self.n), dtype=np.int8)
        rows = np.arange(M)
        for c in range(self.C):
            sel = rows[obs.cam == c]
            cols = []
            if c in self.cam_pose:
                cols += list(range(self.cam_pose[c], self.cam_pose[c] + 6))
            if c in self.intr:
                o, n, _ = self.intr[c]
                cols += list(range(o, o + n))
            for col in cols:
                S[2 * sel, col] = 1
                S[2 * sel + 1, col] = 1
        if self.frame0 is not None:
            for k in range(6):
                cols = self.frame0 + 6 * obs.frame + k
                S[2 * rows, cols] = 1
                S[2 * rows + 1, cols] = 1
        return S.tocsr()


def project_all(s: BundleState, obs: Observations) -> np.ndarray:
    """(M, 2) predicted pixels of every observation."""
    Rf = rodrigues(s.frame_rvec)
    Rc = rodrigues(s.cam_rvec)
    Xr = np.einsum("mij,mj->mi", Rf[obs.frame], obs.board_xyz) + s.frame_tvec[obs.frame]
    Xc = np.einsum("mij,mj->mi", Rc[obs.cam], Xr) + s.cam_tvec[obs.cam]
    out = np.empty((len(obs), 2))
    for c in range(len(s.models)):
        m = obs.cam == c
        if m.any():
            out[m] = distort_project(Xc[m], s.K[c], s.dist[c], s.models[c])
    return out


def residuals(s: BundleState, obs: Observations) -> np.ndarray:
    """(M, 2) reprojection residuals (px)."""
    return project_all(s, obs) - obs.uv


def view_weights(res: np.ndarray, obs: Observations, clip_sigmas: float = 3.0) -> np.ndarray:
    """(M,) weight of each observation: the inverse of its view's noise variance (one view = one
    camera in one frame), relative to the median view.

    Corners of one view share their noise level (motion blur, focus, distance, light), so each view's
    variance is estimated from its own residuals: sum of squares over the residual degrees of freedom
    (2 per corner, less the 6 pose parameters shared by the cameras that see the frame). A view's
    estimate is itself noisy (a chi-square with those degrees of freedom), so it is shrunk towards the
    median in proportion: log-variances are modelled as the median plus a spread between views, whose
    size is estimated from the data (variance of the log-variances less their sampling variance
    2/dof). When the views differ no more than their sampling noise explains, every weight is 1.
    A corner beyond `clip_sigmas` times its view's typical error (from the view's median) counts only
    up to that: outliers are the robust loss's business."""
    e2 = np.sum(np.asarray(res, dtype=float) ** 2, axis=1)
    if len(e2) == 0:
        return np.ones(0)
    views = view_groups(obs.cam, obs.frame)
    inv = views.index
    median_e2 = np.array([np.median(part) for part in np.split(e2[views.order], views.bounds[1:-1])])
    # |r|^2 ~ 2 sigma^2 chi2(2)/2: its median is 2 ln2 sigma^2
    e2 = np.minimum(e2, (clip_sigmas ** 2) * 2 * median_e2[inv] / (2 * np.log(2)))
    ss = np.bincount(inv, weights=e2)
    n = np.bincount(inv).astype(float)
    dof = np.maximum(2 * n - 6.0 / views.cameras_in_frame[views.frame], 1.0)
    log_var = np.log(np.maximum(ss / dof, 1e-300))
    sampling = 2.0 / dof
    centre = float(np.median(log_var))
    between = max(float(np.var(log_var)) - float(np.mean(sampling)), 0.0)
    shrunk = centre + between / (between + sampling) * (log_var - centre)
    return np.exp(centre - shrunk)[inv]


def _weighted_residuals(layout: _Layout, state: BundleState, obs: Observations, weights: np.ndarray | None):
    """The packed parameters -> the residuals (px), each scaled by the square root of its weight; and that
    scale per residual (None without weights)."""
    scale = None if weights is None else np.repeat(np.sqrt(np.asarray(weights, dtype=float)), 2)

    def fun(xv):
        r = residuals(layout.unpack(xv, state), obs).ravel()
        return r if scale is None else r * scale

    return fun, scale


def _jacobian(fun, x: np.ndarray, r0: np.ndarray, S: csc_matrix, groups: list[np.ndarray]) -> csc_matrix:
    """Forward-difference Jacobian with the known sparsity: columns that share no residual row are
    perturbed together, so the cost is one evaluation per group, not per parameter."""
    data = np.empty(S.nnz)
    h_all = 1e-7 * np.maximum(np.abs(x), 1.0)
    for cols in groups:
        xp = x.copy()
        xp[cols] += h_all[cols]
        dr = fun(xp) - r0
        for j in cols:
            a, b = S.indptr[j], S.indptr[j + 1]
            data[a:b] = dr[S.indices[a:b]] / h_all[j]
    return csc_matrix((data, S.indices, S.indptr), shape=S.shape)


def _groups(layout: _Layout, obs: Observations) -> list[np.ndarray]:
    groups: list[list[int]] = []
    per_cam: dict[int, list[int]] = {}
    for c, o in layout.cam_pose.items():
        per_cam.setdefault(c, []).extend(range(o, o + 6))
    for c, (o, n, _) in layout.intr.items():
        per_cam.setdefault(c, []).extend(range(o, o + n))
    width = max((len(v) for v in per_cam.values()), default=0)
    for k in range(width):
        groups.append([v[k] for v in per_cam.values() if k < len(v)])
    if layout.frame0 is not None:
        for k in range(6):
            groups.append(list(layout.frame0 + 6 * np.arange(layout.F) + k))
    return [np.asarray(g, dtype=int) for g in groups if len(g)]


def _robust(e: np.ndarray, loss: str, f: float) -> tuple[np.ndarray, np.ndarray]:
    """Per observation (pixel error norm e): cost rho(e^2) and IRLS weight rho'(e^2)."""
    z = (e / f) ** 2
    if loss == "soft_l1":
        return f * f * 2 * (np.sqrt(1 + z) - 1), 1 / np.sqrt(1 + z)
    if loss == "huber":
        w = np.where(z <= 1, 1.0, 1 / np.sqrt(np.maximum(z, 1)))
        return np.where(z <= 1, e * e, f * f * (2 * np.sqrt(z) - 1)), w
    return e * e, np.ones_like(e)


def _solve_damped(A, g, lam: float, n_head: int, F: int | None) -> np.ndarray:
    """Solve (A + lam diag(A)) dx = -g. The trailing 6F frame-pose block is block-diagonal, so it is
    eliminated with a Schur complement (cost linear in the number of frames)."""
    d = A.diagonal()
    damp = lam * np.maximum(d, 1e-12)
    if F is None:
        return _spd_solve(A.toarray() + np.diag(damp), -g)
    A = A.tocsr()
    V = A[n_head:, n_head:].toarray() if F * 6 <= 600 else None
    if V is not None:
        Vb = V.reshape(F, 6, F, 6)[np.arange(F), :, np.arange(F), :]
    else:
        Vsub = A[n_head:, n_head:].tocoo()
        Vb = np.zeros((F, 6, 6))
        fr, fc = Vsub.row // 6, Vsub.col // 6
        same = fr == fc
        Vb[fr[same], Vsub.row[same] % 6, Vsub.col[same] % 6] = Vsub.data[same]
    Vb = Vb + np.einsum("fi,ij->fij", damp[n_head:].reshape(F, 6), np.eye(6))
    Vinv = np.linalg.inv(Vb)
    gf = g[n_head:].reshape(F, 6)
    if n_head == 0:
        return -np.einsum("fij,fj->fi", Vinv, gf).ravel()
    U = A[:n_head, :n_head].toarray() + np.diag(damp[:n_head])
    W = A[:n_head, n_head:].toarray().reshape(n_head, F, 6)
    WV = np.einsum("afi,fij->afj", W, Vinv)
    Sm = U - np.einsum("afj,bfj->ab", WV, W)
    rhs = -g[:n_head] + np.einsum("afj,fj->a", WV, gf)
    dc = _spd_solve(Sm, rhs)
    df = np.einsum("fij,fj->fi", Vinv, -gf - np.einsum("afi,a->fi", W, dc))
    return np.concatenate([dc, df.ravel()])


def _spd_solve(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.solve(M, b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(M, b, rcond=None)[0]


def bundle_adjust(state: BundleState, obs: Observations, free_intrinsics: bool = True, free_cameras: bool = True,
                  free_frames: bool = True, loss: str = "soft_l1", f_scale: float = 2.0,
                  max_iter: int = 60, tol: float = 1e-6,
                  weights: np.ndarray | None = None) -> tuple[BundleState, dict]:
    """Levenberg-Marquardt with iteratively reweighted robust loss on the sparse problem.

    weights: optional (M,) inverse noise variance of each observation relative to a typical one
    (see `view_weights`); each residual is scaled by its square root, so the robust loss still
    speaks pixels of a typical view.

    Uses the Jacobian sparsity (the same pattern `scipy.optimize.least_squares(jac_sparsity=...)`
    takes) for grouped finite differences, and a Schur complement on the board poses, so a step
    costs about 20 residual evaluations plus a small dense solve whatever the number of frames."""
    layout = _Layout(state, free_intrinsics, free_cameras, free_frames)
    x = layout.pack(state)
    fun, scale = _weighted_residuals(layout, state, obs, weights)
    S = layout.sparsity(obs).tocsc()
    S.sort_indices()
    groups = _groups(layout, obs)
    n_head = layout.frame0 if layout.frame0 is not None else layout.n
    F = layout.F if layout.frame0 is not None else None
    r = fun(x)
    r0 = r.copy()

    def cost_of(rv):
        e = np.linalg.norm(rv.reshape(-1, 2), axis=1)
        c, w = _robust(np.nan_to_num(e, nan=1e6), loss, f_scale)
        return float(np.sum(c)), w

    cost, w = cost_of(r)
    lam = 1e-3
    it = 0
    evals = 1
    for it in range(1, max_iter + 1):  # noqa: B007
        J = _jacobian(fun, x, r, S, groups)
        evals += len(groups)
        wr = np.repeat(w, 2)
        JW = J.T.multiply(wr[None, :]).tocsr()
        A = (JW @ J).tocsc()
        g = JW @ r
        improved = False
        for _ in range(12):
            dx = _solve_damped(A, g, lam, n_head, F)
            xn = x + dx
            rn = fun(xn)
            evals += 1
            cn, wn = cost_of(rn)
            if np.isfinite(cn) and cn < cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        rel = (cost - cn) / max(cost, 1e-300)
        x, r, cost, w = xn, rn, cn, wn
        lam = max(lam / 10, 1e-9)
        if rel < tol or np.max(np.abs(dx) / np.maximum(np.abs(x), 1.0)) < 1e-12:
            break
    out = layout.unpack(x, state)
    if scale is not None:  # report plain pixels
        r0, r = r0 / scale, r / scale
    info = {
        "initial_rmse_px": float(np.sqrt(np.mean(r0.reshape(-1, 2) ** 2) * 2)),
        "rmse_px": float(np.sqrt(np.mean(r.reshape(-1, 2) ** 2) * 2)),
        "iterations": it,
        "evaluations": evals,
        "parameters": int(layout.n),
        "observations": len(obs),
    }
    return out, info


def parameter_covariance(state: BundleState, obs: Observations, free_intrinsics: bool = True, loss: str = "soft_l1",
                         f_scale: float = 2.0, weights: np.ndarray | None = None,
                         details: dict | None = None) -> tuple[list[tuple[int, str]], np.ndarray]:
    """Joint covariance of every camera's parameters at a bundle adjustment's solution: (JᵀWJ)⁻¹ σ², the
    board poses marginalised (Schur complement), W the robust loss's weights, σ² the weighted residuals' sum
    of squares over the degrees of freedom once each view has its own board pose, plus the error of each
    view's own pose (the board moved between the cameras' exposures, a view's detections shifted together:
    view_pose_error, measured from the views of one frame); raised, direction by direction, to the sandwich
    that takes each frame as one cluster of errors (A⁻¹ Σ_f s_f s_fᵀ A⁻¹, s_f the frame's score JᵀWr), where
    there are MIN_CLUSTERS frames or more and two per parameter. Returns ([(camera index, name)], (P, P)); the
    first camera's pose defines the rig frame and has none. Names: rx ry rz tx ty tz (pose, rig -> camera), fx
    fy cx cy, dK (the K-th distortion coefficient). details, when given, gets "view_motion": the measured
    motion of a view's board pose (`view_motion_summary`)."""
    layout = _Layout(state, free_intrinsics, True, True)
    x = layout.pack(state)
    fun, _ = _weighted_residuals(layout, state, obs, weights)
    S = layout.sparsity(obs).tocsc()
    S.sort_indices()
    r = fun(x)
    J = _jacobian(fun, x, r, S, _groups(layout, obs))
    _, w = _robust(np.nan_to_num(np.linalg.norm(r.reshape(-1, 2), axis=1), nan=1e6), loss, f_scale)
    wr = np.repeat(w, 2)
    A = (J.T.multiply(wr[None, :]).tocsr() @ J).tocsc()
    Sinv, W, Vinv = _schur_parts(A, layout.frame0, layout.F)
    shared = view_pose_error(J, r, wr, obs.cam, obs.frame, layout.frame0, layout.n, Sinv, W, Vinv)
    cov = Sinv * shared["sigma2"] + shared["covariance"]
    if details is not None:
        details["view_motion"] = view_motion_summary(shared)
    n_clusters = layout.F
    if n_clusters >= max(MIN_CLUSTERS, 2 * layout.frame0):
        with contextlib.suppress(np.linalg.LinAlgError):  # a covariance not positive definite stays as it is
            cov = larger(cov, _per_view_sandwich(J, wr * r, obs.frame, layout.frame0, layout.F, Sinv, W, Vinv))
    return _labels(layout), cov


def first_order_change(state: BundleState, obs: Observations, target_px: np.ndarray,
                       weights: np.ndarray | None = None) -> dict[tuple[int, str], float]:
    """The change of every parameter (cameras' and board poses') that moves `state`'s pixels of the
    observations to `target_px` ((M, 2)) to first order, by weighted least squares through the Jacobian at
    `state`; returned for the cameras' parameters, by (camera index, name) as `parameter_covariance`'s."""
    layout = _Layout(state, True, True, True)
    x = layout.pack(state)
    fun, scale = _weighted_residuals(layout, state, obs, weights)
    S = layout.sparsity(obs).tocsc()
    S.sort_indices()
    J = _jacobian(fun, x, fun(x), S, _groups(layout, obs))
    d = (np.asarray(target_px, dtype=float) - project_all(state, obs)).ravel()
    d = np.nan_to_num(d if scale is None else d * scale)
    dx = _solve_damped((J.T @ J).tocsc(), -(J.T @ d), 1e-9, layout.frame0, layout.F)
    return dict(zip(_labels(layout), dx[:layout.frame0].tolist(), strict=True))


def _labels(layout: _Layout) -> list[tuple[int, str]]:
    labels: list[tuple[int, str]] = [(0, "")] * layout.frame0
    for c, o in layout.cam_pose.items():
        for k, name in enumerate(("rx", "ry", "rz", "tx", "ty", "tz")):
            labels[o + k] = (c, name)
    for c, (o, _, mask) in layout.intr.items():
        for k, name in enumerate(["fx", "fy", "cx", "cy", *(f"d{k}" for k in np.nonzero(mask)[0])]):
            labels[o + k] = (c, name)
    return labels


def camera_covariances(labels: list[tuple[int, str]], cov: np.ndarray) -> dict:
    """Each camera's block of `parameter_covariance`: {camera index: (parameter names, covariance)}."""
    out = {}
    for c in sorted({c for c, _ in labels}):
        idx = [i for i, (ci, _) in enumerate(labels) if ci == c]
        out[c] = ([labels[i][1] for i in idx], cov[np.ix_(idx, idx)])
    return out


def _schur_parts(A, n_head: int, F: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The leading n_head x n_head block of A⁻¹ (the trailing 6F frame-pose block is block-diagonal): the
    inverse of its Schur complement; with the coupling W (n_head, F, 6) and the frame blocks' inverses."""
    A = A.tocsr()
    U = A[:n_head, :n_head].toarray()
    if F == 0:
        return np.linalg.pinv(U), np.zeros((n_head, 0, 6)), np.zeros((0, 6, 6))
    Vsub = A[n_head:, n_head:].tocoo()
    Vb = np.zeros((F, 6, 6))
    fr, fc = Vsub.row // 6, Vsub.col // 6
    same = fr == fc
    Vb[fr[same], Vsub.row[same] % 6, Vsub.col[same] % 6] = Vsub.data[same]
    Vinv = np.linalg.pinv(Vb)
    W = A[:n_head, n_head:].toarray().reshape(n_head, F, 6)
    Sm = U - np.einsum("afi,fij,bfj->ab", W, Vinv, W)
    return np.linalg.pinv(Sm), W, Vinv


def _per_view_sandwich(J, weighted_residuals, frame, n_head: int, F: int, Sinv, W, Vinv) -> np.ndarray:
    """The head block of A⁻¹ (Σ_f s_f s_fᵀ) A⁻¹ · F / (F - 1), s_f = Jᵀ W r over frame f's residuals: each
    frame's score only touches the head and its own pose, so (A⁻¹ s_f)_head = S⁻¹ (s_h - W_f V_f⁻¹ s_v)."""
    rows = np.repeat(np.asarray(frame), 2)
    scores = csc_matrix(J).multiply(np.asarray(weighted_residuals)[:, None]).tocsr()
    cluster = csr_matrix((np.ones(len(rows)), (rows, np.arange(len(rows)))), shape=(F, len(rows)))
    summed = (cluster @ scores).toarray()
    s_head = summed[:, :n_head]
    s_own = summed[:, n_head:].reshape(F, F, 6)[np.arange(F), np.arange(F)]
    u = (s_head - np.einsum("afi,fij,fj->fa", W, Vinv, s_own)) @ Sinv
    return F / (F - 1) * u.T @ u
