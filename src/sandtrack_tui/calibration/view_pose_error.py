"""An error shared by all corners of one view that looks like a board pose of its own: the board moved
between the cameras' exposures (cameras not locked together, a hand-held board), or a view's detections
shifted together (blur, light). One frame's board pose is fitted to every camera that saw it, so each view
keeps the part of its own pose error that the others do not share; the bundle adjustment's covariance,
which takes every corner's error as independent, cannot see it.

Model: a view v (one camera, one frame) sees the board at the frame's pose moved by m_v, independent from
view to view with covariance Σ_m (in the board pose's six parameters: the same motion whatever the camera);
its residuals are ε + G_v m_v, G_v = d(pixels) / d(board pose), ε independent with variance σ_ε².

Estimate: each view's own pose change δ_v = I_v⁻¹ G_vᵀ W r_v at the solution, I_v = G_vᵀ W G_v. The frame's
pose is the views' information-weighted mean, so δ_v = Σ_u B_u d_u over the frame's views u (d_u = m_u +
the corners' noise, B_v = 1 - I_f⁻¹ I_v, B_u = -I_f⁻¹ I_u, I_f = Σ I_u) and
E[δ_v δ_vᵀ] = Σ_u B_u Σ_m B_uᵀ + σ_ε² (I_v⁻¹ - I_f⁻¹): linear in Σ_m, solved for it over all views (its
negative part dropped), σ_ε² from the residuals that the views' own poses leave. A frame one camera saw
tells nothing (its pose takes all).

Propagation: the parameters' covariance is the sandwich A⁻¹ (σ_ε² A + Σ_v Jᵀ W G_v Σ_m G_vᵀ W J) A⁻¹ (A = JᵀWJ,
the board poses marginalised): σ_ε² A⁻¹ plus, per view, (A⁻¹ Jᵀ W G_v) Σ_m (...)ᵀ. A view's pose error moves
the cameras' parameters only through the other views of its frame; in a frame one camera saw it is absorbed.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.sparse import csr_matrix

POSE = 6


class ViewGroups(NamedTuple):
    """The views (one camera in one frame) of flat observations."""

    index: np.ndarray  # (M,) each observation's view
    frame: np.ndarray  # (V,) each view's frame
    cameras_in_frame: np.ndarray  # (F,) how many views each frame has
    order: np.ndarray  # (M,) the observations sorted by view
    bounds: np.ndarray  # (V + 1,) view v's observations: order[bounds[v]:bounds[v + 1]]


def view_groups(cam: np.ndarray, frame: np.ndarray) -> ViewGroups:
    n_frames = int(frame.max()) + 1
    keys, index = np.unique(cam.astype(np.int64) * n_frames + frame, return_inverse=True)
    view_frame = keys % n_frames
    order = np.argsort(index, kind="stable")
    return ViewGroups(index, view_frame, np.bincount(view_frame, minlength=n_frames), order,
                      np.searchsorted(index[order], np.arange(len(keys) + 1)))


def view_pose_error(J: csr_matrix, r: np.ndarray, w: np.ndarray, cam: np.ndarray, frame: np.ndarray,
                    n_head: int, n_parameters: int, Sinv: np.ndarray, W: np.ndarray,
                    Vinv: np.ndarray) -> dict:
    """{"sigma2": σ_ε², "covariance": the per-view pose term of the head parameters' covariance (n_head,
    n_head), "motion": Σ_m (6, 6), "views": views in frames two cameras or more saw}. J: the weighted
    residuals' Jacobian (2M, n), head parameters first, then 6 per frame; r: weighted residuals (2M,);
    w: the robust loss's weight per residual (2M,); cam, frame: (M,) per observation; Sinv, W, Vinv:
    `bundle._schur_parts`."""
    J = csr_matrix(J)
    views = view_groups(cam, frame)
    per_frame: dict[int, list] = {}
    for k, f in enumerate(views.frame.tolist()):
        obs_rows = views.order[views.bounds[k]:views.bounds[k + 1]]
        if views.cameras_in_frame[f] >= 2:
            per_frame.setdefault(f, []).append(np.stack([2 * obs_rows, 2 * obs_rows + 1], axis=1).ravel())
    total_ss, own_ss, parts, moments = float(np.sum(w * r * r)), 0.0, [], []
    for f, views in per_frame.items():
        found = []
        for rows in views:
            Jv = J[rows].toarray()
            G = Jv[:, n_head + POSE * f:n_head + POSE * (f + 1)]
            info = G.T @ (w[rows, None] * G)
            found.append((info, G.T @ (w[rows] * r[rows]), Jv[:, :n_head].T @ (w[rows, None] * G)))
        try:
            total_inv = np.linalg.inv(sum(i for i, _, _ in found))
            own = [np.linalg.solve(i, g) for i, g, _ in found]  # each view's own pose change
        except np.linalg.LinAlgError:
            continue
        # the change the frame's pose would take from them (0 at a converged solution)
        common = total_inv @ sum(i @ o for (i, _, _), o in zip(found, own, strict=True))
        for v, (info, _, x_head) in enumerate(found):
            own_ss += float(own[v] @ info @ own[v])
            B = [(np.eye(POSE) if u == v else 0.0) - total_inv @ i for u, (i, _, _) in enumerate(found)]
            # vec(B Σ Bᵀ) = (B ⊗ B) vec(Σ), row-major
            moments.append((own[v] - common, np.linalg.inv(info) - total_inv, sum(np.kron(b, b) for b in B)))
            parts.append((f, x_head, info))
    extra_dof = POSE * (len(parts) - len(per_frame))
    sigma2 = (total_ss - own_ss) / max(len(r) - n_parameters - extra_dof, 1)
    out = {"sigma2": sigma2, "covariance": np.zeros((n_head, n_head)), "motion": np.zeros((POSE, POSE)),
           "views": len(parts)}
    if not parts:
        return out
    lhs = sum(k for _, _, k in moments)
    rhs = sum((np.outer(d, d) - sigma2 * noise).ravel() for d, noise, _ in moments)
    motion = np.linalg.lstsq(lhs, rhs, rcond=None)[0].reshape(POSE, POSE)
    lam, Q = np.linalg.eigh((motion + motion.T) / 2)
    motion = Q @ np.diag(np.clip(lam, 0.0, None)) @ Q.T
    root = Q @ np.diag(np.sqrt(np.clip(lam, 0.0, None)))
    cov = np.zeros((n_head, n_head))
    for f, x_head, x_own in parts:
        u = Sinv @ (x_head - W[:, f, :] @ Vinv[f] @ x_own) @ root
        cov += u @ u.T
    out.update(covariance=cov, motion=motion)
    return out


def view_motion_summary(shared: dict) -> dict:
    """`view_pose_error`'s result for a report: the views it used, the corners' own noise (px) and the
    motion's sd about and along the rig frame's axes (degrees, mm; the rotation vector's and the board
    origin's)."""
    sd = np.sqrt(np.diag(shared["motion"]))
    return {"views": int(shared["views"]), "corner_noise_px": float(np.sqrt(shared["sigma2"])),
            "rotation_sd_deg": [float(v) for v in np.degrees(sd[:3])],
            "translation_sd_mm": [float(v) for v in sd[3:]]}
