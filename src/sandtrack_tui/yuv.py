"""Decoded 4:2:0 video frames read as BGR images window by window, the same pixels as FFmpeg's own
conversion.

The tracker reads windows of ~20-80 px around each marker, never a whole frame. Converting every
decoded 1080p frame to BGR (FFmpeg's swscale, as `FrameSource.frame` does) costs ~0.75 ms of CPU per
frame, about as much as tracking eight markers in it. A `Yuv420Frame` keeps the decoder's planes
(no copy) and converts only the windows asked for.

Same pixels: for 8-bit 4:2:0 input, swscale's BGR24 output is, for every pixel,
B = clip(Y'[Y] + Cb[U]), G = clip(Y'[Y] + Gu[U] + Gv[V]), R = clip(Y'[Y] + Cr[V]), clip to 0..255,
with five integer tables that depend on the colour space and range (checked exhaustively, all 2^24
(Y, U, V) combinations, for the FFmpeg build PyAV ships, on x86-64). The tables are read off
swscale itself, with two small probe frames tagged like the video's frames, and then checked
against swscale on a random frame; where that check fails (another FFmpeg build, another code
path) `converter` returns None and frames are converted whole, as before.

Re-acquisition searches windows of up to 170 px for a marker's colour (a linear test on B, G, R):
`linear_mask` answers it from the planes, mostly from the chroma alone, without converting.
"""

from __future__ import annotations

import threading

import av
import numpy as np

from .jit import jit

FORMATS = ("yuv420p", "yuvj420p")  # 8-bit 4:2:0, limited or full range
_SATURATED = 4096  # table value for a chroma level that saturates every pixel (any |v| > 600 would do)


@jit
def _window_bgr(yp, up, vp, x0, y0, x1, y1, yt, cb, gu, gv, cr):
    """BGR uint8 window [y0:y1, x0:x1] of a frame given as its Y, U, V planes (4:2:0). Each row in
    three plain loops (chroma terms, brightness, pixels): ~20 % faster than one loop doing all three."""
    h, w = y1 - y0, x1 - x0
    out = np.empty((h, w, 3), np.uint8)
    c0, c1, c2, yv = np.empty(w, np.int32), np.empty(w, np.int32), np.empty(w, np.int32), np.empty(w, np.int32)
    for i in range(h):
        yy = y0 + i
        ci = yy >> 1
        for j in range(w):
            cj = (x0 + j) >> 1
            u = up[ci, cj]
            v = vp[ci, cj]
            c0[j] = cb[u]
            c1[j] = gu[u] + gv[v]
            c2[j] = cr[v]
        for j in range(w):
            yv[j] = yt[yp[yy, x0 + j]]
        for j in range(w):
            y = yv[j]
            out[i, j, 0] = min(max(y + c0[j], 0), 255)
            out[i, j, 1] = min(max(y + c1[j], 0), 255)
            out[i, j, 2] = min(max(y + c2[j], 0), 255)
    return out


@jit
def _passing_levels(yt, cb, gu, gv, cr, m0, m1, m2, m3, u, v):
    """For chroma (u, v): the brightness levels Y whose pixel passes m0 B + m1 G + m2 R + m3 >= 0
    (float32, as the window would convert), packed as state | lo << 8 | hi << 16: state 1 when they
    are the one run of levels lo..hi (empty when lo > hi), else state 2 (tested pixel by pixel)."""
    c0, c1, c2 = cb[u], gu[u] + gv[v], cr[v]
    first, last, n = -1, -1, 0
    for level in range(256):
        y = yt[level]
        b = np.float32(min(max(y + c0, 0), 255))
        g = np.float32(min(max(y + c1, 0), 255))
        r = np.float32(min(max(y + c2, 0), 255))
        if m0 * b + m1 * g + m2 * r + m3 >= 0:
            if first < 0:
                first = level
            last, n = level, n + 1
    if n == 0:
        return np.uint32(1 | 1 << 8)
    if n == last - first + 1:
        return np.uint32(1 | first << 8 | last << 16)
    return np.uint32(2)


