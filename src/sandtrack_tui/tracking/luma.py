"""Marker motion from brightness (luma), to carry the colour centre across inter-coded frames.

H.264/H.265 video codes colour (chroma) at half resolution and, in predicted frames, mostly as a
copy of the reference frame: for a marker creeping along (0.01-1 px/frame, pushed by the sand
heap) the chroma residual is quantised away and the marker's colour trails its true position by
up to ~0.4 px, building up from each intra-coded frame to the next (measured on the rendered rig:
0.12 px at intra frames, 0.45 px 20-49 frames later). Brightness is coded at full resolution and
far more finely, and does not trail. Its edge, though, is biased by shading and by the contact
shadow (0.1-0.5 px, mostly towards the shadow), but that bias changes slowly. So the tracker
measures the marker's luma centre too; at intra-coded frames it records the offset between the
colour centre and the luma centre; in the frames between, luma centre + offset tells how far the
stale colour held the centre back, and the colour centre is moved forward by that much, along the
motion since the intra frame and by at most its length (a lag can do nothing else: this keeps a
shadow sliding over the sand, which shifts the luma edge sideways, from moving the marker).

The luma centre is a circle fitted to the marker's silhouette edge: along rays from the estimate,
the strongest rise of brightness from the (darker) marker to the sand, located to sub-pixel, then
an algebraic circle fit with robust weights (rays through a shadow or a neighbour count less).
"""

from __future__ import annotations

import numpy as np

from . import kernels

N_RAYS = 32
_ANG = np.linspace(0, 2 * np.pi, N_RAYS, endpoint=False)
_COS, _SIN = np.cos(_ANG).astype(np.float32), np.sin(_ANG).astype(np.float32)
STEP = 0.25
MIN_RISE = 2.0  # luma levels per half pixel: a real edge, not noise on flat sand


def edge_centre(frame_bgr, x: float, y: float, radius: float, iterations: int = 3, settle_px: float = 0.35,
                polarity: float = 1.0, outward: bool = False):
    """Centre (x, y) of the marker's dark silhouette (polarity 1; a bright marker's: -1, the steepest
    fall of brightness outward) near (x, y) in frame coordinates, or None (edge_circle without the radius)."""
    c = edge_circle(frame_bgr, x, y, radius, iterations, settle_px, polarity, outward)
    return None if c is None else c[:2]


def edge_circle(frame_bgr, x: float, y: float, radius: float, iterations: int = 3, settle_px: float = 0.35,
                polarity: float = 1.0, outward: bool = False, known_radius: bool = False):
    """(x, y, r, quadrants): the circle of the marker's silhouette near (x, y), of about `radius`, in
    frame coordinates, and how many of the four quadrants around it hold its outline; or None.
    Along N_RAYS rays, cubic brightness profiles at `STEP` px from 0.4 to 1.7 radii; each ray's
    steepest outward rise (parabola vertex, at least MIN_RISE) is an edge point; a robust circle
    through them moves the estimate; up to `iterations` rounds, until it moves < settle_px.
    `known_radius`: the circle keeps `radius` (markers of one size touching each other), only its centre moves."""
    H, W = frame_bgr.shape[:2]
    R = int(np.ceil(1.8 * radius + 3))
    x0, y0 = int(round(x)) - R, int(round(y)) - R
    if x0 < 0 or y0 < 0 or x0 + 2 * R + 1 > W or y0 + 2 * R + 1 > H:
        return None
    args = (float(x - x0), float(y - y0), float(radius), _steps(radius), _COS, _SIN, MIN_RISE, STEP, iterations,
            settle_px, float(polarity), bool(outward), bool(known_radius))
    yuv = getattr(frame_bgr, "yuv", None)  # a frame still in its 4:2:0 planes (yuv.py)
    if yuv is not None:
        ok, cx, cy, r, quadrants = kernels.edge_centre_yuv(*yuv, x0, y0, 2 * R + 1, *args)
    else:
        ok, cx, cy, r, quadrants = kernels.edge_centre(frame_bgr[y0:y0 + 2 * R + 1, x0:x0 + 2 * R + 1], *args)
    return (cx + x0, cy + y0, r, int(quadrants)) if ok else None


_STEPS: dict = {}


def _steps(radius: float) -> np.ndarray:
    key = round(radius, 1)
    s = _STEPS.get(key)
    if s is None:
        s = np.arange(0.4 * key, 1.7 * key, STEP, dtype=np.float32)
        if len(s) < 6:
            s = np.arange(6, dtype=np.float32) * STEP + 0.4 * key
        _STEPS[key] = s
    return s


def intra_frames(source) -> np.ndarray | None:
    """Boolean mask over the source's frames: True where the video frame is intra-coded (a key
    frame). None when the source is not a video file (image folders, in-memory clips)."""
    path = getattr(source, "path", None)
    times = getattr(source, "times_s", None)
    if path is None or times is None or getattr(source, "is_folder", True):
        return None
    known = getattr(source, "keyframes", None)  # FrameSource lists them when it opens the file
    if known is not None and len(known) == len(times):
        return np.asarray(known, dtype=bool)
    import av

    try:
        with av.open(str(path)) as c:
            st = c.streams.video[0]
            tb = float(st.time_base)
            key_t = [p.pts * tb for p in c.demux(st) if p.pts is not None and p.is_keyframe]
    except (av.error.FFmpegError, OSError, ValueError, IndexError):
        return None
    times = np.asarray(times, dtype=np.float64)
    mask = np.zeros(len(times), dtype=bool)
    if key_t and len(times):
        idx = np.clip(np.searchsorted(times, np.array(key_t) - 1e-6), 0, len(times) - 1)
        near = np.abs(times[idx] - np.array(key_t)) < 0.25 / max(float(getattr(source, "fps", 50.0)), 1.0)
        mask[idx[near]] = True
    return mask
