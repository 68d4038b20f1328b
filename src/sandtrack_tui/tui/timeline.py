"""Timeline strip: every marker's status over the whole video, the first camera in the upper half of
a cell ("▀" foreground) and the second in the lower half (background), so problems show at a glance.
With one camera both halves show it; with three or more the lower half shows the worst of the others."""

from __future__ import annotations

import numpy as np
import pandas as pd
from rich.color import Color as RichColor
from rich.segment import Segment
from rich.style import Style
from textual import events
from textual.geometry import Region
from textual.message import Message
from textual.strip import Strip
from textual.widget import Widget

# Codes in increasing severity: a bucket of frames shows its most severe code.
NONE, TRACKED, MANUAL, IMPORTED, INTERPOLATED, OCCLUDED, LOST, GAP = range(8)
CODE_OF_STATUS = {"tracked": TRACKED, "manual": MANUAL, "imported": IMPORTED, "interpolated": INTERPOLATED,
                  "occluded": OCCLUDED, "lost": LOST}
CODE_RGB = {
    NONE: (38, 38, 38), TRACKED: (50, 170, 70), MANUAL: (70, 200, 235), IMPORTED: (180, 110, 230),
    INTERPOLATED: (230, 190, 40), OCCLUDED: (140, 140, 140), LOST: (235, 50, 50), GAP: (130, 20, 20),
}
PROBLEM_CODES = (OCCLUDED, LOST, GAP)
LABEL_WIDTH = 4


def status_codes(points: pd.DataFrame, marker: int | None, camera: str | None, n_frames: int,
                 side_to_camera: np.ndarray | None = None) -> np.ndarray:
    """Status code per side frame for one marker in one camera. `side_to_camera[i]` is that camera's
    frame index at side frame i (None for the side camera). Frames missing between the marker's first
    and last point are GAP. marker=None: `points` already holds only that marker and camera."""
    sel = points if marker is None else points[(points["marker"] == marker) & (points["camera"] == camera)]
    n_cam = n_frames if side_to_camera is None else int(side_to_camera.max()) + 1
    own = np.zeros(max(n_cam, int(sel["frame"].max()) + 1 if len(sel) else 0, 1), np.int8)
    if len(sel):
        frames = sel["frame"].to_numpy(int)
        ok = frames >= 0
        own[frames[ok]] = [CODE_OF_STATUS.get(s, TRACKED) for s in sel["status"].to_numpy()[ok]]
        first, last = frames[ok].min(), frames[ok].max()
        span = own[first:last + 1]
        span[span == NONE] = GAP
    if side_to_camera is None:
        out = np.zeros(n_frames, np.int8)
        out[:min(n_frames, len(own))] = own[:n_frames]
        return out
    idx = np.clip(side_to_camera, 0, len(own) - 1)
    return own[idx]


def next_problem(codes: dict, frame: int, direction: int = 1) -> int | None:
    """The next side frame after `frame` (or before, direction=-1) where any code is a problem."""
    if not codes:
        return None
    bad = np.zeros(len(next(iter(codes.values()))), bool)
    for c in codes.values():
        bad |= np.isin(c, PROBLEM_CODES)
    idx = np.flatnonzero(bad)
    if direction > 0:
        after = idx[idx > frame]
        # skip to the start of the next problem stretch rather than the next frame of the same one
        if len(after) and after[0] == frame + 1 and bad[frame]:
            starts = after[np.r_[True, np.diff(after) > 1]]
            starts = starts[starts > frame + 1]
            return int(starts[0]) if len(starts) else None
        return int(after[0]) if len(after) else None
    before = idx[idx < frame]
    return int(before[-1]) if len(before) else None