@jit
def _linear_mask(yp, up, vp, x0, y0, x1, y1, yt, cb, gu, gv, cr, m0, m1, m2, m3, passing):
    """uint8 0/1 per pixel of the window [y0:y1, x0:x1]: m0 B + m1 G + m2 R + m3 >= 0 in float32, with
    B, G, R as the window converts; and the box of its ones in the window, (found, x0, y0, x1, y1).
    passing: per chroma u * 256 + v, its passing brightness levels (_passing_levels; 0 = not yet
    known), filled in as chroma values are met (a window holds few distinct ones): most blocks of
    2 x 2 pixels are settled by their chroma alone, most others by comparing brightness levels."""
    h, w = y1 - y0, x1 - x0
    out = np.zeros((h, w), np.uint8)
    by0, by1 = h, -1
    for ci in range(y0 >> 1, ((y1 - 1) >> 1) + 1):
        ya, yb = max(2 * ci, y0), min(2 * ci + 2, y1)
        for cj in range(x0 >> 1, ((x1 - 1) >> 1) + 1):
            u, v = up[ci, cj], vp[ci, cj]
            k = u * 256 + v
            e = passing[k]
            if e == 0:
                e = passing[k] = _passing_levels(yt, cb, gu, gv, cr, m0, m1, m2, m3, u, v)
            st, a, b = e & 255, (e >> 8) & 255, e >> 16
            if st == 1:
                if a > b:  # no brightness passes with this chroma: the block stays 0
                    continue
                if ya == 2 * ci and yb == ya + 2 and 2 * cj >= x0 and 2 * cj + 2 <= x1:  # a whole block
                    xx = 2 * cj
                    l00, l01, l10, l11 = yp[ya, xx], yp[ya, xx + 1], yp[ya + 1, xx], yp[ya + 1, xx + 1]
                    h00, h01 = a <= l00 and l00 <= b, a <= l01 and l01 <= b
                    h10, h11 = a <= l10 and l10 <= b, a <= l11 and l11 <= b
                    if h00 or h01 or h10 or h11:
                        i, j = ya - y0, xx - x0
                        out[i, j], out[i, j + 1], out[i + 1, j], out[i + 1, j + 1] = h00, h01, h10, h11
                        by0 = min(by0, i if (h00 or h01) else i + 1)
                        by1 = max(by1, i + 1 if (h10 or h11) else i)
                    continue
            for yy in range(ya, yb):
                for xx in range(max(2 * cj, x0), min(2 * cj + 2, x1)):
                    level = yp[yy, xx]
                    if st == 1:
                        hit = a <= level <= b
                    else:
                        y = yt[level]
                        bb = np.float32(min(max(y + cb[u], 0), 255))
                        g = np.float32(min(max(y + gu[u] + gv[v], 0), 255))
                        r = np.float32(min(max(y + cr[v], 0), 255))
                        hit = m0 * bb + m1 * g + m2 * r + m3 >= 0
                    if hit:
                        out[yy - y0, xx - x0] = 1
                        by0, by1 = min(by0, yy - y0), max(by1, yy - y0)
    if by1 < 0:
        return out, False, 0, 0, 0, 0
    bx0, bx1 = w, -1
    for i in range(by0, by1 + 1):
        for j in range(w):
            if out[i, j]:
                bx0 = min(bx0, j)
                bx1 = max(bx1, j)
    return out, True, bx0, by0, bx1 + 1, by1 + 1


_NONE_PASS = 1 | 1 << 8  # _passing_levels of a chroma with which no brightness passes


