"""Frames for the tracker, decoded ahead of time in a thread, in the order they will be needed.

PyAV decodes outside the GIL, but hands every frame back to Python; while the tracker holds
the GIL that hand-over waits for the interpreter's switch interval, so `track_project` shortens
it while tracking. (A decoder in a child process with shared-memory frames was tried: starting
it and copying 6 MB frames made it slower than this on 2 cores.)
"""

from __future__ import annotations

import queue
import threading


class ThreadPrefetch:
    def __init__(self, source, indices: list[int], depth: int = 6):
        self.q: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, args=(source, indices), daemon=True)
        self._t.start()

    def _run(self, source, indices):
        try:
            for j in indices:
                if self._stop.is_set():
                    return
                self._put((j, source.frame(j)))
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


def prefetch(source, indices: list[int]):
    """Decode `indices` of `source` ahead of the tracker, in a thread."""
    return ThreadPrefetch(source, indices)
