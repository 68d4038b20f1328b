"""Constant-velocity Kalman filter in pixel space, one per marker and camera.

State ``[x, y, vx, vy]`` (px, px/frame); one step = one frame of that camera (backward tracking
simply feeds frames in reverse order). Process noise is white acceleration (``accel_px``, px/frame²).
The gate is the 99 % ellipse of the predicted measurement: Mahalanobis d² ≤ 9.21 (χ², 2 dof).
While a marker is hidden, only `predict` runs: the covariance grows and the gate widens.
A constant-acceleration model made the gate jumpy when the tool hits a marker, hence constant velocity.
"""

from __future__ import annotations

import math

import numpy as np

GATE_D2 = 9.21  # chi-square, 2 dof, 99 %

_F = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)
_H = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], dtype=np.float64)


class ConstantVelocityKF:
    def __init__(self, x: float, y: float, accel_px: float = 2.0, meas_px: float = 0.3,
                 init_speed_px: float = 3.0, coast_damping: float = 0.9, coast_walk_px: float = 3.0,
                 coast_cv_frames: int = 3):
        self.x = np.array([x, y, 0.0, 0.0])
        self.P = np.diag([meas_px**2, meas_px**2, init_speed_px**2, init_speed_px**2])
        q = accel_px**2
        self._q = q
        # Discrete white-noise acceleration over one frame.
        self.Q = q * np.array([[0.25, 0, 0.5, 0], [0, 0.25, 0, 0.5], [0.5, 0, 1, 0], [0, 0.5, 0, 1]])
        self.R = np.eye(2) * meas_px**2
        self.coast_damping = coast_damping
        self.coast_walk_px = coast_walk_px
        self.coast_cv_frames = coast_cv_frames
        self._coasting = False
        self.coast_frames = 0

    @property
    def position(self) -> np.ndarray:
        return self.x[:2].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self.x[2:].copy()

    def predict(self) -> np.ndarray:
        if self._coasting and self.coast_frames > self.coast_cv_frames:
            # Hidden for a while: a hidden marker has mostly stopped (buried, or the tool has passed).
            # Its velocity is forgotten and the position does a random walk, so the gate widens
            # like sqrt(frames), not like frames^1.5 as the constant-velocity model would.
            self.x[2:] = 0.0
            self.P[2:, :] = 0.0
            self.P[:, 2:] = 0.0
            self.P[0, 0] += self.coast_walk_px**2
            self.P[1, 1] += self.coast_walk_px**2
            return self.position
        if self._coasting:
            self.x[2:] *= self.coast_damping
        # x = F x, P = F P F' + Q, written out (a 4 x 4 per track and frame: numpy's call overhead
        # would cost more than the arithmetic).
        x0, x1, x2, x3 = self.x.tolist()
        (p00, p01, p02, p03), (_, p11, p12, p13), (_, _, p22, p23), (_, _, _, p33) = self.P.tolist()
        q = self._q
        a02, a03, a12, a13 = p02 + p22, p03 + p23, p12 + p23, p13 + p33
        self.x = np.array([x0 + x2, x1 + x3, x2, x3])
        n00, n01, n11 = p00 + 2 * p02 + p22, p01 + p03 + p12 + p23, p11 + 2 * p13 + p33
        self.P = np.array([[n00 + 0.25 * q, n01, a02 + 0.5 * q, a03],
                           [n01, n11 + 0.25 * q, a12, a13 + 0.5 * q],
                           [a02 + 0.5 * q, a12, p22 + q, p23],
                           [a03, a13 + 0.5 * q, p23, p33 + q]])
        return self.position

    def innovation_cov(self) -> np.ndarray:
        return self.P[:2, :2] + self.R

    def innovation_inv(self) -> np.ndarray:
        return _inv2(self.innovation_cov())

    def mahalanobis2(self, z) -> np.ndarray:
        """Squared Mahalanobis distance(s) of measurement(s) z (2,) or (N, 2) from the prediction."""
        s00, s01, s11 = self.P[0, 0] + self.R[0, 0], self.P[0, 1] + self.R[0, 1], self.P[1, 1] + self.R[1, 1]
        det = s00 * s11 - s01 * s01
        if isinstance(z, tuple) and len(z) == 2:  # one point: plain floats (per track and frame)
            dx, dy = float(z[0]) - self.x[0], float(z[1]) - self.x[1]
            return np.array([(s11 * dx * dx - 2 * s01 * dx * dy + s00 * dy * dy) / det])
        z = np.atleast_2d(np.asarray(z, dtype=np.float64))
        d = z - self.x[:2]
        return (s11 * d[:, 0] ** 2 - 2 * s01 * d[:, 0] * d[:, 1] + s00 * d[:, 1] ** 2) / det

    def gate_halfsize(self, d2: float = GATE_D2) -> tuple[float, float]:
        """Half extents (x, y) of the box enclosing the gate ellipse."""
        P, R = self.P, self.R
        return math.sqrt(d2 * (P[0, 0] + R[0, 0])), math.sqrt(d2 * (P[1, 1] + R[1, 1]))

    def update(self, z, meas_px: float | None = None) -> None:
        r = self.R[0, 0] if meas_px is None else meas_px**2
        zx, zy = float(z[0]), float(z[1])
        x0, x1, x2, x3 = self.x.tolist()
        P = self.P.tolist()
        s00, s01, s11 = P[0][0] + r, P[0][1], P[1][1] + r
        det = s00 * s11 - s01 * s01
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        # K = P[:, :2] S^-1 (4 x 2); x += K (z - Hx); P -= K P[:2, :] (then symmetrised)
        K = [(row[0] * i00 + row[1] * i01, row[0] * i01 + row[1] * i11) for row in P]
        ex, ey = zx - x0, zy - x1
        self.x = np.array([x0 + K[0][0] * ex + K[0][1] * ey, x1 + K[1][0] * ex + K[1][1] * ey,
                           x2 + K[2][0] * ex + K[2][1] * ey, x3 + K[3][0] * ex + K[3][1] * ey])
        P0, P1 = P[0], P[1]
        n = {}
        for i in range(4):  # the upper triangle; the result is symmetric
            ki0, ki1, Pi = K[i][0], K[i][1], P[i]
            for j in range(i, 4):
                n[i, j] = Pi[j] - ki0 * P0[j] - ki1 * P1[j]
        self.P = np.array([[n[0, 0], n[0, 1], n[0, 2], n[0, 3]], [n[0, 1], n[1, 1], n[1, 2], n[1, 3]],
                           [n[0, 2], n[1, 2], n[2, 2], n[2, 3]], [n[0, 3], n[1, 3], n[2, 3], n[3, 3]]])
        self._coasting = False
        self.coast_frames = 0

    def coast(self) -> None:
        """Record that this frame had no measurement (the next predict damps velocity)."""
        self._coasting = True
        self.coast_frames += 1

    def reset(self, x: float, y: float, speed_px: float = 3.0, velocity=None) -> None:
        """Re-attach after a long gap: position known, velocity uncertain."""
        v = np.zeros(2) if velocity is None else np.asarray(velocity, dtype=np.float64)
        self.x = np.array([x, y, v[0], v[1]])
        r = self.R[0, 0]
        self.P = np.diag([r, r, speed_px**2, speed_px**2])
        self._coasting = False
        self.coast_frames = 0


def _inv2(S: np.ndarray) -> np.ndarray:
    a, b, c, d = S[0, 0], S[0, 1], S[1, 0], S[1, 1]
    det = a * d - b * c
    return np.array([[d, -b], [-c, a]]) / det
