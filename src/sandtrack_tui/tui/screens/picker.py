"""The marker list: every marker, nearest to the cursor first, for picking one out of a crowd;
rename and merge from here too."""

from __future__ import annotations

import math
from dataclasses import dataclass

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import DataTable, Input, Label

from ..frame_view import STATUS_RGB
from ..table import SHORT


@dataclass
class PickerRow:
    marker: int
    label: str
    status: dict[str, str]  # per camera, at this frame ("" = no point)
    distance_px: float  # from the cursor in the active view (inf: no point there)
    problem_frames: int  # lost, occluded or gap, over the whole video and every camera


class MarkerPicker(ModalScreen[int | None]):
    DEFAULT_CSS = """
    MarkerPicker { align: center middle; }
    MarkerPicker > Vertical { width: 90%; max-width: 110; height: auto; max-height: 85%; border: round $accent;
                              background: $surface; padding: 0 1; }
    MarkerPicker Label { width: 100%; }
    MarkerPicker DataTable { height: auto; max-height: 30; }
    MarkerPicker Input { display: none; }
    MarkerPicker Input.-shown { display: block; }
    """
    BINDINGS = [Binding("enter", "pick", "select"), Binding("r", "rename", "rename"),
                Binding("M", "merge", "merge into…"), Binding("slash", "filter", "filter"),
                Binding("escape", "close", "close")]

    def __init__(self, app, rows: list[PickerRow], cameras: list[str], active: str):
        super().__init__()
        self.main, self.rows, self.cameras, self.active = app, rows, cameras, active
        self.shown: list[PickerRow] = rows

    def compose(self) -> ComposeResult:
        with Vertical():
            yield Label(f"[b]Markers[/] nearest the cursor in {self.active} first. enter: select, r: rename, "
                        "M: merge into…, /: filter, esc: close")
            yield Input(placeholder="id or name", id="filter")
            yield DataTable(id="markers", cursor_type="row")

    def on_mount(self) -> None:
        t = self.query_one(DataTable)
        t.add_column("id", key="id", width=5)
        t.add_column("name", key="name", width=16)
        for cam in self.cameras:
            t.add_column(cam[:8], key=f"st-{cam}", width=max(len(cam[:8]), 4))
        t.add_column("px away", key="dist", width=8)
        t.add_column("problem frames", key="problems", width=14)
        self._fill()
        t.focus()

    def _fill(self) -> None:
        t = self.query_one(DataTable)
        t.clear()
        for r in self.shown:
            cells = [str(r.marker), Text(r.label, style="bold")]
            for cam in self.cameras:
                s = r.status.get(cam, "")
                rgb = STATUS_RGB.get(s, (120, 120, 120))
                cells.append(Text(SHORT.get(s, s[:4]) or "·", style=f"rgb({rgb[0]},{rgb[1]},{rgb[2]})"))
            cells.append(f"{r.distance_px:.0f}" if math.isfinite(r.distance_px) else "—")
            cells.append(str(r.problem_frames) if r.problem_frames else "")
            t.add_row(*cells, key=str(r.marker))

    def current(self) -> int | None:
        t = self.query_one(DataTable)
        if not self.shown or t.cursor_row is None or not 0 <= t.cursor_row < len(self.shown):
            return None
        return self.shown[t.cursor_row].marker

    def refresh_rows(self) -> None:
        """After a rename or merge: the markers as they are now, the same filter applied."""
        if not self.main.marker_list:
            self.dismiss(None)
            return
        self.rows = self.main.picker_rows()
        self._apply_filter(self.query_one("#filter", Input).value)

    def _apply_filter(self, text: str) -> None:
        text = text.strip().lower()
        self.shown = [r for r in self.rows if not text or text == str(r.marker) or text in r.label.lower()]
        self._fill()

    def on_input_changed(self, event: Input.Changed) -> None:
        self._apply_filter(event.value)

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.query_one(DataTable).focus()

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        self.action_pick()

    def action_pick(self) -> None:
        m = self.current()
        if m is not None:
            self.dismiss(m)

    def action_rename(self) -> None:
        m = self.current()
        if m is not None:
            self.main.action_rename(m, then=self.refresh_rows)

    def action_merge(self) -> None:
        m = self.current()
        if m is not None:
            self.main.action_merge(m, then=self.refresh_rows)

    def action_filter(self) -> None:
        box = self.query_one("#filter", Input)
        box.add_class("-shown")
        box.focus()

    def action_close(self) -> None:
        if self.query_one("#filter", Input).has_focus:
            self.query_one(DataTable).focus()
            return
        self.dismiss(None)
