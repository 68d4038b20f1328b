"""MP4 writer: H.264 video (libx264, fixed thread count: deterministic) plus AAC mono audio (PyAV).

Frames are converted and encoded on a background thread (PyAV releases the GIL while encoding), so
encoding overlaps the rendering of the next frames; the encoder sees the same frames in the same order.
"""

from __future__ import annotations

import queue
import threading
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

AUDIO_RATE = 48000


class Mp4Writer:
    """Write BGR frames at a fixed rate (pts 0, 1, 2, ... in 1/fps) and one mono audio track.

    `audio` is float32 in [-1, 1]; `audio_start_s` is the presentation time of its first sample.
    """

    def __init__(self, path: str | Path, width: int, height: int, fps: float, audio: np.ndarray,
                 audio_start_s: float = 0.0, crf: int = 26, preset: str = "veryfast", keyint: int = 50):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.container = av.open(str(self.path), "w", format="mp4")
        self.container.metadata["comment"] = "sandtrack sample: rendered twin of the sand-box rig"
        rate = Fraction(fps).limit_denominator(1001)
        vs = self.container.add_stream("libx264", rate=rate)
        vs.width, vs.height = width, height
        vs.pix_fmt = "yuv420p"
        vs.codec_context.time_base = 1 / rate
        vs.options = {
            "crf": str(crf),
            "preset": preset,
            "threads": "1",
            "x264-params": f"keyint={keyint}:min-keyint={keyint}:scenecut=0:bframes=2",
        }
        self.video = vs
        aus = self.container.add_stream("aac", rate=AUDIO_RATE, layout="mono")
        aus.options = {"b": "96k"}
        self.audio_stream = aus
        self.n = 0
        self._write_audio(np.asarray(audio, np.float32), int(round(audio_start_s * AUDIO_RATE)))
        self._queue: queue.Queue = queue.Queue(maxsize=4)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._encode_loop, name="mp4-encode", daemon=True)
        self._thread.start()

    def _write_audio(self, audio: np.ndarray, start: int) -> None:
        block = 1024
        for k in range(0, len(audio), block):
            chunk = np.ascontiguousarray(audio[None, k : k + block])
            frame = av.AudioFrame.from_ndarray(chunk, format="fltp", layout="mono")
            frame.sample_rate = AUDIO_RATE
            frame.pts = start + k
            frame.time_base = Fraction(1, AUDIO_RATE)
            for p in self.audio_stream.encode(frame):
                self.container.mux(p)
        for p in self.audio_stream.encode(None):
            self.container.mux(p)

    def write(self, bgr: np.ndarray) -> None:
        """Queue one frame (the array must not be changed afterwards)."""
        if self._error is not None:
            raise self._error
        self._queue.put(bgr)

    def _encode_loop(self) -> None:
        while (bgr := self._queue.get()) is not None:
            if self._error is not None:
                continue  # keep draining so that write() never blocks
            try:
                # wraps the array without copying it (the encoder converts it to YUV at once)
                frame = av.VideoFrame.from_numpy_buffer(np.ascontiguousarray(bgr), format="bgr24")
                frame.pts = self.n
                frame.time_base = self.video.codec_context.time_base
                self.n += 1
                for p in self.video.encode(frame):
                    self.container.mux(p)
            except BaseException as exc:  # noqa: BLE001 - re-raised in the writing thread
                self._error = exc

    def close(self) -> None:
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        try:
            if self._error is not None:
                raise self._error
            for p in self.video.encode(None):
                self.container.mux(p)
        finally:
            self.container.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
