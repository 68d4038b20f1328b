"""Frames for the tracker, decoded ahead of time in a thread, in the order they will be needed.

PyAV decodes outside the GIL, but hands every frame back to Python; while the tracker holds
the GIL that hand-over waits for the interpreter's switch interval, so `track_project` shortens
it while tracking. (A decoder in a child process with shared-memory frames was tried: starting
it and copying 6 MB frames made it slower than this on 2 cores.)

Frames are handed out as `source.lazy_frame(j)` where the source has it: the decoded planes,
converted to BGR only in the windows the tracker reads (yuv.py), not whole.

Batches: the tracker is faster than the decoder, so it would wait for every frame and resume with
its caches emptied by the decoder threads. It asks for a few frames at a time instead
(`wait_for`), and tracks them in one run: 3-5 % more frames per second on 2 cores.

Backward order: a video can only be decoded forward from a key frame, so frame j costs decoding
from its key frame up to j. Asked for frame by frame in reverse, a reader decodes each group of
pictures again and again unless its cache holds the whole group (50 frames of 1080p BGR in the
rendered sample: 300 MB). Here the frames wanted from one group are decoded in one forward pass
and handed out in reverse; a group longer than the memory budget is done in slices from its top,
each pass starting again at the key frame.
"""

from __future__ import annotations

import threading
from collections import deque

import numpy as np

from .luma import intra_frames

BACKWARD_BUDGET_MB = 160  # frames held per camera while a group of pictures is handed out in reverse
QUEUE_MB = 80  # frames decoded ahead per camera (12 of 1080p BGR), at least 4


class ThreadPrefetch:
    def __init__(self, source, indices: list[int], depth: int | None = None,
                 budget_mb: float = BACKWARD_BUDGET_MB, lazy: bool = True):
        frame_mb = 3 * getattr(source, "width", 1920) * getattr(source, "height", 1080) / 2**20
        self.depth = depth or int(min(max(QUEUE_MB // max(frame_mb, 1e-3), 4), 64))
        self._items: deque = deque()
        self._cond = threading.Condition()
        self._want = 1  # items the consumer waits for
        self._done = False
        self._stop = threading.Event()
        self._read = getattr(source, "lazy_frame", source.frame) if lazy else source.frame
        keys = _key_frames(source) if len(indices) > 1 and all(
            a > b for a, b in zip(indices, indices[1:], strict=False)) else None
        if keys is None:
            self._t = threading.Thread(target=self._produce, args=(self._run, source, indices), daemon=True)
        else:
            self._t = threading.Thread(target=self._produce,
                                       args=(self._run_backward, source, indices, keys, budget_mb), daemon=True)
        self._t.start()

    def _produce(self, run, *args):
        try:
            run(*args)
        except BaseException as exc:  # handed to the consumer
            self._put(exc)
        finally:
            with self._cond:
                self._done = True
                self._cond.notify_all()

    def _run(self, source, indices):
        for j in indices:
            if self._stop.is_set():
                return
            self._put((j, self._read(j)))

    def _run_backward(self, source, indices, keys, budget_mb):
        budget = max(1, int(budget_mb * 2**20 // (3 * source.width * source.height)))  # frames held at once
        pos = 0
        while pos < len(indices):
            top = indices[pos]
            key = int(keys[max(np.searchsorted(keys, top, side="right") - 1, 0)])
            group = [j for j in indices[pos:pos + budget] if j >= key]
            wanted = set(group)
            held = {}
            for i in range(key, top + 1):  # one forward pass from the key frame
                if self._stop.is_set():
                    return
                img = self._read(i)
                if i in wanted:
                    held[i] = img
            for j in group:
                self._put((j, held.pop(j)))
            pos += len(group)

    def _put(self, item):
        with self._cond:
            while len(self._items) >= self.depth and not self._stop.is_set():
                self._cond.wait(0.1)
            if self._stop.is_set():
                return
            self._items.append(item)
            if len(self._items) >= self._want:  # wake the consumer only when its batch is there
                self._cond.notify_all()

    def wait_for(self, n: int) -> None:
        """Block until `n` items are ready (at most the queue's depth) or no more will come."""
        with self._cond:
            self._want = min(max(n, 1), self.depth)
            while len(self._items) < self._want and not self._done:
                self._cond.wait()
            self._want = 1

    def get(self):
        """(index, frame) of the next frame, in order; re-raises the decoder's exception."""
        with self._cond:
            while not self._items:
                if self._done:
                    raise RuntimeError("the decoder stopped before the last frame")
                self._cond.wait()
            item = self._items.popleft()
            if len(self._items) == self.depth - 1:
                self._cond.notify_all()  # the decoder may be waiting for room
        if isinstance(item, BaseException):
            raise item
        return item

    def close(self):
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._t.join(timeout=2)


def _key_frames(source) -> np.ndarray | None:
    """Indices of the source's key frames (a video file), or None (image folders, in-memory clips)."""
    mask = intra_frames(source)
    keys = None if mask is None else np.flatnonzero(mask)
    return keys if keys is not None and len(keys) and keys[0] == 0 else None


def prefetch(source, indices: list[int], lazy: bool = True):
    """Decode `indices` of `source` ahead of the tracker, in a thread (a descending list of a video's
    frames group by group, see the module notes); `lazy=False` hands out BGR arrays only."""
    return ThreadPrefetch(source, indices, lazy=lazy)
