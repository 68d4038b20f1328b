"""Calibration points: every board corner seen by the two cameras in every frame, with its world
position, as the training table of the pixel -> XYZ regression.

`points.csv` columns: ``frame, corner_id, xs, ys, xf, yf, X_mm, Y_mm, Z_mm``
(frame = side camera frame index; xs, ys = side pixel; xf, yf = front pixel, both as detected,
distorted; X, Y, Z = world mm). X, Y, Z come from the board's fitted rigid pose in that frame (all
cameras that see it, cameras fixed at the calibration) applied to the known corner positions of
the board, not from triangulating the two pixels: they carry no triangulation noise. A camera
named otherwise than side or front has the pixel columns ``x_NAME, y_NAME``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..board import BoardSpec
from ..camera import Calibration
from .detect import BoardView

Views = dict[str, dict[int, BoardView]]


def pixel_columns(names: list[str]) -> dict[str, tuple[str, str]]:
    from ..xyz import pixel_columns as columns_of

    return {n: columns_of(n) for n in names}


def calibration_points(calibration: Calibration, views: Views, board: BoardSpec,
                       poses: dict[int, np.ndarray], cameras: list[str] | None = None) -> pd.DataFrame:
    """Rows for every corner seen by all of `cameras` (default: the first two) in every posed frame."""
    names = cameras or calibration.names[:2]
    cols = pixel_columns(names)
    pts = board.corner_points_mm()
    out = []
    for f in sorted(poses):
        vs = [views[n].get(f) for n in names]
        if any(v is None for v in vs):
            continue
        common = vs[0].ids
        for v in vs[1:]:
            common = np.intersect1d(common, v.ids)
        if len(common) == 0:
            continue
        T = poses[f]
        xyz = calibration.to_world(pts[common] @ T[:3, :3].T + T[:3, 3])
        d = {"frame": np.full(len(common), f), "corner_id": common}
        for n, v in zip(names, vs, strict=True):
            px = v.corners[np.searchsorted(v.ids, common)]
            d[cols[n][0]], d[cols[n][1]] = px[:, 0], px[:, 1]
        d["X_mm"], d["Y_mm"], d["Z_mm"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        out.append(pd.DataFrame(d))
    if not out:
        return pd.DataFrame(columns=["frame", "corner_id", *[c for n in names for c in cols[n]],
                                     "X_mm", "Y_mm", "Z_mm"])
    return pd.concat(out, ignore_index=True)


def write_points(df: pd.DataFrame, path: str | Path) -> None:
    df.to_csv(path, index=False, float_format="%.4f")
