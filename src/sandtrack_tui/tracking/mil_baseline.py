"""OpenCV's TrackerMIL on the same markers, for the benchmark comparison.

TrackerMIL is the one OpenCV 5 tracker that runs without downloaded model files. It reports a
box per frame (and a success flag); the marker centre is taken as the box centre.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pandas as pd


def track_mil(source, seed_frame: int, x: float, y: float, w: float, h: float, stop: int) -> pd.DataFrame:
    """Track one marker from `seed_frame` (centre x, y; box w x h) to `stop` (inclusive) with TrackerMIL.

    Returns DataFrame[frame, x_px, y_px, ok, ms] (ms = update time, decoding excluded)."""
    tracker = cv2.TrackerMIL.create()
    w, h = int(round(w)), int(round(h))
    tracker.init(source.frame(seed_frame), (int(round(x - (w - 1) / 2)), int(round(y - (h - 1) / 2)), w, h))
    rows = [(seed_frame, x, y, True, 0.0)]
    for f in range(seed_frame + 1, stop + 1):
        img = source.frame(f)
        t0 = time.perf_counter()
        ok, box = tracker.update(img)
        ms = (time.perf_counter() - t0) * 1000
        bx, by, bw, bh = box
        rows.append((f, bx + bw / 2 - 0.5, by + bh / 2 - 0.5, bool(ok), ms) if ok else (f, np.nan, np.nan, False, ms))
    return pd.DataFrame(rows, columns=["frame", "x_px", "y_px", "ok", "ms"])


def track_mil_many(source, seeds: pd.DataFrame, stop: int) -> pd.DataFrame:
    """All seeds (marker, frame, x, y, w, h) of one camera, frame by frame (each frame decoded once)."""
    trackers = {}
    first = int(seeds.frame.min())
    img0 = {}
    rows = []
    for r in seeds.itertuples():
        img = img0.setdefault(int(r.frame), source.frame(int(r.frame)))
        t = cv2.TrackerMIL.create()
        w, h = int(round(r.w)), int(round(r.h))
        t.init(img, (int(round(r.x - (w - 1) / 2)), int(round(r.y - (h - 1) / 2)), w, h))
        trackers[int(r.marker)] = (t, int(r.frame))
        rows.append((int(r.frame), int(r.marker), r.x, r.y, True, 0.0))
    for f in range(first + 1, stop + 1):
        img = source.frame(f)
        for m, (t, f0) in trackers.items():
            if f <= f0:
                continue
            t0 = time.perf_counter()
            ok, (bx, by, bw, bh) = t.update(img)
            ms = (time.perf_counter() - t0) * 1000
            if ok:
                rows.append((f, m, bx + bw / 2 - 0.5, by + bh / 2 - 0.5, True, ms))
            else:
                rows.append((f, m, np.nan, np.nan, False, ms))
    return pd.DataFrame(rows, columns=["frame", "marker", "x_px", "y_px", "ok", "ms"])
