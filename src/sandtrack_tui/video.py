"""Frame-accurate video access.

`FrameSource` decodes a video with PyAV by presentation timestamp (pts): at open it demuxes the
stream once (no decoding) to list every frame's pts, so the frame count and per-frame times are
exact and frame ``i`` is the ``i``-th frame in presentation order, also with B-frames. Random
access seeks to the keyframe before the wanted pts and decodes forward; reading the next frame
continues the running decoder. Decoded frames sit in an LRU cache bounded in bytes. A folder of
images is accepted too (sorted by name, times = index / fps).

Frames are numpy arrays, H x W x 3, uint8, BGR (as OpenCV). Times are seconds of the file's
presentation timeline. Image folders may hold grey or colour images of 8 or 16 bits (PNG, TIFF, ...):
they are read as BGR too, grey replicated into three channels, 16-bit scaled to 8 bits by one factor
for the whole folder (255 / the top of the bit depth the images use, e.g. 4095 for 12-bit data), so
brightness means the same in every frame. `lazy_frame` gives the same frame without converting it whole: the decoded
4:2:0 planes, converted to BGR window by window when read (yuv.py), for the tracker, which reads
only small windows.

`FramePair` pairs the side and front cameras for a sync offset in seconds. Convention used
everywhere: ``offset_s`` is how much later the front camera started recording than the side
camera, so an event at side time ``t`` appears at front time ``t - offset_s``.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import av
import cv2
import numpy as np
from av.video.reformatter import VideoReformatter

from .errors import SandtrackError

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff"}
BGR_KEPT = 3  # whole-frame conversions FrameSource.frame keeps (a view stepping to and fro)
# Each video file's packet index (its frames' and key frames' timestamps, the last group of pictures decoded
# once to find frames that do not decode), by (path, size, mtime): a session opens one video many times (views,
# tracking, sync), and reading the index costs ~0.25 s at 1080p.
_INDEX: dict[tuple, tuple[np.ndarray, np.ndarray, bool]] = {}


def bit_depth_scale(images) -> float:
    """Factor taking images of more than 8 bits to 0..255: 255 / (2^bits - 1) for the smallest bit
    depth (at least 8) that holds their largest value; 1 for 8-bit images."""
    top = 0.0
    for img in images:
        if img.dtype == np.uint8:
            return 1.0
        top = max(top, float(np.max(img)) if img.size else 0.0)
    if not np.isfinite(top) or top <= 0:
        return 1.0
    if top <= 1.0:  # floating-point images in 0..1
        return 255.0
    bits = max(8, int(np.ceil(np.log2(top + 1))))
    return 255.0 / (2.0**bits - 1)


def to_bgr8(img: np.ndarray, scale: float | None = None) -> np.ndarray:
    """An image as H x W x 3 uint8 BGR: grey (H x W, or one channel) replicated into three channels,
    an alpha channel dropped, more than 8 bits scaled by `scale` (default: from its own bit depth,
    see bit_depth_scale). An 8-bit BGR image is returned as is."""
    img = np.asarray(img) if not hasattr(img, "shape") else img
    if img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8:
        return img
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(np.asarray(img, dtype=np.float32) if img.dtype.kind == "f" else img,
                                  alpha=bit_depth_scale([img]) if scale is None else scale)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 1:
        return cv2.cvtColor(img[..., 0], cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:
        return np.ascontiguousarray(img[..., :3])
    return img


def fingerprint(path: str | Path, chunk: int = 1 << 20) -> str:
    """Content fingerprint: size + SHA-1 of the first and last MiB (fast on large videos)."""
    p = Path(path)
    if p.is_dir():
        h = hashlib.sha1()
        for f in sorted(x for x in p.iterdir() if x.suffix.lower() in IMAGE_SUFFIXES):
            h.update(f.name.encode())
            h.update(str(f.stat().st_size).encode())
        return "dir:" + h.hexdigest()
    size = p.stat().st_size
    h = hashlib.sha1(str(size).encode())
    with p.open("rb") as fh:
        h.update(fh.read(chunk))
        if size > chunk:
            fh.seek(max(size - chunk, chunk))
            h.update(fh.read(chunk))
    return f"{size}:{h.hexdigest()}"


class _LRU:
    def __init__(self, max_bytes: int):
        self.max_bytes = max_bytes
        self.bytes = 0
        self.items: OrderedDict[int, np.ndarray] = OrderedDict()

    def get(self, key: int) -> np.ndarray | None:
        v = self.items.get(key)
        if v is not None:
            self.items.move_to_end(key)
        return v

    def put(self, key: int, value, replace: bool = False) -> None:
        if key in self.items:
            if not replace:
                return
            self.bytes -= self.items.pop(key).nbytes
        self.items[key] = value
        self.bytes += value.nbytes
        while self.bytes > self.max_bytes and len(self.items) > 1:
            _, old = self.items.popitem(last=False)
            self.bytes -= old.nbytes


class FrameSource:
    """Random and sequential, frame-accurate access to a video file or an image folder."""

    def __init__(self, path: str | Path, cache_mb: float = 256, fps: float | None = None):
        self.path = Path(path)
        self._lock = threading.RLock()
        self._cache = _LRU(int(cache_mb * 1024 * 1024))
        self._container = None
        self._decoder = None
        self._next_index = None  # index the running decoder will yield next
        # One BGR converter per source, one thread: a frame's own to_ndarray() builds a new scaler
        # context, with a new pool of threads, for every frame (~10 % of the decoding time).
        self._reformatter = VideoReformatter()
        self._lazy_ok = True  # False once a frame had no exact window converter (yuv.py)
        self._bgr_kept: dict[int, np.ndarray] = {}  # frame index -> BGR, most recent last
        if not self.path.exists():
            raise SandtrackError(f"file not found: {self.path}")
        if self.path.is_dir():
            self._open_folder(fps or 50.0)
        else:
            self._open_video()

    # -- opening -------------------------------------------------------------------------------
    def _open_folder(self, fps: float) -> None:
        self._files = sorted(f for f in self.path.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
        if not self._files:
            raise SandtrackError(f"{self.path}: folder holds no images ({', '.join(sorted(IMAGE_SUFFIXES))})")
        first = cv2.imread(str(self._files[0]), cv2.IMREAD_UNCHANGED)
        if first is None:
            raise SandtrackError(f"{self._files[0]}: not a readable image")
        self.height, self.width = first.shape[:2]
        # One 16-bit -> 8-bit factor for the whole folder, from the first, middle and last images.
        probe = [first] + [cv2.imread(str(self._files[k]), cv2.IMREAD_UNCHANGED)
                           for k in sorted({len(self._files) // 2, len(self._files) - 1} - {0})]
        self._scale = bit_depth_scale([p for p in probe if p is not None])
        self.fps = float(fps)
        self.times_s = np.arange(len(self._files)) / self.fps
        self._pts = None
        self.keyframes = None
        self.is_folder = True
        self.truncated = False

    def _open_video(self) -> None:
        self.is_folder = False
        self.truncated = False
        try:
            container = av.open(str(self.path))
        except (av.error.InvalidDataError, av.error.FFmpegError, OSError, ValueError) as exc:
            raise SandtrackError(f"{self.path}: not a readable video ({_short(exc)})") from None
        try:
            if not container.streams.video:
                raise SandtrackError(f"{self.path}: no video stream")
            stream = container.streams.video[0]
            self.time_base = stream.time_base
            st = Path(self.path).stat()
            key = (str(Path(self.path).resolve()), st.st_size, st.st_mtime_ns)
            if key not in _INDEX:
                if len(_INDEX) > 64:
                    _INDEX.clear()
                _INDEX[key] = self._read_index(container, stream)
            self._pts, self.keyframes, self.truncated = (v.copy() if isinstance(v, np.ndarray) else v
                                                         for v in _INDEX[key])
            self.width = stream.codec_context.width
            self.height = stream.codec_context.height
            rate = stream.average_rate or stream.guessed_rate
            if rate:
                self.fps = float(rate)
            elif len(self._pts) > 1:
                self.fps = 1.0 / float(np.median(np.diff(self._pts)) * self.time_base)
            else:
                self.fps = 50.0
            self.times_s = self._pts.astype(np.float64) * float(self.time_base)
        finally:
            container.close()
        # Verify the first frame decodes: catches files whose packets are garbage.
        self.frame(0)

    def _read_index(self, container, stream) -> tuple[np.ndarray, np.ndarray, bool]:
        """The frames' timestamps, True where a frame is a key (intra-coded) frame as the demuxer lists it, and
        whether the file is cut short. The last GOP is decoded: a truncated file lists packets that cannot
        be decoded, and only the frames before the first of those are kept."""
        pts, key_pts = [], []
        try:
            for packet in container.demux(stream):
                if packet.pts is not None and packet.size > 0:
                    pts.append(packet.pts)
                    if packet.is_keyframe:
                        key_pts.append(packet.pts)
        except (av.error.InvalidDataError, av.error.FFmpegError):
            pass  # truncated file: keep the frames before the damage
        if not pts:
            raise SandtrackError(f"{self.path}: video holds no frames")
        pts = np.array(sorted(pts), dtype=np.int64)
        last_key = max(key_pts) if key_pts else int(pts[0])
        decoded = set()
        try:
            container.seek(int(last_key), stream=stream, backward=True, any_frame=False)
            for frame in container.decode(stream):
                if frame.pts is not None:
                    decoded.add(int(frame.pts))
        except (av.error.InvalidDataError, av.error.FFmpegError, EOFError):
            pass
        missing = [p for p in pts[pts >= last_key] if int(p) not in decoded]
        truncated = bool(missing)
        if missing:
            pts = pts[pts < min(missing)]
        if len(pts) == 0:
            raise SandtrackError(f"{self.path}: no frame of the video can be decoded")
        return pts, np.isin(pts, np.array(key_pts, dtype=np.int64)), truncated

    # -- access --------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.times_s)

    @property
    def frame_count(self) -> int:
        return len(self)

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1] - self.times_s[0] + 1.0 / self.fps)

    def index_at(self, t_s: float) -> int:
        """Index of the frame whose time is nearest to ``t_s`` (clipped to the video)."""
        i = int(np.searchsorted(self.times_s, t_s))
        if i <= 0:
            return 0
        if i >= len(self.times_s):
            return len(self.times_s) - 1
        return i if self.times_s[i] - t_s < t_s - self.times_s[i - 1] else i - 1

    def __getitem__(self, i: int) -> np.ndarray:
        return self.frame(i)

    def frame(self, i: int) -> np.ndarray:
        """Frame i as a BGR array. A video with an exact window converter (yuv.py) keeps its frames in
        the cache as decoded planes whoever reads them first, so a tracking run is handed every frame in
        one form (the same kernels, the same figures, run after run) while another thread seeds from or
        shows the same frames; the last few whole-frame conversions are kept beside the cache."""
        with self._lock:
            img = self._get(i, lazy=True)
            if isinstance(img, np.ndarray):
                return img
            key = i % len(self)
            bgr = self._bgr_kept.pop(key, None)
            if bgr is None:
                bgr = img.bgr(self._reformatter)
            self._bgr_kept[key] = bgr
            while len(self._bgr_kept) > BGR_KEPT:
                self._bgr_kept.pop(next(iter(self._bgr_kept)))
            return bgr

    def lazy_frame(self, i: int):
        """Frame i for reading in windows: a `yuv.Yuv420Frame` (the decoded planes; `f[y0:y1, x0:x1]`
        is that BGR window, the same pixels as `frame(i)`) when the video is 8-bit 4:2:0 with an exact
        window converter, else the BGR array."""
        with self._lock:
            return self._get(i, lazy=True)

    def _get(self, i: int, lazy: bool):
        n = len(self)
        if i < 0:
            i += n
        if not 0 <= i < n:
            raise IndexError(f"frame {i} outside 0..{n - 1}")
        cached = self._cache.get(i)
        if cached is not None:
            return cached
        img = self._read_image(i) if self.is_folder else self._decode(i, lazy)
        self._cache.put(i, img)
        return img

    def iter_frames(self, start: int = 0, stop: int | None = None, step: int = 1):
        """Yield (index, frame) in order; sequential decoding, no seeks between frames."""
        stop = len(self) if stop is None else min(stop, len(self))
        for i in range(max(start, 0), stop, step):
            yield i, self.frame(i)

    def _read_image(self, i: int) -> np.ndarray:
        img = cv2.imread(str(self._files[i]), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise SandtrackError(f"{self._files[i]}: not a readable image")
        if img.shape[:2] != (self.height, self.width):
            raise SandtrackError(f"{self._files[i]}: size differs from the first image")
        return to_bgr8(img, self._scale)

    def _ensure_container(self):
        if self._container is None:
            self._container = av.open(str(self.path))
            stream = self._container.streams.video[0]
            stream.thread_type = "AUTO"
        return self._container

    def _frames_from_decoder(self):
        container = self._ensure_container()
        stream = container.streams.video[0]
        try:
            yield from container.decode(stream)
        except (av.error.InvalidDataError, av.error.FFmpegError, EOFError):
            return

    def _decode(self, i: int, lazy: bool = False):
        target = int(self._pts[i])
        if self._decoder is None or self._next_index is None or i < self._next_index or i > self._next_index + 60:
            self._seek(target)
        for frame in self._decoder:
            if frame.pts is None:
                continue
            img = self._wrap(frame) if lazy and self._lazy_ok else None
            if img is None:
                img = self._reformatter.reformat(frame, format="bgr24", threads=1).to_ndarray()
            k = int(np.searchsorted(self._pts, frame.pts))
            if k < len(self._pts) and self._pts[k] == frame.pts:
                self._next_index = k + 1
                if k != i:
                    self._cache.put(k, img)
            if frame.pts == target:
                return img
            if frame.pts > target:
                break
        raise SandtrackError(f"{self.path}: frame {i} could not be decoded (damaged file?)")

    def _wrap(self, frame):
        from . import yuv  # (numba: imported only when frames are read lazily)

        img = yuv.wrap(frame)
        self._lazy_ok = img is not None
        return img

    def _seek(self, target_pts: int) -> None:
        container = self._ensure_container()
        stream = container.streams.video[0]
        container.seek(int(target_pts), stream=stream, backward=True, any_frame=False)
        self._decoder = self._frames_from_decoder()
        self._next_index = 0  # unknown until the first frame comes out

    def close(self) -> None:
        with self._lock:
            if self._container is not None:
                self._container.close()
            self._container = None
            self._decoder = None
            self._next_index = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def describe(self) -> dict:
        return {
            "path": str(self.path),
            "frames": len(self),
            "fps": self.fps,
            "width": self.width,
            "height": self.height,
            "duration_s": self.duration_s,
        }


def _short(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__


@dataclass
class PairedIndex:
    side: int
    front: int
    remainder_frames: float  # (wanted front time - time of frame `front`) in front frames, in [-0.5, 0.5]


class FramePair:
    """Side and front frames paired by a sync offset (s; front started `offset_s` later)."""

    def __init__(self, side: FrameSource, front: FrameSource, offset_s: float = 0.0,
                 names: tuple[str, str] = ("side", "front")):
        self.side = side
        self.front = front
        self.offset_s = float(offset_s)
        self.names = names

    def mismatch_warnings(self) -> list[str]:
        out = []
        a, b = self.names
        if (self.side.width, self.side.height) != (self.front.width, self.front.height):
            out.append(f"resolutions differ: {a} {self.side.width}x{self.side.height}, "
                       f"{b} {self.front.width}x{self.front.height}")
        if abs(self.side.fps - self.front.fps) > 1e-3:
            out.append(f"frame rates differ: {a} {self.side.fps:g} fps, {b} {self.front.fps:g} fps")
        return out

    def front_time(self, side_index: int) -> float:
        return float(self.side.times_s[side_index]) - self.offset_s

    def index(self, side_index: int) -> PairedIndex:
        tf = self.front_time(side_index)
        j = self.front.index_at(tf)
        rem = (tf - float(self.front.times_s[j])) * self.front.fps
        return PairedIndex(side_index, j, rem)

    def side_range(self) -> tuple[int, int]:
        """[first, last] side indices whose front time lies within the front video (±half a frame)."""
        half = 0.5 / self.front.fps
        tf = self.side.times_s - self.offset_s
        ok = np.nonzero((tf >= self.front.times_s[0] - half) & (tf <= self.front.times_s[-1] + half))[0]
        if len(ok) == 0:
            raise SandtrackError("the videos do not overlap in time for this sync offset")
        return int(ok[0]), int(ok[-1])

    def __len__(self) -> int:
        return len(self.side)

    def __getitem__(self, side_index: int) -> tuple[np.ndarray, np.ndarray, PairedIndex]:
        p = self.index(side_index)
        return self.side.frame(p.side), self.front.frame(p.front), p


# -- any number of cameras --------------------------------------------------------------------
def synced_camera(cameras: list[str]) -> str | None:
    """The camera the project's one sync offset belongs to: the front camera, or with two cameras the
    second, whatever its name; None when no camera takes it (one camera, or several without a front
    camera, which are taken as started together)."""
    if "front" in cameras[1:]:
        return "front"
    return cameras[1] if len(cameras) == 2 else None


def camera_offsets(cameras: list[str], sync_offset_s: float) -> dict[str, float]:
    """How much later (s) each camera started recording than the first one (see synced_camera)."""
    synced = synced_camera(cameras)
    return {c: float(sync_offset_s) if c == synced else 0.0 for c in cameras}


def nearest_frames(ref: FrameSource, other: FrameSource, offset_s: float) -> np.ndarray:
    """Index of `other`'s frame nearest in time to each frame of `ref` (other started offset_s later)."""
    t = ref.times_s - offset_s
    if len(other.times_s) < 2:
        return np.zeros(len(t), int)
    j = np.clip(np.searchsorted(other.times_s, t), 1, len(other.times_s) - 1)
    nearer_left = (t - other.times_s[j - 1]) <= (other.times_s[j] - t)
    return np.where(nearer_left, j - 1, j).astype(int)


def common_range(sources: dict, offsets: dict[str, float], ref: str) -> tuple[int, int]:
    """[first, last] frames of camera `ref` that every other camera also recorded (±half a frame)."""
    ok = np.ones(len(sources[ref]), bool)
    for c, src in sources.items():
        if c == ref:
            continue
        half = 0.5 / src.fps
        t = sources[ref].times_s - offsets.get(c, 0.0)
        ok &= (t >= src.times_s[0] - half) & (t <= src.times_s[-1] + half)
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        raise SandtrackError("the videos do not overlap in time for this sync offset")
    return int(idx[0]), int(idx[-1])
