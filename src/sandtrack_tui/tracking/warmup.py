"""Compile (or load from numba's cache) every kernel of kernels.py before the first tracking run:
`python -m sandtrack_tui.tracking.warmup` (make runs it once after installing)."""

from __future__ import annotations

import av
import numpy as np

from .. import yuv
from . import kernels
from .matcher import Match
from .reacquire import find_blobs
from .rest import RestReference
from .tracker import MarkerTrack


def warm_up() -> None:
    """Compile (or load) every kernel for the argument types tracking uses, on a small synthetic
    frame: run once after installing, so the first tracking run does not pay the compilation."""
    yy, xx = np.mgrid[0:96, 0:96]
    inside = ((xx - 40.3) ** 2 + (yy - 47.6) ** 2 <= 20.0).astype(np.float32)[..., None]
    frame = np.round(np.array([120.0, 160.0, 190.0]) * (1 - inside) + np.array([170.0, 70.0, 40.0]) * inside)
    frame = frame.astype(np.uint8)
    planar = yuv.wrap(av.VideoFrame.from_ndarray(frame, format="bgr24").reformat(format="yuv420p"))
    for img in (frame, planar) if planar is not None else (frame,):  # BGR arrays, and frames read in windows
        track = MarkerTrack(1, "warm-up", frame, 0, 40.3, 47.6, 12, 12)
        track.intra = np.ones(2, bool)
        track.predict()
        m = track.propose(img, 1)
        track.apply(1, img, m)
        track.matcher.update_template(img, 40.3, 47.6)
        rest = RestReference(img, 40.3, 47.6, track.model.radius, m or Match(40.3, 47.6, 1.0, 10.0, 1.0))
        rest.shift(img, 0.2, 3.0)
        find_blobs(img, track.model, 40.0, 47.0, 30.0, 30.0)
        track.model.any_in(img, np.array([[20, 27, 60, 67]], np.int64))
    kernels.median(np.zeros(3, np.float32))
    kernels.median(np.zeros(3))
    if planar is not None:
        kernels.colour_score_yuv_interpolated(*planar.yuv, 20, 27, 60, 67, *track.model._score_coeffs)


if __name__ == "__main__":
    warm_up()