@jit
def _linear_any(yp, up, vp, x0, y0, x1, y1, yt, cb, gu, gv, cr, m0, m1, m2, m3, passing):
    """Does any pixel of the window [y0:y1, x0:x1] pass _linear_mask's test (its `found`, by the same
    arithmetic)? No mask is made, each 2 x 2 block is mostly settled by its chroma (one row of chroma
    at a time), and the first pixel that passes ends the search: the epipolar band's tiles, most of
    which hold nothing of the marker's colour, ~30 % faster than through _linear_mask."""
    c0, c1 = x0 >> 1, ((x1 - 1) >> 1) + 1
    for ci in range(y0 >> 1, ((y1 - 1) >> 1) + 1):
        urow, vrow = up[ci], vp[ci]
        for cj in range(c0, c1):
            u, v = urow[cj], vrow[cj]
            k = (np.int64(u) << 8) | np.int64(v)
            e = passing[k]
            if e == _NONE_PASS:
                continue
            if e == 0:
                e = passing[k] = _passing_levels(yt, cb, gu, gv, cr, m0, m1, m2, m3, u, v)
                if e == _NONE_PASS:
                    continue
            st, a, b = e & 255, (e >> 8) & 255, e >> 16
            for yy in range(max(2 * ci, y0), min(2 * ci + 2, y1)):
                for xx in range(max(2 * cj, x0), min(2 * cj + 2, x1)):
                    level = yp[yy, xx]
                    if st == 1:
                        if a <= level <= b:
                            return True
                        continue
                    y = yt[level]
                    bb = np.float32(min(max(y + cb[u], 0), 255))
                    g = np.float32(min(max(y + gu[u] + gv[v], 0), 255))
                    r = np.float32(min(max(y + cr[v], 0), 255))
                    if m0 * bb + m1 * g + m2 * r + m3 >= 0:
                        return True
    return False


@jit
def _linear_found(yp, up, vp, boxes, yt, cb, gu, gv, cr, m0, m1, m2, m3, passing):
    """_linear_any per window (x0, y0, x1, y1) of `boxes` (n x 4), in one call for many windows."""
    out = np.zeros(boxes.shape[0], np.bool_)
    for i in range(boxes.shape[0]):
        x0, y0, x1, y1 = boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3]
        if x1 > x0 and y1 > y0:
            out[i] = _linear_any(yp, up, vp, x0, y0, x1, y1, yt, cb, gu, gv, cr, m0, m1, m2, m3, passing)
    return out


def _plane(plane, rows: int) -> np.ndarray:
    """A decoded plane as a (rows, line size) uint8 array sharing the frame's memory (the array
    keeps the frame alive). The line may be padded beyond the image width; only the width is read."""
    return np.frombuffer(plane, np.uint8).reshape(rows, plane.line_size)


