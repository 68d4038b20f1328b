"""Board detection in images and videos: ChArUco and chessboard corners with sub-pixel accuracy.

A ChArUco board seen from behind (printed on both sides, as Caliscope's boards are) shows a mirror
image; when the plain search finds nothing, the horizontally flipped image is searched and the
corners mapped back (`mirror_search`). Blurred views are measured (variance of the Laplacian inside
the board's outline) so the calibration can skip them.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import av
import cv2
import numpy as np

from ..board import BoardSpec
from ..errors import SandtrackError
from ..video import FrameSource
from .corners import refine_corners

ProgressFn = Callable[[str, int, int], None]
LARGE_PX = 1400  # images wider than this are searched in windows first (smaller ones: whole image, cheap enough)


@dataclass
class BoardView:
    """The board's corners found in one image of one camera."""

    frame: int  # frame index of the reference (first) camera this view is paired with
    source_frame: int  # the camera's own frame index
    ids: np.ndarray  # (n,) corner ids (OpenCV ChArUco order, see BoardSpec.corner_points_mm)
    corners: np.ndarray  # (n, 2) pixels
    sharpness: float = float("nan")
    mirrored: bool = False

    def __len__(self) -> int:
        return len(self.ids)


class BoardDetector:
    """Finds one board in greyscale or BGR images. Thread-safe (one OpenCV detector per thread)."""

    def __init__(self, board: BoardSpec, mirror_search: bool = True, min_corners: int = 6, edge_refine: bool = True):
        self.board = board
        self.mirror_search = mirror_search and board.type == "charuco"
        self.edge_refine = edge_refine  # corners at the crossing of their square edges (corners.py)
        self.min_corners = max(4, min_corners)
        self._local = threading.local()
        a, _ = board.inner_corners
        self._grid = np.stack([np.arange(board.n_corners) % a, np.arange(board.n_corners) // a], axis=1)

    def _charuco(self):
        det = getattr(self._local, "det", None)
        if det is None:
            params = cv2.aruco.DetectorParameters()
            params.detectInvertedMarker = bool(self.board.inverted)
            det = cv2.aruco.CharucoDetector(self.board.cv_board(), cv2.aruco.CharucoParameters(), params)
            self._local.det = det
        return det

    def detect(self, image: np.ndarray, hint: BoardView | None = None) -> BoardView | None:
        """Find the board. In large images, `hint` (the board in a nearby frame) restricts the search to
        a window around it first, else the board is located at half size to find that window.
        Windows only save time: the corners are always refined on full-resolution pixels."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        view = self._find(gray, hint)
        if view is not None and self.edge_refine:
            view.corners = refine_corners(gray, self._grid[view.ids], view.corners, self._edge_margin())
        return view

    def _edge_margin(self) -> float:
        """Free band along each square edge, in squares: up to the ArUco markers, or half a square."""
        if self.board.type != "charuco":
            return 0.5
        return 0.5 * (self.board.square_mm - self.board.marker_size_mm) / self.board.square_mm

    def _find(self, gray: np.ndarray, hint: BoardView | None) -> BoardView | None:
        near = None
        large = max(gray.shape) > LARGE_PX
        self._local.hint_hit = not large  # small images: only the hint's side (plain/mirrored) is used
        if hint is not None and len(hint) and large:
            box = _box(hint.corners, gray.shape, grow=0.6)
            near = self._detect_in(gray, box, hint.mirrored)
            # keep the window's answer unless the board may reach past the window: a corner within
            # about a square of its edge (the markers there may have been cut off)
            self._local.hint_hit = near is not None and self._whole_board_in(near, box, gray.shape)
            if self._local.hint_hit:
                return near
        found = None
        if self.board.type == "charuco" and large:
            located = self._locate(gray)
            if located is not None:
                box, mirrored = located
                found = self._detect_in(gray, box, mirrored)
                if found is not None and not self._whole_board_in(found, box, gray.shape):
                    found = None  # the window may have cut part of the board off
        if found is None or (near is not None and len(found) < len(near)):
            # a camera that saw the board from behind most likely still does: try that side first
            found = self._detect_full(gray, prefer_mirrored=bool(hint is not None and hint.mirrored))
        if near is not None and (found is None or len(near) > len(found)):
            return near
        return found

    def _whole_board_in(self, view: BoardView, box, shape, margin: float = 10.0) -> bool:
        """True when the whole board, extrapolated from the corners found through the board-to-image
        homography, lies inside the window (sides on the image edge excepted): then the window cannot
        have cut anything off."""
        obj = self.board.corner_points_mm()[view.ids, :2]
        try:
            H, _ = cv2.findHomography(obj, view.corners)
        except cv2.error:
            H = None
        if H is None:
            return False
        g = self._grid[view.ids]
        if len(np.unique(g[:, 0])) < 3 or len(np.unique(g[:, 1])) < 3:
            return False  # a strip of corners: too little to extrapolate the board from
        w, h = self.board.size_mm
        outline = cv2.perspectiveTransform(np.array([[[0, 0], [w, 0], [w, h], [0, h]]], np.float64), H)[0]
        if not np.isfinite(outline).all():
            return False
        outline = np.clip(outline, 0, [shape[1] - 1, shape[0] - 1])
        return not _touches(outline, box, margin, shape)

    def hint_hit(self) -> bool:
        """Whether this thread's last search with a hint was settled inside the hint's window (always
        true for small images, which are searched whole)."""
        return bool(getattr(self._local, "hint_hit", False))

    def _detect_in(self, gray: np.ndarray, box, mirrored: bool | None = None) -> BoardView | None:
        x0, y0, x1, y1 = box
        view = self._detect_full(np.ascontiguousarray(gray[y0:y1, x0:x1]), mirrored)
        if view is None:
            return None
        view.corners = view.corners + [x0, y0]
        return view

    def _locate(self, gray: np.ndarray):
        """(bounding box (x0, y0, x1, y1), mirrored) of the ArUco markers found at half size, or None."""
        small = cv2.resize(gray, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        det = getattr(self._local, "aruco", None)
        if det is None:
            params = cv2.aruco.DetectorParameters()
            params.detectInvertedMarker = bool(self.board.inverted)
            det = self._local.aruco = cv2.aruco.ArucoDetector(self.board.aruco_dictionary(), params)
        for img, flip in ((small, False), (np.ascontiguousarray(small[:, ::-1]), True)):
            corners, ids, _ = det.detectMarkers(img)
            if ids is not None and len(ids):
                c = np.concatenate([m.reshape(-1, 2) for m in corners]) * 2.0
                if flip:
                    c[:, 0] = gray.shape[1] - 1 - c[:, 0]
                return _box(c, gray.shape, grow=0.5), flip
            if not self.mirror_search:
                break
        return None

    def _detect_full(self, gray: np.ndarray, mirrored: bool | None = None,
                     prefer_mirrored: bool = False) -> BoardView | None:
        """mirrored: True/False = search that side only; None = both (mirror search), the side given by
        `prefer_mirrored` first."""
        found = None
        if self.board.type == "chessboard":
            found, mirrored = self._detect_chessboard(gray), False
        else:
            sides = [mirrored] if mirrored is not None else [prefer_mirrored, not prefer_mirrored]
            for side in sides:
                if side and not self.mirror_search:
                    continue
                found = self._detect_charuco(np.ascontiguousarray(gray[:, ::-1]) if side else gray)
                if found is not None:
                    if side:
                        found[1][:, 0] = gray.shape[1] - 1 - found[1][:, 0]
                    mirrored = side
                    break
        if found is None:
            return None
        ids, corners = found
        if len(ids) < self.min_corners or not self._spans_plane(ids):
            return None
        return BoardView(frame=-1, source_frame=-1, ids=ids, corners=corners,
                         sharpness=_sharpness(gray, corners), mirrored=mirrored)

    def _detect_charuco(self, gray: np.ndarray):
        cc, ci, _, _ = self._charuco().detectBoard(gray)
        if ci is None or len(ci) == 0:
            return None
        ids = ci.ravel().astype(np.int32)
        order = np.argsort(ids)
        return ids[order], cc.reshape(-1, 2).astype(np.float64)[order]

    def _detect_chessboard(self, gray: np.ndarray):
        g = 255 - gray if self.board.inverted else gray
        size = self.board.inner_corners
        # Cheap check at reduced size first; the sector-based detector is slow on empty frames.
        scale = min(1.0, 960.0 / max(g.shape))
        small = cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) if scale < 1 else g
        ok, _ = cv2.findChessboardCorners(small, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_FAST_CHECK
                                          | cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not ok:
            return None
        ok, corners = cv2.findChessboardCornersSB(g, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_ACCURACY)
        if not ok:
            return None
        return np.arange(self.board.n_corners, dtype=np.int32), corners.reshape(-1, 2).astype(np.float64)

    def _spans_plane(self, ids: np.ndarray) -> bool:
        """Corners all on one row/column/diagonal give no pose: reject them."""
        g = self._grid[ids].astype(float)
        g -= g.mean(0)
        return np.linalg.matrix_rank(g, tol=1e-6) >= 2


def _box(points: np.ndarray, shape, grow: float = 0.5):
    """Integer window around points, enlarged by `grow` times its size on each side (at least 80 px)."""
    lo, hi = points.min(0), points.max(0)
    pad = np.maximum(grow * (hi - lo), 80.0)
    x0, y0 = np.maximum(np.floor(lo - pad), 0).astype(int)
    x1 = int(min(np.ceil(hi[0] + pad[0]), shape[1]))
    y1 = int(min(np.ceil(hi[1] + pad[1]), shape[0]))
    return x0, y0, x1, y1


def _touches(points: np.ndarray, box, margin: float, shape) -> bool:
    """True when points come within `margin` px of a window edge that is not the image edge."""
    x0, y0, x1, y1 = box
    lo, hi = points.min(0), points.max(0)
    return bool((x0 > 0 and lo[0] - x0 < margin) or (y0 > 0 and lo[1] - y0 < margin)
                or (x1 < shape[1] and hi[0] > x1 - margin) or (y1 < shape[0] and hi[1] > y1 - margin))


def _sharpness(gray: np.ndarray, corners: np.ndarray) -> float:
    x0, y0 = np.floor(corners.min(0)).astype(int)
    x1, y1 = np.ceil(corners.max(0)).astype(int) + 1
    roi = gray[max(y0, 0):max(y1, 1), max(x0, 0):max(x1, 1)]
    if roi.size < 25:
        return 0.0
    return float(cv2.Laplacian(roi, cv2.CV_32F).var())


def open_source(path: str | Path) -> FrameSource:
    p = Path(path)
    if not p.exists():
        raise SandtrackError(f"video or image folder not found: {p}")
    return FrameSource(p, cache_mb=64)


def frame_pairing(sources: dict[str, FrameSource], offsets_s: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """For every frame of the reference (first) camera, the matching position of each camera on its
    own frame axis, as a fractional frame index (NaN outside that camera's video). offsets_s[name] =
    how much later that camera started recording than the reference camera (the project's sync
    convention)."""
    names = list(sources)
    ref = sources[names[0]]
    t = np.asarray(ref.times_s, dtype=float) - float(ref.times_s[0])
    out = {names[0]: np.arange(len(ref), dtype=float)}
    for n in names[1:]:
        s = sources[n]
        ts = np.asarray(s.times_s, dtype=float) - float(s.times_s[0])
        target = t - float((offsets_s or {}).get(n, 0.0))
        pos = np.interp(target, ts, np.arange(len(ts), dtype=float))
        half = 0.5 / max(s.fps, 1e-6)
        pos[(target < ts[0] - half) | (target > ts[-1] + half)] = np.nan
        out[n] = pos
    return out


SUBFRAME = 0.1  # a camera more than this fraction of a frame off the reference instant is interpolated


# FFmpeg's grey from limited-range YUV: luma stretched from 16..235 to 0..255 (full-range YUV: luma as is)
_LIMITED_TO_FULL = np.clip(np.round((np.arange(256) - 16) * 255 / 219), 0, 255).astype(np.uint8)
_PLANAR_LUMA = {"yuv420p", "yuv422p", "yuv444p", "nv12", "yuvj420p", "yuvj422p", "yuvj444p"}


def _luma(frame) -> np.ndarray | None:
    """Grey image of an 8-bit YUV frame straight from its luma plane (about a third cheaper than a
    swscale conversion), or None for other pixel formats."""
    name = frame.format.name
    if name not in _PLANAR_LUMA:
        return None
    plane = frame.planes[0]
    y = np.frombuffer(plane, np.uint8).reshape(-1, plane.line_size)[:frame.height, :frame.width]
    return np.ascontiguousarray(y) if name.startswith("yuvj") else cv2.LUT(y, _LIMITED_TO_FULL)


def _gray_frames(source: FrameSource, wanted: Sequence[int]):
    """Yield (index, grey image) for the wanted frame indices (ascending), decoding sequentially
    and converting only the frames that are wanted."""
    wanted = sorted(set(int(i) for i in wanted))
    if not wanted:
        return
    if source.is_folder:
        for i in wanted:
            yield i, cv2.cvtColor(source.frame(i), cv2.COLOR_BGR2GRAY)
        return
    times = np.asarray(source.times_s, dtype=float)
    fast: bool | None = None
    want = set(wanted)
    last = wanted[-1]
    with av.open(str(source.path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        tb = float(stream.time_base)
        first_t = times[wanted[0]]
        if wanted[0] > 0:
            container.seek(int(first_t / tb), stream=stream, backward=True, any_frame=False)
        try:
            for frame in container.decode(stream):
                if frame.pts is None:
                    continue
                k = int(np.searchsorted(times, frame.pts * tb - 1e-9))
                if k >= len(times) or abs(times[k] - frame.pts * tb) > 1e-6:
                    continue
                if k in want:
                    if fast is None:  # first frame: use the luma plane only if it gives FFmpeg's grey exactly
                        grey = frame.to_ndarray(format="gray")
                        luma = _luma(frame)
                        fast = luma is not None and np.array_equal(luma, grey)
                        yield k, grey
                    else:
                        yield k, _luma(frame) if fast else frame.to_ndarray(format="gray")
                if k >= last:
                    break
        except (av.error.InvalidDataError, av.error.FFmpegError, EOFError):
            return


def detect_in_sources(sources: dict[str, FrameSource], board: BoardSpec, ref_frames: Sequence[int],
                      pairing: dict[str, np.ndarray], progress: ProgressFn | None = None,
                      mirror_search: bool = True, workers: int = 2,
                      max_gap: int = 10) -> dict[str, dict[int, BoardView]]:
    """Detect the board in the given reference-camera frames of every camera (one thread per camera),
    searching first near where it was up to `max_gap` frames before.
    Returns {camera: {reference frame: BoardView}}."""
    detector = BoardDetector(board, mirror_search=mirror_search)
    names = list(sources)
    ref_frames = sorted(set(int(f) for f in ref_frames))
    done = [0]
    lock = threading.Lock()

    def plan(name: str) -> dict[int, list[tuple[int, int, float]]]:
        # each reference frame needs one own frame, or two around it when the instant falls between
        pos = pairing[name][ref_frames]
        need: dict[int, list[tuple[int, int, float]]] = {}
        for f, p in zip(ref_frames, pos, strict=True):
            if not np.isfinite(p):
                continue
            j0 = int(np.floor(p))
            a = p - j0
            last_index = len(sources[name]) - 1
            if a <= SUBFRAME or j0 >= last_index:
                need.setdefault(min(j0, last_index), []).append((f, -1, 0.0))
            elif a >= 1 - SUBFRAME:
                need.setdefault(j0 + 1, []).append((f, -1, 0.0))
            else:
                need.setdefault(j0, []).append((f, j0 + 1, a))
                need.setdefault(j0 + 1, [])
        return need

    needs = {n: plan(n) for n in names}
    total = [sum(len(v) for v in needs.values())]

    def run(name: str) -> dict[int, BoardView]:
        need = needs[name]
        found: dict[int, BoardView] = {}
        last: tuple[int, BoardView] | None = None
        skip_hints = 0  # after a hint missed (the board jumped), search a few frames without one
        for j, gray in _gray_frames(sources[name], list(need)):
            hint = last[1] if last is not None and j - last[0] <= max_gap and skip_hints == 0 else None
            skip_hints = max(0, skip_hints - 1)
            view = detector.detect(gray, hint)
            if hint is not None and not detector.hint_hit():
                skip_hints = 3
            if view is not None:
                last = (j, view)
                found[j] = view
            with lock:
                done[0] += 1
                if progress is not None:
                    progress("detect", done[0], total[0])
        views: dict[int, BoardView] = {}
        for j, wants in need.items():
            for f, j1, a in wants:
                v0 = found.get(j)
                if v0 is None:
                    continue
                if j1 < 0:
                    views[f] = BoardView(frame=f, source_frame=j, ids=v0.ids, corners=v0.corners,
                                         sharpness=v0.sharpness, mirrored=v0.mirrored)
                    continue
                v1 = found.get(j1)
                if v1 is None:
                    continue
                common, i0, i1 = np.intersect1d(v0.ids, v1.ids, return_indices=True)
                if len(common) < detector.min_corners:
                    continue
                # linear motion between the two frames around the reference instant
                corners = (1 - a) * v0.corners[i0] + a * v1.corners[i1]
                views[f] = BoardView(frame=f, source_frame=j if a < 0.5 else j1, ids=common, corners=corners,
                                     sharpness=min(v0.sharpness, v1.sharpness), mirrored=v0.mirrored)
        return views

    with ThreadPoolExecutor(max_workers=max(1, min(workers, len(names)))) as pool:
        results = list(pool.map(run, names))
    return dict(zip(names, results, strict=True))


def detection_stride(n_frames: int, budget: int) -> int:
    return max(1, math.ceil(n_frames / max(budget, 1)))
