"""Frames for the tracker, decoded ahead of time in a thread, in the order they will be needed.

PyAV decodes outside the GIL, but hands every frame back to Python; while the tracker holds
the GIL that hand-over waits for the interpreter's switch interval, so `track_project` shortens
it while tracking. (A decoder in a child process with shared-memory frames was tried: starting
it and copying 6 MB frames made it slower than this on 2 cores.)

Backward order: a video can only be decoded forward from a key frame, so frame j costs decoding
from its key frame up to j. Asked for frame by frame in reverse, a reader decodes each group of
pictures again and again unless its cache holds the whole group (50 frames of 1080p BGR in the
rendered sample: 300 MB). Here the frames wanted from one group are decoded in one forward pass
and handed out in reverse; a group longer than the memory budget is done in slices from its top,
each pass starting again at the key frame.
"""

from __future__ import annotations

import queue
import threading

import numpy as np

from .luma import intra_frames

BACKWARD_BUDGET_MB = 160  # frames held per camera while a group of pictures is handed out in reverse


class ThreadPrefetch:
    def __init__(self, source, indices: list[int], depth: int = 6, budget_mb: float = BACKWARD_BUDGET_MB):
        self.q: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        keys = _key_frames(source) if len(indices) > 1 and all(
            a > b for a, b in zip(indices, indices[1:], strict=False)) else None
        if keys is None:
            self._t = threading.Thread(target=self._run, args=(source, indices), daemon=True)
        else:
            self._t = threading.Thread(target=self._run_backward, args=(source, indices, keys, budget_mb),
                                       daemon=True)
        self._t.start()

    def _run(self, source, indices):
        try:
            for j in indices:
                if self._stop.is_set():
                    return
                self._put((j, source.frame(j)))
        except BaseException as exc:  # handed to the consumer
            self._put(exc)

    def _run_backward(self, source, indices, keys, budget_mb):
        try:
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
                    img = source.frame(i)
                    if i in wanted:
                        held[i] = img
                for j in group:
                    self._put((j, held.pop(j)))
                pos += len(group)
        except BaseException as exc:  # handed to the consumer
            self._put(exc)

    def _put(self, item):
        while not self._stop.is_set():
            try:
                self.q.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def get(self):
        item = self.q.get()
        if isinstance(item, BaseException):
            raise item
        return item

    def close(self):
        self._stop.set()
        self._t.join(timeout=2)


def _key_frames(source) -> np.ndarray | None:
    """Indices of the source's key frames (a video file), or None (image folders, in-memory clips)."""
    mask = intra_frames(source)
    keys = None if mask is None else np.flatnonzero(mask)
    return keys if keys is not None and len(keys) and keys[0] == 0 else None


def prefetch(source, indices: list[int]):
    """Decode `indices` of `source` ahead of the tracker, in a thread (a descending list of a video's
    frames group by group, see the module notes)."""
    return ThreadPrefetch(source, indices)
