"""The network checked against triangulation: where a calibration gives an independent XYZ of the same
point, a network error its spread cannot see (a point beyond the board's poses, where no calibration
point shows it) appears as a disagreement between the two.

The test (`check_network`): d = XYZ_network - XYZ_triangulation, each axis's |d_i| / sd(d_i) against
`Z_CHECK`, the level at which a consistent point fails on any of its three axes with probability 1 %
(Šidák: 1 - 0.99^(1/3) per axis, two-sided; it holds whatever the correlation between the axes, which
neither sd states; a χ² over the axes with only their variances does not). Both estimates read the same
pixels, so the pixels' noise is common to them and cancels in d: var(d_i) is the network's sd² plus the
triangulation's sd², less twice the triangulation's pixel part (its sd from the pixels alone, without
the calibration's covariance; an efficient estimator's covariance with any other unbiased one is its
own variance). What stays is the network's own error (its spread without the pixel noise) and the
calibration's. A point that passes (`OK`) keeps the network's sd; one that fails (`INCONSISTENT`) gets,
per axis, sd² = max(sd², d² + sd_triangulation²): its error is the disagreement plus the triangulation's
error, and that is its second moment. Where either sd is unknown there is no test (`UNCHECKED`, the sd as
it was).

What it includes: a network error larger than the two estimates' stated uncertainties allow, wherever
the triangulation holds. What it leaves out: a network error within about 2.9 sd(d) on every axis (it
passes, and stays outside the network's sd when the spread understates it), and errors the two share
(a calibration error the network learned from the same board). The residual variant is not checked: it
is the triangulation plus a learned correction, not an independent estimate.
"""

from __future__ import annotations

import numpy as np

Z_CHECK = 2.934161015263939  # normal quantile 1 - (1 - 0.99^(1/3)) / 2: 1 % false alarms over three axes
OK, INCONSISTENT, UNCHECKED = "ok", "inconsistent", "unchecked"


def check_network(xyz: np.ndarray, sd: np.ndarray, xyz_tri: np.ndarray, sd_tri: np.ndarray,
                  sd_tri_pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The network's sd (N, 3) mm after the check and its verdict per row (OK, INCONSISTENT, UNCHECKED),
    from the network's XYZ and sd and the triangulation's XYZ, sd and sd from the pixels alone (each
    (N, 3) mm, world axes; see module docstring)."""
    xyz, sd = np.asarray(xyz, float), np.asarray(sd, float)
    xyz_tri, sd_tri, sd_pix = (np.asarray(a, float) for a in (xyz_tri, sd_tri, sd_tri_pixels))
    out = sd.copy()
    verdict = np.full(len(sd), UNCHECKED, dtype=object)
    ok = np.isfinite(np.hstack([xyz, sd, xyz_tri, sd_tri, sd_pix])).all(axis=1)
    if not ok.any():
        return out, verdict
    d = xyz[ok] - xyz_tri[ok]
    common = np.minimum(sd_pix[ok] ** 2, np.minimum(sd[ok], sd_tri[ok]) ** 2)
    var_d = sd[ok] ** 2 + sd_tri[ok] ** 2 - 2 * common
    var_d = np.maximum(var_d, 1e-12)
    bad = (d ** 2 > Z_CHECK ** 2 * var_d).any(axis=1)
    widened = np.sqrt(np.maximum(sd[ok] ** 2, d ** 2 + sd_tri[ok] ** 2))
    rows = np.flatnonzero(ok)
    out[rows[bad]] = widened[bad]
    verdict[rows] = np.where(bad, INCONSISTENT, OK)
    return out, verdict
