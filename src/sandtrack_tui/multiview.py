"""XYZ of every marker at one instant from any number of cameras (the live table of a project
whose cameras are not exactly a side and a front camera; `xyz.py` serves those, network included).

The instant is a frame of the first camera. Each other camera's point is taken at that time: its
continuous frame index is (t - offset) x fps (`video.camera_offsets`), and its point is
interpolated between the two frames around it when both are real observations, or taken as is
when the index is a whole frame. The markers are triangulated from every camera that has a point
(`triangulation.triangulate`: two cameras or more), with the RMS reprojection residual.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .triangulation import triangulate
from .video import camera_offsets

COLUMNS = ["marker", "X_mm", "Y_mm", "Z_mm", "residual_px", "cameras"]
_USABLE = ("tracked", "manual", "interpolated", "imported")
_EPS = 1e-6


def pixels_at_frame(project, frame: int, cameras: list[str]) -> dict[str, dict[int, tuple[float, float]]]:
    """{camera: {marker: (x, y)}} at the time of the first camera's frame `frame`."""
    vids = project.videos()
    offsets = camera_offsets(cameras, project.sync_offset_s)
    t = frame / float(vids[cameras[0]].fps or 50.0)
    out = {}
    for c in cameras:
        fps = float(vids[c].fps or 50.0)
        u = (t - offsets[c]) * fps
        j0 = int(np.floor(u + _EPS))
        w = u - j0
        pts = project.points(camera=c, frames=(j0, j0 + 1))
        pts = pts[pts["status"].isin(_USABLE) & pts["x_px"].notna() & pts["y_px"].notna()]
        at = {(int(r.marker), int(r.frame)): (float(r.x_px), float(r.y_px)) for r in pts.itertuples(index=False)}
        here = {}
        for m in {k[0] for k in at}:
            a, b = at.get((m, j0)), at.get((m, j0 + 1))
            if a is not None and abs(w) < _EPS:
                here[m] = a
            elif a is not None and b is not None:
                here[m] = ((1 - w) * a[0] + w * b[0], (1 - w) * a[1] + w * b[1])
        out[c] = here
    return out


def xyz_at_frame(project, frame: int, cameras: list[str], calibration) -> pd.DataFrame:
    """One row per marker seen by at least two calibrated cameras at that instant (COLUMNS; world mm)."""
    cams = [c for c in cameras if calibration is not None and c in calibration.cameras]
    if len(cams) < 2:
        return pd.DataFrame(columns=COLUMNS)
    px = pixels_at_frame(project, frame, cameras)
    markers = sorted(set().union(*(px[c] for c in cams)))
    if not markers:
        return pd.DataFrame(columns=COLUMNS)
    obs = {c: np.array([px[c].get(m, (np.nan, np.nan)) for m in markers], float) for c in cams}
    xyz, res = triangulate(calibration, obs, refine=True, world=True)
    seen = np.sum([np.isfinite(obs[c]).all(axis=1) for c in cams], axis=0)
    out = pd.DataFrame({"marker": markers, "X_mm": xyz[:, 0], "Y_mm": xyz[:, 1], "Z_mm": xyz[:, 2],
                        "residual_px": res, "cameras": seen})
    return out[out["cameras"] >= 2].reset_index(drop=True)