class Yuv420Frame:
    """A decoded 8-bit 4:2:0 frame that reads as an H x W x 3 uint8 BGR image: `frame[y0:y1, x0:x1]`
    is that window converted (a new array), `np.asarray(frame)` or `frame.bgr()` the whole image.
    `shape`, `ndim`, `dtype` are the BGR image's; `nbytes` is what the planes take."""

    ndim = 3
    dtype = np.dtype(np.uint8)

    def __init__(self, av_frame, tables: tuple):
        self._frame = av_frame
        h, w = av_frame.height, av_frame.width
        p = av_frame.planes
        self._y = _plane(p[0], h)
        self._u = _plane(p[1], (h + 1) // 2)
        self._v = _plane(p[2], (h + 1) // 2)
        self._tables = tables
        self.shape = (h, w, 3)
        # The planes and the conversion tables, for kernels that convert the windows they read
        # themselves (tracking/kernels.py, the *_yuv variants).
        self.yuv = (self._y, self._u, self._v, tables)

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1] * 3

    @property
    def nbytes(self) -> int:
        return self._y.nbytes + self._u.nbytes + self._v.nbytes

    def __getitem__(self, key) -> np.ndarray:
        if isinstance(key, tuple) and len(key) == 2 and isinstance(key[0], slice) and isinstance(key[1], slice):
            y0, y1, sy = key[0].indices(self.shape[0])
            x0, x1, sx = key[1].indices(self.shape[1])
            if sy == 1 and sx == 1:
                return _window_bgr(self._y, self._u, self._v, x0, y0, max(x1, x0), max(y1, y0), *self._tables)
        return self.bgr()[key]

    def linear_mask(self, coeffs: tuple, x0: int, y0: int, x1: int, y1: int) -> tuple:
        """(mask, found, bx0, by0, bx1, by1): uint8 0/1 per pixel of the window [y0:y1, x0:x1] where
        m0 B + m1 G + m2 R + m3 >= 0 (coeffs: float32 (m0, m1, m2, m3)), computed in float32 from the
        planes without converting the window, and the box of its ones (window coordinates)."""
        return _linear_mask(self._y, self._u, self._v, x0, y0, max(x1, x0), max(y1, y0), *self._tables, *coeffs,
                            _passing(self._tables, coeffs))

    def linear_found(self, coeffs: tuple, boxes: np.ndarray) -> np.ndarray:
        """linear_mask's `found` for each window (x0, y0, x1, y1) of `boxes` (n x 4 int64), in one call."""
        return _linear_found(self._y, self._u, self._v, boxes, *self._tables, *coeffs, _passing(self._tables, coeffs))

    def bgr(self, reformatter=None) -> np.ndarray:
        """The whole frame as BGR (FFmpeg's conversion, as FrameSource.frame gives it); `reformatter`:
        an av VideoReformatter to reuse (one per thread)."""
        if reformatter is None:
            return _swscale_bgr(self._frame)
        return reformatter.reformat(self._frame, format="bgr24", threads=1).to_ndarray()

    def __array__(self, dtype=None, copy=None):
        a = self.bgr()
        return a if dtype is None else a.astype(dtype)


def _swscale_bgr(av_frame) -> np.ndarray:
    from av.video.reformatter import VideoReformatter

    return VideoReformatter().reformat(av_frame, format="bgr24", threads=1).to_ndarray()


_TABLES: dict = {}
_PASSING: dict = {}
_MAX_PASSING = 64  # per colour test and kind of frame: 256 KB each
_LOCK = threading.Lock()


def _passing(tables: tuple, coeffs: tuple) -> np.ndarray:
    """The `passing` table of _linear_mask for one colour test on frames with these tables; kept for
    the process (a tracking run's models test the same coefficients on every frame)."""
    key = (id(tables), *(float(c) for c in coeffs))
    out = _PASSING.get(key)
    if out is None:
        out = np.zeros(65536, np.uint32)
        with _LOCK:
            if len(_PASSING) >= _MAX_PASSING:
                _PASSING.clear()
            _PASSING[key] = out
    return out


def converter(av_frame) -> tuple | None:
    """The window converter's tables for frames formatted and tagged like `av_frame` (pixel format,
    colour space, colour range), or None when its output would differ from FFmpeg's conversion or
    the format is not 8-bit 4:2:0. Found once per kind of frame in a process (~10 ms)."""
    fmt = av_frame.format.name
    if fmt not in FORMATS:
        return None
    key = (fmt, int(av_frame.colorspace), int(av_frame.color_range))
    with _LOCK:
        if key not in _TABLES:
            _TABLES[key] = _probe(*key)
        return _TABLES[key]


def wrap(av_frame) -> Yuv420Frame | None:
    """`av_frame` as a Yuv420Frame, or None when it has no exact window converter."""
    tables = converter(av_frame)
    return None if tables is None else Yuv420Frame(av_frame, tables)


# -- reading the tables off swscale ----------------------------------------------------------
def _frame(planes: tuple, fmt: str, colorspace: int, color_range: int):
    y, u, v = planes
    f = av.VideoFrame.from_ndarray(np.concatenate([y.ravel(), u.ravel(), v.ravel()]).reshape(-1, y.shape[1]),
                                   format=fmt)
    f.colorspace, f.color_range = colorspace, color_range
    return f


# The ramp probes' brightness: in block j of every block row the levels 4 j .. 4 j + 3, two per
# pixel row; _PROBE_LEVELS[r] is the level of each of the 128 pixel columns in pixel row r of a block.
_PROBE_LEVELS = np.arange(256, dtype=np.uint8).reshape(64, 2, 2).transpose(1, 0, 2).reshape(2, 128)


def _ramp_probe(chroma_rows: bool) -> tuple:
    """Planes 512 x 128: block row i has U = i (V = 128), or V = i (U = 128); the 64 blocks of a row
    hold every Y level once (_PROBE_LEVELS)."""
    y = np.tile(_PROBE_LEVELS, (256, 1))
    ramp = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 64, axis=1)
    flat = np.full((256, 64), 128, np.uint8)
    return (y, ramp, flat) if chroma_rows else (y, flat, ramp)


