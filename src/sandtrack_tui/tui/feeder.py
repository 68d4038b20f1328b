"""Decoding and downscaling off the UI thread.

One background thread serves the latest request per camera (older requests are dropped, so
holding a key down never queues work), then spends idle time decoding the next frames in the
direction of travel so that stepping finds them in the FrameSource cache.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .frame_view import ViewTransform, render
from .graphics import render_graphics


@dataclass
class FrameRequest:
    camera: str
    index: int
    tf: ViewTransform
    boost: bool = True
    cell_px: tuple[int, int] | None = None  # graphics: render at the terminal's pixels, not half-blocks
    look: object | None = None  # the markers' appearance model when they are not blue (frame_view.render)
    markers: tuple = ()  # (x, y) source px of the tracked markers: what the boost paints in a dense scene

    @property
    def key(self):
        return (self.index, self.tf, self.boost, self.cell_px, self.markers, id(self.look))


@dataclass
class FrameResult:
    request: FrameRequest
    pixels: np.ndarray | None
    decode_ms: float
    render_ms: float
    error: str | None = None
    marker_share: float = 0.0  # share of the picture that looks like markers (frame_view.Rendered)
    boost_limited: bool = False  # a dense scene: the boost painted only the tracked markers


class FrameFeeder:
    def __init__(self, sources: dict, deliver: Callable[[FrameResult], None], prefetch_frames: int = 4):
        self.sources = sources
        self.deliver = deliver
        self.prefetch_frames = prefetch_frames
        self._cond = threading.Condition()
        self._pending: dict[str, FrameRequest] = {}
        self._prefetch: list[tuple[str, int]] = []
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="frame-feeder", daemon=True)
        self._thread.start()

    def request(self, req: FrameRequest, direction: int = 1) -> None:
        src = self.sources[req.camera]
        ahead = [req.index + direction * k for k in range(1, self.prefetch_frames + 1)]
        with self._cond:
            self._pending[req.camera] = req
            self._prefetch = [(c, i) for c, i in self._prefetch if c != req.camera]
            self._prefetch.extend((req.camera, i) for i in ahead if 0 <= i < len(src))
            self._cond.notify()

    def stop(self) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._stop and not self._pending and not self._prefetch:
                    self._cond.wait()
                if self._stop:
                    return
                if self._pending:
                    camera = next(iter(self._pending))
                    req = self._pending.pop(camera)
                    job = None
                else:
                    req = None
                    job = self._prefetch.pop(0)
            if req is not None:
                self._serve(req)
            else:
                # prefetching is best effort; a real request reports errors
                with contextlib.suppress(Exception):
                    self.sources[job[0]].frame(job[1])

    def _serve(self, req: FrameRequest) -> None:
        try:
            t0 = time.perf_counter()
            frame = self.sources[req.camera].frame(req.index)
            t1 = time.perf_counter()
            markers = np.array(req.markers, float).reshape(-1, 2)
            if req.cell_px is None:
                out = render(frame, req.tf, boost=req.boost, look=req.look, markers=markers)
            else:
                out = render_graphics(frame, req.tf, req.cell_px, boost=req.boost, look=req.look, markers=markers)
            t2 = time.perf_counter()
            result = FrameResult(req, out.pixels, (t1 - t0) * 1000, (t2 - t1) * 1000, None, out.marker_share,
                                 out.limited)
        except Exception as exc:  # noqa: BLE001 - shown to the user, the app keeps running
            result = FrameResult(req, None, 0.0, 0.0, f"{req.camera} frame {req.index}: {exc}")
        self.deliver(result)
