"""Is a DEM trajectory consistent with the measured one, given the measurement's error? The χ² of
their differences in units of the combined uncertainty, with honest degrees of freedom.

Per sample i (an experiment frame): the difference d_i = experiment - DEM (mm, 3 axes) and its
covariance C_i = the experiment's (its ``sd_*_mm`` columns, and ``cov_*_mm2`` when given) + the DEM's
(an sd per axis). m_i = d_iᵀ C_i⁻¹ d_i is χ²-distributed with 3 degrees of freedom if the DEM is the
truth and the uncertainties are right; a sample lies *within the 95 % band* when m_i ≤ χ²₃(0.95) = 7.81
(the 95 % ellipsoid of the difference; per axis the band is ±1.96 sd).

Samples along a trajectory are not independent: a resting marker's error is the same frame after frame,
and the calibration's and the network's errors change only as the marker moves. Summing m_i over n
frames as if they were n independent draws would reject a good DEM run. So the null distribution of
χ² = Σ m_i is taken with the variance that the samples' correlation gives it: the whitened differences
w_i = L_i⁻¹ d_i (C_i = L_i L_iᵀ) are autocorrelated along the frame grid, per component a, ρ_a(k) from
the data about zero (not about their mean: a difference that persists counts as correlated, which is
what a systematic measurement error looks like; an offset far beyond the uncertainty is still found,
since it makes χ² large, not only persistent). For Gaussian w, Var χ² = 2 Σ_a [n + 2 Σ_k n_k ρ_a(k)²]
(n_k pairs at lag k, k up to Sokal's window: the smallest M ≥ 5 τ(M)). χ² is then compared with
g·χ²(h), the scaled χ² of the same mean and variance (Welch–Satterthwaite): h is the effective number
of degrees of freedom, h / 3 the effective number of independent samples. The time shift fitted over
all particles takes one degree of freedom from the run (a 1/N share from each of its N particles).

Left out, and said so: correlation between particles (a calibration error shared by all), and between
the axes of successive samples; the DEM's interpolation between its output steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from .interval import Z_BOTH

CHI2_95_3D = float(stats.chi2.ppf(0.95, 3))  # 7.81
Z95 = Z_BOTH  # 1.96: the 95 % band per axis is ±Z95 sd
SOKAL_C = 5.0


@dataclass
class Chi2:
    chi2: float  # Σ m_i
    dof: float  # 3 n - fitted share: the expected χ² if the DEM is right
    var0: float  # its variance under that hypothesis, with the samples' correlation
    samples: int  # samples with an uncertainty
    within: int  # samples within the 95 % band

    @property
    def reduced(self) -> float:
        """χ² / dof: 1 when the differences are as large as the uncertainty says."""
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    @property
    def dof_eff(self) -> float:
        return 2.0 * self.dof ** 2 / self.var0 if self.var0 > 0 else float("nan")

    @property
    def chi2_eff(self) -> float:
        return self.chi2 * self.dof_eff / self.dof if self.dof > 0 else float("nan")

    @property
    def p_value(self) -> float:
        """P(a χ² this large or larger | the DEM is right), from g·χ²(h)."""
        h = self.dof_eff
        return float(stats.chi2.sf(self.chi2_eff, h)) if np.isfinite(h) and h > 0 else float("nan")

    def to_dict(self) -> dict:
        n = self.samples
        return {"chi2": self.chi2, "chi2_dof": self.dof, "chi2_reduced": self.reduced, "chi2_eff": self.chi2_eff,
                "dof_eff": self.dof_eff, "samples_eff": self.dof_eff / 3.0, "p_value": self.p_value,
                "samples_with_sd": n, "within_95_pct": 100.0 * self.within / n if n else float("nan")}


def covariances(sd: np.ndarray, cov: np.ndarray | None = None, extra_sd: float = 0.0) -> np.ndarray:
    """(n, 3, 3) mm² from per-axis sd (n, 3), optional covariances (n, 3: XY, XZ, YZ) and an sd added
    to every axis (e.g. the DEM's)."""
    sd = np.asarray(sd, float).reshape(-1, 3)
    c = np.zeros((len(sd), 3, 3))
    c[:, [0, 1, 2], [0, 1, 2]] = sd ** 2 + float(extra_sd) ** 2
    if cov is not None:
        cov = np.nan_to_num(np.asarray(cov, float).reshape(-1, 3))
        for k, (i, j) in enumerate(((0, 1), (0, 2), (1, 2))):
            c[:, i, j] = c[:, j, i] = cov[:, k]
    return c


def whiten(diff: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whitened differences w (n, 3) and a mask of the samples whose covariance is usable (finite,
    positive definite); w is NaN elsewhere."""
    n = len(diff)
    w = np.full((n, 3), np.nan)
    ok = np.isfinite(cov).all(axis=(1, 2)) & np.isfinite(diff).all(axis=1)
    c = np.where(ok[:, None, None], cov, np.eye(3))
    ok &= np.linalg.eigvalsh(c).min(axis=1) > 0  # an sd of 0 claims an exact position: no χ² from it
    if ok.any():
        L = np.linalg.cholesky(np.where(ok[:, None, None], c, np.eye(3)))
        w[ok] = np.linalg.solve(L[ok], diff[ok][..., None])[..., 0]
    return w, ok


def chi2_of_track(frames: np.ndarray, w: np.ndarray, fitted_share: float = 0.0) -> Chi2:
    """χ² of one trajectory from its whitened differences w (n, 3; NaN rows left out) at integer frame
    indices `frames` (gaps allowed), with the variance its autocorrelation gives (module docstring)."""
    ok = np.isfinite(w).all(axis=1)
    n = int(ok.sum())
    if n == 0:
        return Chi2(float("nan"), 0.0, float("nan"), 0, 0)
    w, f = w[ok], np.asarray(frames)[ok].astype(np.int64)
    m = (w ** 2).sum(axis=1)
    var0 = sum(_chi2_variance(f - f.min(), w[:, a]) for a in range(3))
    return Chi2(float(m.sum()), 3.0 * n - fitted_share, var0, n, int((m <= CHI2_95_3D).sum()))


def _chi2_variance(index: np.ndarray, z: np.ndarray) -> float:
    """Var Σ z_i² for Gaussian z of unit variance on a frame grid, from their autocorrelation about zero."""
    n = len(z)
    size = int(index.max()) + 1
    grid, mask = np.zeros(size), np.zeros(size)
    grid[index], mask[index] = z, 1.0
    nfft = 1 << int(np.ceil(np.log2(2 * size)))
    prod = np.fft.irfft(np.abs(np.fft.rfft(grid, nfft)) ** 2, nfft)[:size]
    pairs = np.rint(np.fft.irfft(np.abs(np.fft.rfft(mask, nfft)) ** 2, nfft)[:size])
    mean_sq = float((z ** 2).mean())
    if mean_sq <= 0:
        return 2.0 * n
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(pairs > 0, prod / np.maximum(pairs, 1) / mean_sq, 0.0)
    terms = np.clip(pairs[1:] * rho[1:] ** 2 - 1.0, 0.0, None)  # less the noise of rho estimated from n_k pairs
    tau = 1.0 + 2.0 * np.cumsum(terms) / n
    lags = np.arange(1, size)
    stop = np.nonzero(lags >= SOKAL_C * tau)[0]
    window = int(stop[0]) + 1 if len(stop) else size - 1
    return 2.0 * (n + 2.0 * float(terms[:window].sum()))


def combine(parts: list[Chi2], fitted: float = 0.0) -> Chi2:
    """One χ² over independent parts (the run's particles); `fitted` parameters beyond their shares."""
    parts = [p for p in parts if p.samples > 0]
    if not parts:
        return Chi2(float("nan"), 0.0, float("nan"), 0, 0)
    return Chi2(sum(p.chi2 for p in parts), sum(p.dof for p in parts) - fitted, sum(p.var0 for p in parts),
                sum(p.samples for p in parts), sum(p.within for p in parts))
