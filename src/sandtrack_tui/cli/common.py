"""Helpers shared by the subcommands: JSON output, progress on stderr."""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np

from ..errors import NotAvailableYet


def add_json_flag(parser) -> None:
    parser.add_argument("--json", action="store_true", help="print one JSON object with the results on stdout")


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def emit(result: dict, as_json: bool, text: str | None = None) -> None:
    """Print the result: one JSON object with --json, else `text` (or key: value lines)."""
    if as_json:
        print(json.dumps(_jsonable(result)))
    elif text is not None:
        print(text)
    else:
        for k, v in _jsonable(result).items():
            print(f"{k}: {v}")


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


class Progress:
    """A throttled one-line progress bar on stderr (only when stderr is a terminal, else sparse lines)."""

    def __init__(self, total: int, label: str = "", every_s: float = 0.25):
        self.total = max(int(total), 1)
        self.label = label
        self.every_s = every_s
        self._last = 0.0
        self._tty = sys.stderr.isatty()
        self._t0 = time.perf_counter()

    def update(self, done: int, extra: str = "") -> None:
        now = time.perf_counter()
        if now - self._last < (self.every_s if self._tty else 5.0) and done < self.total:
            return
        self._last = now
        frac = min(done / self.total, 1.0)
        bar = "#" * int(frac * 30)
        line = f"{self.label} [{bar:<30}] {done}/{self.total} {extra}"
        if self._tty:
            print("\r" + line, end="", file=sys.stderr, flush=True)
        else:
            print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._tty:
            print(file=sys.stderr, flush=True)


def not_available(what: str):
    def run(args) -> int:
        raise NotAvailableYet(f"{what} is not available yet")

    return run
