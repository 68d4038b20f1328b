"""The network checked against triangulation: where a calibration gives an independent XYZ of the same
point, the network's error is measured point by point (a network error its spread cannot see, at a point
beyond the board's poses where no calibration point shows it, appears as a disagreement between the two),
and the network's sd says what both sources of evidence together say about it.

The model, per world axis: the network's error is a + p and the triangulation's b + p, where p is the
pixels' noise (both read the same pixels, so it is common to them; variance C, the triangulation's sd from
the pixels alone), a the network's own error (its spread without the pixel noise: variance A = sd² - C)
and b the calibration's (B = sd_triangulation² - C). The disagreement d = XYZ_network - XYZ_triangulation
= a - b does not hold p.

The test (`OK` / `INCONSISTENT`): each axis's |d| / sqrt(A + B) against `Z_CHECK`, the level at which a
consistent point fails on any of its three axes with probability 1 % (Šidák: 1 - 0.99^(1/3) per axis,
two-sided; it holds whatever the correlation between the axes, which neither sd states).

The sd: given d, the network's error is Gaussian with mean m = d A / (A + B) and variance
v = A B / (A + B) + C (the spread as the prior of a, the triangulation as a measurement of it). A point
that fails the test has shown its spread wrong: no prior, m = d and v = B + C (the disagreement plus the
triangulation's error); so has a point without a spread (outside the training volume, or a model file
without one): verdict `UNCHECKED`, sd from the disagreement alone. The reported sd is the half-width of the
interval around the network's XYZ that holds the error with 95 % probability, divided by 1.96, so that
±1.96 sd is that interval (with m = 0 it is sqrt(v); it grows to |m| + 1.645 sqrt(v) as |m| grows). m is
kept beside it (the bias columns): such an error is not centred, so a χ² over many points (`compare`) takes
the Gaussian N(m, v) back (`interval.gaussian_sd`) instead of reading the sd as a centred one.

What it includes: the network's error as far as the triangulation measures it, wherever the triangulation
holds. What it leaves out: errors the two share (a calibration error the network learned from the same
board), correlations between the axes, and the triangulation's own misstatements (where its sd is too
large, as on the very points that calibrated it, so is this one). The residual variant is not checked: it
is the triangulation plus a learned correction, not an independent estimate.
"""

from __future__ import annotations

import numpy as np

from ..interval import interval_sd

Z_CHECK = 2.934161015263939  # normal quantile 1 - (1 - 0.99^(1/3)) / 2: 1 % false alarms over three axes
OK, INCONSISTENT, UNCHECKED = "ok", "inconsistent", "unchecked"


def check_network(xyz: np.ndarray, sd: np.ndarray, xyz_tri: np.ndarray, sd_tri: np.ndarray,
                  sd_tri_pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The network's sd (N, 3) mm after the check, its verdict per row (OK, INCONSISTENT, UNCHECKED) and its
    error's estimated mean m (N, 3) mm (the bias: XYZ - m is the best estimate; NaN without a triangulation),
    from the network's XYZ and sd (NaN: no spread) and the triangulation's XYZ, sd and sd from the pixels
    alone (each (N, 3) mm, world axes; see module docstring). Rows without a triangulation keep their sd."""
    xyz, sd = np.asarray(xyz, float), np.asarray(sd, float)
    xyz_tri, sd_tri, sd_pix = (np.asarray(a, float) for a in (xyz_tri, sd_tri, sd_tri_pixels))
    out = sd.copy()
    verdict = np.full(len(sd), UNCHECKED, dtype=object)
    bias = np.full(sd.shape, np.nan)
    rows = np.isfinite(np.hstack([xyz, xyz_tri, sd_tri, sd_pix])).all(axis=1)
    if not rows.any():
        return out, verdict, bias
    d, s, st = xyz[rows] - xyz_tri[rows], sd[rows], sd_tri[rows]
    prior = np.isfinite(s).all(axis=1)
    common = np.minimum(sd_pix[rows] ** 2, np.fmin(s, st) ** 2)
    a = np.where(prior[:, None], np.maximum(np.nan_to_num(s) ** 2 - common, 0.0), 0.0)
    b = np.maximum(st ** 2 - common, 0.0)
    total = np.maximum(a + b, 1e-12)
    bad = prior & (d ** 2 > Z_CHECK ** 2 * total).any(axis=1)
    trusted = (prior & ~bad)[:, None]  # the spread holds as the prior of the network's own error
    mean = np.where(trusted, a / total, 1.0) * d
    var = np.where(trusted, a * b / total, b) + common
    out[rows] = interval_sd(mean, np.sqrt(var))
    bias[rows] = mean
    verdict[np.flatnonzero(rows)[prior]] = np.where(bad[prior], INCONSISTENT, OK)
    return out, verdict, bias
