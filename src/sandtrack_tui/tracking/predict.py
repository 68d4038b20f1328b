"""Constant-velocity Kalman filters for many tracks at once (arrays, one row per track).

State per track: x, y (px), vx, vy (px per frame). `start` makes new tracks (velocity unknown: a wide
first gate), `predict` steps them one frame, `gate` gives the innovation covariance and the largest
radius a gate can reach, `mahalanobis` the squared distance of candidates, `update` folds in the
measurements of the tracks that got one. Units are pixels and frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_F = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]], float)
_H = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], float)


@dataclass(frozen=True)
class Motion:
    accel_px: float = 3.0  # sd of the change of velocity per frame (a bead bouncing off the bed)
    measure_px: float = 0.5  # sd of a detection's centre
    first_speed_px: float = 15.0  # sd of a new track's unknown velocity, per axis
    gate_d2: float = 13.8  # chi-square, 2 dof, 99.9 %


def start(xy: np.ndarray, motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """New tracks at positions xy (n, 2): state (n, 4) at rest, covariance (n, 4, 4)."""
    n = len(xy)
    X = np.zeros((n, 4))
    X[:, :2] = xy
    P = np.zeros((n, 4, 4))
    P[:, 0, 0] = P[:, 1, 1] = motion.measure_px ** 2
    P[:, 2, 2] = P[:, 3, 3] = motion.first_speed_px ** 2
    return X, P


def _q(motion: Motion) -> np.ndarray:
    a = motion.accel_px ** 2
    return a * np.array([[.25, 0, .5, 0], [0, .25, 0, .5], [.5, 0, 1, 0], [0, .5, 0, 1]])


def predict(X: np.ndarray, P: np.ndarray, motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    return X @ _F.T, _F @ P @ _F.T + _q(motion)


def gate(P: np.ndarray, motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Innovation covariance S (n, 2, 2) and each gate's reach (px): sqrt(gate_d2 * largest eigenvalue)."""
    S = P[:, :2, :2] + np.eye(2) * motion.measure_px ** 2
    a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    lam = 0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b ** 2)
    return S, np.sqrt(motion.gate_d2 * lam)


def mahalanobis(S: np.ndarray, X: np.ndarray, ti: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distance of measurement z[k] from track ti[k]'s prediction."""
    d = z - X[ti, :2]
    a, b, c = S[ti, 0, 0], S[ti, 0, 1], S[ti, 1, 1]
    det = a * c - b * b
    return (c * d[:, 0] ** 2 - 2 * b * d[:, 0] * d[:, 1] + a * d[:, 1] ** 2) / det


def update(X: np.ndarray, P: np.ndarray, rows: np.ndarray, z: np.ndarray,
           motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update of tracks `rows` with measurements z (len(rows), 2); the others are kept as predicted."""
    if len(rows) == 0:
        return X, P
    X, P = X.copy(), P.copy()
    Pr = P[rows]
    S = Pr[:, :2, :2] + np.eye(2) * motion.measure_px ** 2
    K = Pr[:, :, :2] @ np.linalg.inv(S)  # (m, 4, 2)
    X[rows] = X[rows] + np.einsum("mij,mj->mi", K, z - X[rows, :2])
    P[rows] = Pr - K @ Pr[:, :2, :]
    return X, P
