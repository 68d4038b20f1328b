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


class ConstantVelocityKF:
    """State and covariance are kept as plain floats (a 4 x 4 per track and frame: numpy's per-call
    cost would be most of the work); `x` and `P` give them as arrays."""

    def __init__(self, x: float, y: float, accel_px: float = 2.0, meas_px: float = 0.3,
                 init_speed_px: float = 3.0, coast_damping: float = 0.9, coast_walk_px: float = 3.0,
                 coast_cv_frames: int = 3):
        self._x = [float(x), float(y), 0.0, 0.0]
        # Upper triangle of P: p00 p01 p02 p03 p11 p12 p13 p22 p23 p33.
        m2, v2 = float(meas_px**2), float(init_speed_px**2)
        self._p = [m2, 0.0, 0.0, 0.0, m2, 0.0, 0.0, v2, 0.0, v2]
        # Discrete white-noise acceleration over one frame: Q = q [[I/4, I/2], [I/2, I]] (see advance).
        self._q = accel_px**2
        self.R = np.eye(2) * meas_px**2
        self._r = float(self.R[0, 0])
        self.coast_damping = coast_damping
        self.coast_walk_px = coast_walk_px
        self.coast_cv_frames = coast_cv_frames
        self._coasting = False
        self.coast_frames = 0

    @property
    def x(self) -> np.ndarray:
        return np.array(self._x)

    @x.setter
    def x(self, value) -> None:
        self._x = [float(v) for v in np.asarray(value, dtype=np.float64).ravel()]

    @property
    def P(self) -> np.ndarray:
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._p
        return np.array([[p00, p01, p02, p03], [p01, p11, p12, p13], [p02, p12, p22, p23], [p03, p13, p23, p33]])

    @P.setter
    def P(self, value) -> None:
        P = np.asarray(value, dtype=np.float64)
        self._p = [float(P[i, j]) for i in range(4) for j in range(i, 4)]

    @property
    def position(self) -> np.ndarray:
        return np.array(self._x[:2])

    @property
    def xy(self) -> tuple[float, float]:
        return self._x[0], self._x[1]

    @property
    def vxy(self) -> tuple[float, float]:
        return self._x[2], self._x[3]

    @property
    def velocity(self) -> np.ndarray:
        return np.array(self._x[2:])

    def predict(self) -> np.ndarray:
        self.advance()
        return self.position

    def advance(self) -> None:
        """`predict` without building the position array (per track and frame)."""
        if self._coasting and self.coast_frames > self.coast_cv_frames:
            # Hidden for a while: a hidden marker has mostly stopped (buried, or the tool has passed).
            # Its velocity is forgotten and the position does a random walk, so the gate widens
            # like sqrt(frames), not like frames^1.5 as the constant-velocity model would.
            self._x[2] = self._x[3] = 0.0
            w2 = self.coast_walk_px**2
            p = self._p
            self._p = [p[0] + w2, p[1], 0.0, 0.0, p[4] + w2, 0.0, 0.0, 0.0, 0.0, 0.0]
            return
        x0, x1, x2, x3 = self._x
        if self._coasting:
            x2, x3 = x2 * self.coast_damping, x3 * self.coast_damping
        # x = F x, P = F P F' + Q, written out.
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._p
        q = self._q
        a02, a03, a12, a13 = p02 + p22, p03 + p23, p12 + p23, p13 + p33
        self._x = [x0 + x2, x1 + x3, x2, x3]
        n00, n01, n11 = p00 + 2 * p02 + p22, p01 + p03 + p12 + p23, p11 + 2 * p13 + p33
        self._p = [n00 + 0.25 * q, n01, a02 + 0.5 * q, a03, n11 + 0.25 * q, a12, a13 + 0.5 * q,
                   p22 + q, p23, p33 + q]

    def innovation_inv(self) -> tuple[float, float, float]:
        """(i00, i01, i11) of the inverse innovation covariance, as plain floats (per track and frame)."""
        p, r = self._p, self._r  # (R = r I, a plain float: numpy scalars would slow every term down)
        s00, s01, s11 = p[0] + r, p[1], p[4] + r
        det = s00 * s11 - s01 * s01
        return s11 / det, -s01 / det, s00 / det

    def d2(self, zx: float, zy: float) -> float:
        """Squared Mahalanobis distance of one measurement (zx, zy) from the prediction."""
        p, r = self._p, self._r
        s00, s01, s11 = p[0] + r, p[1], p[4] + r
        det = s00 * s11 - s01 * s01
        dx, dy = float(zx) - self._x[0], float(zy) - self._x[1]
        return (s11 * dx * dx - 2 * s01 * dx * dy + s00 * dy * dy) / det

    def mahalanobis2(self, z) -> np.ndarray:
        """Squared Mahalanobis distance(s) of measurement(s) z (2,) or (N, 2) from the prediction."""
        if isinstance(z, tuple) and len(z) == 2:  # one point: plain floats (per track and frame)
            return np.array([self.d2(z[0], z[1])])
        p, r = self._p, self._r
        s00, s01, s11 = p[0] + r, p[1], p[4] + r
        det = s00 * s11 - s01 * s01
        z = np.atleast_2d(np.asarray(z, dtype=np.float64))
        d = z - np.array(self._x[:2])
        return (s11 * d[:, 0] ** 2 - 2 * s01 * d[:, 0] * d[:, 1] + s00 * d[:, 1] ** 2) / det

    def gate_halfsize(self, d2: float = GATE_D2) -> tuple[float, float]:
        """Half extents (x, y) of the box enclosing the gate ellipse."""
        p, r = self._p, self._r
        return math.sqrt(d2 * (p[0] + r)), math.sqrt(d2 * (p[4] + r))

    def update(self, z, meas_px: float | None = None) -> None:
        r = self._r if meas_px is None else meas_px**2
        zx, zy = float(z[0]), float(z[1])
        x0, x1, x2, x3 = self._x
        p00, p01, p02, p03, p11, p12, p13, p22, p23, p33 = self._p
        s00, s01, s11 = p00 + r, p01, p11 + r
        det = s00 * s11 - s01 * s01
        i00, i01, i11 = s11 / det, -s01 / det, s00 / det
        # K = P[:, :2] S^-1 (4 x 2); x += K (z - Hx); P -= K P[:2, :] (upper triangle; symmetric)
        k00, k01 = p00 * i00 + p01 * i01, p00 * i01 + p01 * i11
        k10, k11 = p01 * i00 + p11 * i01, p01 * i01 + p11 * i11
        k20, k21 = p02 * i00 + p12 * i01, p02 * i01 + p12 * i11
        k30, k31 = p03 * i00 + p13 * i01, p03 * i01 + p13 * i11
        ex, ey = zx - x0, zy - x1
        self._x = [x0 + k00 * ex + k01 * ey, x1 + k10 * ex + k11 * ey,
                   x2 + k20 * ex + k21 * ey, x3 + k30 * ex + k31 * ey]
        self._p = [p00 - k00 * p00 - k01 * p01, p01 - k00 * p01 - k01 * p11, p02 - k00 * p02 - k01 * p12,
                   p03 - k00 * p03 - k01 * p13,
                   p11 - k10 * p01 - k11 * p11, p12 - k10 * p02 - k11 * p12, p13 - k10 * p03 - k11 * p13,
                   p22 - k20 * p02 - k21 * p12, p23 - k20 * p03 - k21 * p13,
                   p33 - k30 * p03 - k31 * p13]
        self._coasting = False
        self.coast_frames = 0

    def translate(self, dx: float, dy: float) -> None:
        """Move the position by (dx, dy): the whole view moved (camera pan or shake), not the marker."""
        self._x[0] += float(dx)
        self._x[1] += float(dy)

    def coast(self) -> None:
        """Record that this frame had no measurement (the next predict damps velocity)."""
        self._coasting = True
        self.coast_frames += 1

    def reset(self, x: float, y: float, speed_px: float = 3.0, velocity=None) -> None:
        """Re-attach after a long gap: position known, velocity uncertain."""
        v = (0.0, 0.0) if velocity is None else [float(u) for u in np.asarray(velocity, dtype=np.float64)]
        self._x = [float(x), float(y), v[0], v[1]]
        r, s2 = self._r, float(speed_px**2)
        self._p = [r, 0.0, 0.0, 0.0, r, 0.0, 0.0, s2, 0.0, s2]
        self._coasting = False
        self.coast_frames = 0

