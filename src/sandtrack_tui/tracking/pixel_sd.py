"""Each tracked point's own pixel uncertainty, from the template match that placed it.

The sd (px, per image axis) of a "tracked" point grows as its match score (normalised cross-correlation
peak) falls: SD_FLOOR_PX + SD_PER_SCORE_PX · (1 − score). The two numbers were fitted (Gaussian
likelihood) to the true errors of every tracked point of the rendered sample (6,323 points, both
cameras); there ±1.96 sd held 94 % of the errors (per score sextile 91–98 %). Other statuses: a manual
or imported point has no estimate of its own (NaN: the camera's calibration RMSE stands in); an
occluded or interpolated point is a prediction, not a measurement (inf: its XYZ gets no sd).
"""

from __future__ import annotations

import numpy as np

SD_FLOOR_PX = 0.06
SD_PER_SCORE_PX = 1.9
_PREDICTED = ("occluded", "interpolated")


def point_sd_px(score, status) -> np.ndarray:
    """Per point: its sd (px) from the match score for "tracked", NaN (unknown) or inf (a prediction)."""
    score = np.asarray(score, dtype=float)
    status = np.asarray(status, dtype=object)
    sd = SD_FLOOR_PX + SD_PER_SCORE_PX * (1.0 - np.clip(score, 0.0, 1.0))
    out = np.where(status == "tracked", sd, np.nan)
    return np.where(np.isin(status, _PREDICTED), np.inf, out)
