"""Robust straight-line fits and the settled value of a series: shared by the image and DEM methods.

A flank is fitted as ``y = a + b x`` by iteratively reweighted least squares with Tukey's biweight
(c = 4.685 robust standard deviations; the scale is the MAD of the residuals), started from the
Theil-Sen line, so a few grains, a shadow blob or a stray particle do not tilt it. The slope's
standard error comes from the final weighted fit, inflated for the correlation of neighbouring
residuals (an outline pixel or a surface particle is not independent of the next one): with rho the
lag-1 autocorrelation of the residuals in x order, the variance is multiplied by (1 + rho) / (1 - rho).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SandtrackError

TUKEY_C = 4.685
MIN_POINTS = 8


@dataclass
class LineFit:
    intercept: float
    slope: float
    cov: np.ndarray  # 2 x 2 covariance of (intercept, slope)
    scale: float  # robust residual standard deviation
    inliers: np.ndarray  # bool per point: weight > 0
    rho: float  # lag-1 autocorrelation of the residuals

    @property
    def slope_sigma(self) -> float:
        return float(np.sqrt(max(self.cov[1, 1], 0.0)))


def _theil_sen(x: np.ndarray, y: np.ndarray, max_points: int = 400) -> tuple[float, float]:
    if len(x) > max_points:  # evenly spaced subsample: O(n^2) pairs stay small
        k = np.linspace(0, len(x) - 1, max_points).round().astype(int)
        x, y = x[k], y[k]
    i, j = np.triu_indices(len(x), 1)
    dx = x[j] - x[i]
    ok = np.abs(dx) > 1e-12
    if not ok.any():
        raise SandtrackError("a line fit needs points at different positions")
    b = float(np.median((y[j] - y[i])[ok] / dx[ok]))
    return float(np.median(y - b * x)), b


def robust_line(x, y, iterations: int = 30) -> LineFit:
    """Tukey-biweight IRLS fit of y = a + b x (see module docstring)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < MIN_POINTS:
        raise SandtrackError(f"too few points for a line fit ({len(x)}, at least {MIN_POINTS})")
    order = np.argsort(x, kind="stable")
    x, y = x[order], y[order]
    a, b = _theil_sen(x, y)
    w = np.ones_like(x)
    scale = 0.0
    for _ in range(iterations):
        r = y - (a + b * x)
        scale = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        if scale <= 1e-12:
            scale = max(float(np.sqrt(np.mean(r * r))), 1e-12)
        u = r / (TUKEY_C * scale)
        w_new = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
        if (w_new > 0).sum() < MIN_POINTS:
            break
        A = np.column_stack([np.ones_like(x), x])
        sw = np.sqrt(w_new)
        a_new, b_new = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)[0]
        done = abs(b_new - b) < 1e-10 * (1 + abs(b)) and abs(a_new - a) < 1e-9 * (1 + abs(a))
        a, b, w = float(a_new), float(b_new), w_new
        if done:
            break
    r = y - (a + b * x)
    keep = w > 0
    rk = r[keep]
    sigma2 = float((w[keep] * rk ** 2).sum() / max(w[keep].sum() - 2, 1.0))
    rho = 0.0
    if keep.sum() > 4 and rk.std() > 0:
        rho = float(np.clip(np.corrcoef(rk[:-1], rk[1:])[0, 1], 0.0, 0.95))
    A = np.column_stack([np.ones_like(x), x])[keep]
    try:
        cov = np.linalg.inv((A * w[keep, None]).T @ A) * sigma2 * (1 + rho) / (1 - rho)
    except np.linalg.LinAlgError:
        raise SandtrackError("the line fit is degenerate (all points at one position)") from None
    inliers = np.empty_like(keep)
    inliers[order] = keep
    return LineFit(a, b, cov, float(np.sqrt(sigma2)), inliers, rho)


def slope_angle_deg(fit: LineFit) -> tuple[float, float]:
    """|atan(slope)| and its standard error (deg)."""
    b = fit.slope
    return float(np.degrees(np.arctan(abs(b)))), float(np.degrees(fit.slope_sigma / (1 + b * b)))


@dataclass
class Settled:
    angle_deg: float  # mean of the settled samples
    sd_deg: float  # their standard deviation
    from_s: float  # time from which the series stays settled
    samples: int
    tolerance_deg: float


def settled_value(t, angle, tolerance_deg: float | None = None, tail: float = 0.2) -> Settled | None:
    """The value a series settles to: the final level is the median of the last `tail` of the valid
    samples (at least 3); the series is settled from the first time after which every sample stays
    within the tolerance of it: `tolerance_deg`, or by default max(0.3 deg, 3 x the robust spread of
    that last part). None when fewer than 3 valid samples."""
    t, a = np.asarray(t, float), np.asarray(angle, float)
    ok = np.isfinite(t) & np.isfinite(a)
    t, a = t[ok], a[ok]
    if len(a) < 3:
        return None
    order = np.argsort(t, kind="stable")
    t, a = t[order], a[order]
    n_tail = max(3, int(np.ceil(tail * len(a))))
    last = a[-n_tail:]
    level = float(np.median(last))
    if tolerance_deg is None:
        spread = 1.4826 * float(np.median(np.abs(last - level)))
        tolerance_deg = max(0.3, 3.0 * spread)
    outside = np.nonzero(np.abs(a - level) > tolerance_deg)[0]
    first = int(outside[-1]) + 1 if len(outside) else 0
    first = min(first, len(a) - 1)
    s = a[first:]
    return Settled(float(s.mean()), float(s.std(ddof=1)) if len(s) > 1 else 0.0, float(t[first]), len(s),
                   float(tolerance_deg))
