"""The network checked against triangulation: where a calibration gives an independent XYZ of the same
point, a network whose error the spread cannot see (a point beyond the board's poses, where every
calibration point is silent) shows up as a disagreement between the two.

The test (`check_network`): d = XYZ_network - XYZ_triangulation, χ² = Σ d_i² / var(d_i) over the three
axes, compared with the 99 % quantile of χ² with 3 degrees of freedom (`CHI2_3_99`). Both estimates
read the same pixels, so the pixels' noise is common to them and cancels in d: var(d) per axis is the
network's sd² plus the triangulation's sd², less twice the triangulation's pixel part (its sd from the
pixels alone, the calibration's covariance left out; for an efficient estimator its covariance with any
other unbiased one is its own variance). What stays is the network's own error (its spread without the
pixel noise) and the calibration's. Points that pass (`OK`) keep the network's sd; points that fail
(`INCONSISTENT`) get, per axis, sd² = max(sd², d² + sd_triangulation²): the network's error is the
disagreement plus the triangulation's error, whose second moment that is. Where either sd is unknown
there is no test (`UNCHECKED`, the sd as it was).

What it includes: any network error larger than the two estimates' stated uncertainties allow, wherever
the triangulation holds. What it leaves out: a network error below the test's power (about 3.4 combined
sd in the worst axis: a bias that small still passes, and stays outside the network's sd), and errors the
two share (a calibration error the network learned from the same board). The residual variant is not
checked: it is the triangulation plus a learned correction, not an independent estimate.
"""

from __future__ import annotations

import numpy as np

CHI2_3_99 = 11.344866730144373  # 99 % quantile of χ² with 3 degrees of freedom
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
    bad = np.sum(d ** 2 / var_d, axis=1) > CHI2_3_99
    widened = np.sqrt(np.maximum(sd[ok] ** 2, d ** 2 + sd_tri[ok] ** 2))
    rows = np.flatnonzero(ok)
    out[rows[bad]] = widened[bad]
    verdict[rows] = np.where(bad, INCONSISTENT, OK)
    return out, verdict