def _offsets(value: np.ndarray, known: np.ndarray) -> np.ndarray | None:
    """Per row c, the integer t[c] with value[c, k] == known[k] + t[c] wherever value is not clipped
    (0 or 255) and known[k] is known (not NaN); NaN where no such k; None if a row disagrees."""
    ok = (value > 0) & (value < 255) & ~np.isnan(known)[None, :]
    diff = value - np.nan_to_num(known)[None, :]
    lo, hi = np.where(ok, diff, np.inf).min(axis=1), np.where(ok, diff, -np.inf).max(axis=1)
    some = ok.any(axis=1)
    if (lo[some] != hi[some]).any():
        return None
    return np.where(some, lo, np.nan)


def _saturated(t: np.ndarray | None, value: np.ndarray) -> np.ndarray | None:
    """Rows still unknown that are clipped everywhere get -/+_SATURATED; None if any other is unknown."""
    if t is None:
        return None
    t = t.copy()
    t[np.isnan(t) & (value == 0).all(axis=1)] = -_SATURATED
    t[np.isnan(t) & (value == 255).all(axis=1)] = _SATURATED
    return None if np.isnan(t).any() else t


def _fit(bgr_u: np.ndarray, bgr_v: np.ndarray) -> tuple | None:
    """The five tables from the two ramp probes' BGR output (block row = chroma level)."""
    def by_level(bgr, ch):  # (256 chroma levels, 256 Y levels): the channel's value
        out = np.empty((256, 256), np.float64)
        for r in (0, 1):
            out[:, _PROBE_LEVELS[r]] = bgr[r::2, :, ch]
        return out

    b_u, g_u, g_v, r_v = by_level(bgr_u, 0), by_level(bgr_u, 1), by_level(bgr_v, 1), by_level(bgr_v, 2)
    # Y' and Cb together from B: anchored at Cb[128] = 0, each filling in where the other was clipped.
    yt = np.where((b_u[128] > 0) & (b_u[128] < 255), b_u[128], np.nan)
    cb = None
    for _ in range(4):
        cb = _offsets(b_u, yt)
        more = None if cb is None else _offsets(b_u.T, cb)
        if more is None:
            return None
        yt = np.where(np.isnan(yt), more, yt)
    if np.isnan(yt).any():
        return None
    cb = _saturated(cb, b_u)
    cr = _saturated(_offsets(r_v, yt), r_v)
    gu = _saturated(_offsets(g_u, yt), g_u)  # includes Gv[128]
    if cb is None or cr is None or gu is None:
        return None
    gv = _saturated(_offsets(g_v, yt + gu[128]), g_v)
    if gv is None:
        return None
    return tuple(np.ascontiguousarray(t, dtype=np.int32) for t in (yt, cb, gu, gv, cr))


def _probe(fmt: str, colorspace: int, color_range: int) -> tuple | None:
    rng = np.random.default_rng(0)
    check = (rng.integers(0, 256, (256, 512), dtype=np.uint8),
             rng.integers(0, 256, (128, 256), dtype=np.uint8), rng.integers(0, 256, (128, 256), dtype=np.uint8))
    probes = [_ramp_probe(True), _ramp_probe(False), check]
    try:
        want_all = [_swscale_bgr(_frame(p, fmt, colorspace, color_range)) for p in probes]
    except (av.error.FFmpegError, ValueError):  # a colour space swscale cannot convert (it fails on frames too)
        return None
    tables = _fit(want_all[0].astype(np.float64), want_all[1].astype(np.float64))
    if tables is None:
        return None
    for planes, want in zip(probes, want_all, strict=True):
        h, w = planes[0].shape
        got = _window_bgr(*(np.ascontiguousarray(p) for p in planes), 0, 0, w, h, *tables)
        if not np.array_equal(got, want):
            return None
    return tables
