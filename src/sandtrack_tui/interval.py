"""A Gaussian error N(m, s²) and the symmetric 95 % interval around zero that holds it.

An XYZ whose error has an estimated offset m (a network's error as the triangulation measures it,
`regression.check`) is reported with sd = h / 1.96, ±h the interval around the XYZ that holds the error with
95 % probability: per axis, ±1.96 sd means what it means for any other row. A χ² (`compare`) needs the
Gaussian itself: with the offset kept beside the sd, `gaussian_sd` gives s back."""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr

Z_SIDE = 1.6448536269514722  # one-sided 95 % normal quantile
Z_BOTH = 1.959963984540054  # two-sided 95 % normal quantile


def interval_sd(mean: np.ndarray, sd: np.ndarray, iterations: int = 3) -> np.ndarray:
    """h / 1.96 where ±h around 0 holds a Gaussian error N(mean, sd²) with probability 95 %; by Newton's
    method from below (h >= max(|mean| + 1.645 sd, 1.96 sd); the coverage is concave in h there, so each
    step stays below the root; three steps: within 1e-8 of it)."""
    m, s = np.abs(mean), np.maximum(sd, 1e-12)
    h = np.maximum(m + Z_SIDE * s, Z_BOTH * s)
    for _ in range(iterations):
        hi, lo = (h - m) / s, (-h - m) / s
        f = ndtr(hi) - ndtr(lo) - 0.95
        slope = (np.exp(-0.5 * hi ** 2) + np.exp(-0.5 * lo ** 2)) / (np.sqrt(2 * np.pi) * s)
        h = h - f / np.maximum(slope, 1e-300)
    return h / Z_BOTH


def gaussian_sd(interval: np.ndarray, mean: np.ndarray, iterations: int = 60) -> np.ndarray:
    """The inverse of `interval_sd`: s such that ±1.96 `interval` around 0 holds N(mean, s²) with
    probability 95 % (bisection: the coverage falls as s grows). NaN mean: 0; NaN where the interval is NaN
    or does not reach past the mean (no Gaussian of that mean has 95 % inside it)."""
    h = Z_BOTH * np.asarray(interval, float)
    m = np.abs(np.nan_to_num(np.asarray(mean, float)))
    m, h = np.broadcast_arrays(m, h)
    lo = np.zeros(h.shape)
    hi = np.where(np.isfinite(h), h / Z_SIDE, np.nan)  # at s = h / 1.645 even m = 0 holds less than 95 %
    for _ in range(iterations):
        s = 0.5 * (lo + hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            held = ndtr((h - m) / s) - ndtr((-h - m) / s)
        wider = held > 0.95
        lo = np.where(wider, s, lo)
        hi = np.where(wider, hi, s)
    out = 0.5 * (lo + hi)
    return np.where(np.isfinite(h) & (h > m), out, np.nan)
