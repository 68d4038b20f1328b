"""Live per-marker table for the current frame."""

from __future__ import annotations

import math
from dataclasses import dataclass

from rich.text import Text
from textual.widgets import DataTable

from .frame_view import STATUS_RGB

COLUMNS = (("id", 3), ("st s/f", 7), ("score", 5), ("side px", 13), ("front px", 13), ("XYZ triang. mm", 20),
           ("XYZ network mm", 20), ("Δ mm", 5), ("res px", 6))
SHORT = {"tracked": "trk", "manual": "man", "interpolated": "int", "occluded": "occ", "lost": "LOST",
         "imported": "imp"}


@dataclass
class MarkerRow:
    marker: int
    label: str
    status_side: str | None = None
    status_front: str | None = None
    score: float | None = None
    side_px: tuple[float, float] | None = None
    front_px: tuple[float, float] | None = None
    xyz_tri: tuple[float, float, float] | None = None
    xyz_net: tuple[float, float, float] | None = None
    residual_px: float | None = None

    @property
    def difference_mm(self) -> float | None:
        if self.xyz_tri is None or self.xyz_net is None:
            return None
        d = math.dist(self.xyz_tri, self.xyz_net)
        return d if math.isfinite(d) else None


def _finite(v) -> bool:
    return v is not None and all(math.isfinite(float(x)) for x in (v if isinstance(v, tuple) else (v,)))


def _status(s: str | None) -> Text:
    if not s:
        return Text("·", style="dim")
    r, g, b = STATUS_RGB.get(s, (200, 200, 200))
    return Text(SHORT.get(s, s[:4]), style=f"rgb({r},{g},{b})")


def format_row(row: MarkerRow) -> list:
    def px(v):
        return f"{v[0]:6.1f},{v[1]:6.1f}" if _finite(v) else "—"

    def xyz(v):
        return f"{v[0]:6.1f},{v[1]:6.1f},{v[2]:6.1f}" if _finite(v) else "—"

    status = Text.assemble(_status(row.status_side), "/", _status(row.status_front))
    diff = row.difference_mm
    return [
        Text(row.label, style="bold"),
        status,
        f"{row.score:.2f}" if _finite(row.score) else "—",
        px(row.side_px),
        px(row.front_px),
        xyz(row.xyz_tri),
        xyz(row.xyz_net),
        f"{diff:.1f}" if diff is not None else "—",
        Text(f"{row.residual_px:.2f}", style="red" if row.residual_px > 2.0 else "")
        if _finite(row.residual_px) else "—",
    ]


class MarkerTable(DataTable):
    DEFAULT_CSS = """
    MarkerTable { height: auto; max-height: 11; }
    """

    can_focus = False  # display only: keys belong to the frame views

    def __init__(self, id: str | None = None) -> None:
        super().__init__(id=id, cursor_type="row", zebra_stripes=True, show_cursor=True)
        self._shape: tuple = ()
        self._shown: dict[int, list] = {}

    def on_mount(self) -> None:
        for label, width in COLUMNS:
            self.add_column(label, width=width, key=label)

    def set_rows(self, rows: list[MarkerRow], selected: int | None) -> None:
        keys = tuple(r.marker for r in rows)
        formatted = {r.marker: format_row(r) for r in rows}
        if keys != self._shape:
            self.clear()
            for r in rows:
                self.add_row(*formatted[r.marker], key=str(r.marker))
            self._shape = keys
        else:
            for r in rows:  # only the cells that changed: each update re-renders the table
                old = self._shown.get(r.marker, [])
                for i, (col, value) in enumerate(zip(self.columns, formatted[r.marker], strict=True)):
                    if i >= len(old) or old[i] != value:
                        self.update_cell(str(r.marker), col, value)
        self._shown = formatted
        if selected is not None and selected in keys:
            idx = keys.index(selected)
            if self.cursor_row != idx:
                self.move_cursor(row=idx, animate=False)
