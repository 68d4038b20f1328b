"""Frames from 4:2:0 video with their colour re-interpolated, window by window.

Camera video stores colour (chroma) at half resolution in both directions; only brightness (luma)
has full resolution. FFmpeg's YUV 4:2:0 -> BGR conversion (PyAV's `to_ndarray("bgr24")`)
replicates each chroma sample over its 2 x 2 block of pixels, so every colour edge is snapped to
the block grid. A marker is ~8 px wide and is found by its colour: the snapping moved its colour
centroid by up to ~0.5 px, depending on where the marker sat on the block grid (a fixed error per
marker while it rests, measured on the rendered rig). Here the block chroma is recovered exactly
from the decoded BGR (BGR minus its BT.601 luma is constant within a block) and interpolated
bilinearly from the sample positions, then added back to the full-resolution luma. This is done
only for the small windows the tracker reads, so nothing is converted twice.

Where a chroma sample sits within its block ("siting") depends on the camera and the encoder
(centred, left, or shifted by the encoder's own filtering); a wrong siting shifts the colour by
up to half a pixel, so it is a setting (TrackParams.chroma_siting; off by default). Centred
(0.5, 0.5) fits the rendered sample (FFmpeg/x264): mean error 0.315 -> 0.277 px there. On a clip
encoded at another size the best position was ~0.75, and centred made it worse: measure it on
the camera chain before turning it on. Estimating it from the frame (luma vs chroma edge
alignment) was tried and overshot by ~0.1 px.
"""

from __future__ import annotations

import cv2
import numpy as np

LUMA_BGR = np.array([0.114, 0.587, 0.299], np.float32)  # BT.601 luma weights, B G R
CENTRE_SITING = (0.5, 0.5)  # chroma sample (i, j) lies at pixel (2j + 0.5, 2i + 0.5)


def block_replicated(bgr: np.ndarray, size: int = 256) -> bool:
    """True when the frame's chroma is constant over even-aligned 2 x 2 blocks (decoded 4:2:0)."""
    if not isinstance(bgr, np.ndarray) or bgr.ndim != 3 or min(bgr.shape[:2]) < 8:
        return False
    H, W = bgr.shape[:2]
    h, w = min(size, H) & ~1, min(size, W) & ~1
    y0, x0 = ((H - h) // 2) & ~1, ((W - w) // 2) & ~1
    f = bgr[y0:y0 + h, x0:x0 + w].astype(np.float32)
    d = f - (f @ LUMA_BGR)[..., None]
    blocks = d.reshape(h // 2, 2, w // 2, 2, 3)
    within = float(blocks.std(axis=(1, 3)).mean())
    overall = float(d.std())
    return overall > 2.0 and within < 0.15 * overall and within < 1.5


class Chroma420Frame:
    """A decoded BGR frame; slicing `frame[y0:y1, x0:x1]` returns that window as float32 BGR with
    the chroma interpolated instead of replicated. `raw` is the frame as decoded."""

    def __init__(self, bgr: np.ndarray, siting: tuple[float, float] = CENTRE_SITING):
        self.raw = bgr
        self.shape = bgr.shape
        self.siting = siting

    ndim = 3
    dtype = np.dtype(np.float32)

    @property
    def size(self) -> int:
        return self.raw.size

    def __getitem__(self, key) -> np.ndarray:
        if not (isinstance(key, tuple) and len(key) == 2 and all(isinstance(k, slice) for k in key)):
            raise TypeError("Chroma420Frame supports frame[y0:y1, x0:x1] only")
        H, W = self.shape[:2]
        y0, y1, sy = key[0].indices(H)
        x0, x1, sx = key[1].indices(W)
        if sy != 1 or sx != 1:
            raise TypeError("Chroma420Frame supports unit steps only")
        if y1 <= y0 or x1 <= x0:
            return np.zeros((max(y1 - y0, 0), max(x1 - x0, 0), 3), np.float32)
        return reinterpolate(self.raw, x0, y0, x1, y1, self.siting)


def reinterpolate(bgr: np.ndarray, x0: int, y0: int, x1: int, y1: int,
                  siting: tuple[float, float] = CENTRE_SITING) -> np.ndarray:
    """Window [y0:y1, x0:x1] of a block-replicated BGR frame, chroma interpolated (float32 BGR)."""
    H, W = bgr.shape[:2]
    # Source blocks: even-aligned, one block of margin for the interpolation, inside the image.
    bx0, by0 = max((x0 & ~1) - 2, 0), max((y0 & ~1) - 2, 0)
    bx1, by1 = min(((x1 + 1) & ~1) + 2, W & ~1), min(((y1 + 1) & ~1) + 2, H & ~1)
    if bx1 - bx0 < 4 or by1 - by0 < 4 or x1 > bx1 or y1 > by1:
        return bgr[y0:y1, x0:x1].astype(np.float32)
    src = bgr[by0:by1, bx0:bx1].astype(np.float32)
    luma = src @ LUMA_BGR
    hb, wb = (by1 - by0) // 2, (bx1 - bx0) // 2
    blocks = cv2.resize(src - luma[..., None], (wb, hb), interpolation=cv2.INTER_AREA)  # the block chroma
    if siting == CENTRE_SITING:  # resize's own pixel-centre convention is exactly this siting
        chroma = cv2.resize(blocks, (2 * wb, 2 * hb), interpolation=cv2.INTER_LINEAR)
    else:  # sample (i, j) at pixel (bx0 + 2 j + sx, by0 + 2 i + sy)
        gx = (np.arange(2 * wb, dtype=np.float32) - siting[0]) * 0.5
        gy = (np.arange(2 * hb, dtype=np.float32) - siting[1]) * 0.5
        mx, my = np.meshgrid(gx, gy)
        chroma = cv2.remap(blocks, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = chroma + luma[..., None]
    return out[y0 - by0:y1 - by0, x0 - bx0:x1 - bx0]


def for_tracking(frame, siting: tuple[float, float] = CENTRE_SITING):
    """Wrap a decoded frame for the tracker when its chroma is block-replicated; else as is."""
    if isinstance(frame, np.ndarray) and block_replicated(frame):
        return Chroma420Frame(frame, siting)
    return frame