class Timeline(Widget):
    DEFAULT_CSS = """
    Timeline { height: 3; max-height: 11; border-top: solid $panel; }
    """

    class Seek(Message):
        def __init__(self, frame: int, marker: int | None) -> None:
            super().__init__()
            self.frame, self.marker = frame, marker

    def __init__(self, id: str | None = None) -> None:
        super().__init__(id=id)
        self.codes: dict[tuple[int, str], np.ndarray] = {}
        self.markers: list[tuple[int, str]] = []
        self.cameras: list[str] = ["side", "front"]
        self.n_frames = 1
        self.frame = 0
        self.selected: int | None = None
        self.range: tuple[int | None, int | None] = (None, None)
        self._styles: dict[tuple, Style] = {}
        self._rows: dict[tuple, Strip] = {}  # marker rows, by (row, width, selected)

    def set_data(self, markers: list[tuple[int, str]], codes: dict, n_frames: int, cameras: list[str]) -> None:
        self.markers, self.codes, self.n_frames, self.cameras = markers, codes, max(n_frames, 1), cameras
        self._rows.clear()
        self.styles.height = 2 + max(len(markers), 1)  # ruler + rows + top border
        self.refresh(layout=True)

    def set_position(self, frame: int, selected: int | None, rng: tuple[int | None, int | None]) -> None:
        only_ruler = selected == self.selected and rng == self.range
        self.frame, self.selected, self.range = frame, selected, rng
        if only_ruler:  # a step moves the ruler's ▼ only: the marker rows stay as they are
            self.refresh(Region(0, 0, self.content_size.width, 1))
        else:
            self.refresh()

    def on_resize(self) -> None:
        self._rows.clear()

    def _style(self, top, bot) -> Style:
        key = (top, bot)
        st = self._styles.get(key)
        if st is None:
            st = self._styles[key] = Style(color=RichColor.from_rgb(*top), bgcolor=RichColor.from_rgb(*bot))
        return st

    def _col_frames(self, width: int) -> np.ndarray:
        cols = max(width - LABEL_WIDTH, 1)
        return np.linspace(0, self.n_frames, cols + 1).astype(int)

    def render_line(self, y: int) -> Strip:
        width = self.content_size.width
        cols = max(width - LABEL_WIDTH, 1)
        edges = self._col_frames(width)
        if y == 0:
            line = [" "] * cols
            col_of = int(np.clip(np.searchsorted(edges, self.frame, side="right") - 1, 0, cols - 1))
            a, b = self.range
            for f, ch in ((a, "["), (b, "]")):
                if f is not None:
                    line[int(np.clip(np.searchsorted(edges, f, side="right") - 1, 0, cols - 1))] = ch
            end = str(self.n_frames - 1)
            if cols > len(end) + 2:
                line[cols - len(end):] = list(end)
            line[col_of] = "▼"
            head = f"{self.frame:>{LABEL_WIDTH - 1}} "[-LABEL_WIDTH:]
            return Strip([Segment(head, Style(dim=True)), Segment("".join(line), Style(color="yellow", bold=True))],
                         width)
        k = y - 1
        if k >= len(self.markers):
            if not self.markers and k == 0:
                return Strip([Segment("no markers yet: click one, or press A to auto-seed"[:width].ljust(width),
                                      Style(dim=True))], width)
            return Strip.blank(width)
        mid, label = self.markers[k]
        sel = mid == self.selected
        cached = self._rows.get((k, width, sel))
        if cached is not None:
            return cached
        segs = [Segment(f"{label[:LABEL_WIDTH - 1]:>{LABEL_WIDTH - 1}} ",
                        Style(reverse=sel, bold=sel))]
        per_cam = []
        for cam in self.cameras:
            c = self.codes.get((mid, cam))
            if c is None or not len(c):
                per_cam.append(np.zeros(cols, np.int8))
                continue
            n = len(c)
            e = np.clip(edges, 0, n)
            # max over each bucket (buckets are never empty when n >= cols; else repeat frames)
            starts = np.minimum(e[:-1], n - 1)
            vals = np.maximum.reduceat(c, starts) if n >= cols else c[starts]
            per_cam.append(vals)
        top = per_cam[0]
        bot = np.maximum.reduce(per_cam[1:]) if len(per_cam) > 1 else per_cam[0]
        keys = top.astype(np.int16) * 16 + bot
        cuts = np.flatnonzero(keys[1:] != keys[:-1]) + 1
        for a, b in zip([0, *cuts.tolist()], [*cuts.tolist(), cols], strict=True):
            segs.append(Segment("▀" * (b - a), self._style(CODE_RGB[int(top[a])], CODE_RGB[int(bot[a])])))
        strip = self._rows[(k, width, sel)] = Strip(segs, width)
        return strip

    def on_click(self, event: events.Click) -> None:
        off = event.get_content_offset(self)
        if off is None:
            return
        width = self.content_size.width
        edges = self._col_frames(width)
        col = off.x - LABEL_WIDTH
        marker = None
        if 1 <= off.y <= len(self.markers):
            marker = self.markers[off.y - 1][0]
        if col < 0:
            if marker is not None:
                self.post_message(self.Seek(self.frame, marker))
            return
        col = min(col, len(edges) - 2)
        frame = int((edges[col] + max(edges[col + 1] - 1, edges[col])) // 2)
        self.post_message(self.Seek(min(frame, self.n_frames - 1), marker))
