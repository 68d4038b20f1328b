"""Live per-marker table for the current frame: status and pixels in every camera, then XYZ by
triangulation and by the network (a side and a front camera), XYZ by triangulation (other rigs
of two or more cameras), or x, y in mm through the scale (one camera). An XYZ cell ends with
"± sd": the largest of its three 1-sigma sd (mm; "±?" where not known), and "~" when a camera's
pixels came from its nearest frame instead of the two around (a seed frame), "^" after the sd when a camera's
pixel lies beyond the image region its calibration covered (the sd leaves out the lens model's error
there). A network XYZ that
disagrees with the triangulation beyond both their sd (`network_check` "inconsistent"; its sd then
comes from the disagreement) ends with "!"."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from rich.text import Text
from textual.widgets import DataTable

from .frame_view import STATUS_RGB

SHORT = {"tracked": "trk", "manual": "man", "interpolated": "int", "occluded": "occ", "lost": "LOST",
         "imported": "imp"}


@dataclass
class MarkerRow:
    marker: int
    label: str
    status: dict[str, str] = field(default_factory=dict)  # per camera
    px: dict[str, tuple[float, float] | None] = field(default_factory=dict)
    score: float | None = None
    xyz_tri: tuple[float, float, float] | None = None
    xyz_net: tuple[float, float, float] | None = None
    sd_tri: tuple[float, float, float] | None = None
    sd_net: tuple[float, float, float] | None = None
    net_check: str = ""  # the network's XYZ against triangulation: "ok", "inconsistent", "unchecked"
    nearest_frame: bool = False
    outside_region: bool = False  # a camera's pixel beyond the image region its calibration covered
    residual_px: float | None = None
    xy_mm: tuple[float, float] | None = None  # one camera: image position in mm

    @property
    def difference_mm(self) -> float | None:
        if self.xyz_tri is None or self.xyz_net is None:
            return None
        d = math.dist(self.xyz_tri, self.xyz_net)
        return d if math.isfinite(d) else None


def columns(cameras: list[str]) -> list[tuple[str, int]]:
    """(title, width) of the table's columns for a project's cameras."""
    status_w = max(4 * len(cameras) - 1, 3)
    cols = [("id", 3), ("st " + "/".join(c[0] for c in cameras), status_w), ("score", 5)]
    cols += [(f"{c[:8]} px", 13) for c in cameras]
    if len(cameras) == 1:
        return [*cols, ("x, y mm", 15)]
    cols.append(("XYZ triang. mm ± sd", XYZ_WIDTH))
    if cameras == ["side", "front"]:
        cols += [("XYZ network mm ± sd", XYZ_WIDTH), ("Δ mm", 5)]
    return [*cols, ("res px", 6)]


XYZ_WIDTH = 28


def format_xyz(v, sd, nearest: bool = False, outside: bool = False) -> str:
    """"X, Y, Z ±sd" (mm; sd the largest axis's 1 sigma, "±?" unknown), "~" first for a nearest-frame row,
    "^" after the sd for pixels beyond the calibrated image region."""
    if not _finite(v):
        return "—"
    text = f"{'~' if nearest else ''}{v[0]:.1f},{v[1]:.1f},{v[2]:.1f}"
    text = f"{text} ±{max(sd):.2f}" if _finite(sd) else f"{text} ±?"
    return text + "^" if outside else text


def _finite(v) -> bool:
    return v is not None and all(math.isfinite(float(x)) for x in (v if isinstance(v, tuple) else (v,)))


def _status(s: str | None) -> Text:
    if not s:
        return Text("·", style="dim")
    r, g, b = STATUS_RGB.get(s, (200, 200, 200))
    return Text(SHORT.get(s, s[:4]), style=f"rgb({r},{g},{b})")


def format_row(row: MarkerRow, cameras: list[str]) -> list:
    def px(v):
        return f"{v[0]:6.1f},{v[1]:6.1f}" if _finite(v) else "—"

    parts = []
    for k, cam in enumerate(cameras):
        if k:
            parts.append("/")
        parts.append(_status(row.status.get(cam)))
    cells = [Text(row.label, style="bold"), Text.assemble(*parts),
             f"{row.score:.2f}" if _finite(row.score) else "—"]
    cells += [px(row.px.get(cam)) for cam in cameras]
    if len(cameras) == 1:
        return [*cells, f"{row.xy_mm[0]:6.1f},{row.xy_mm[1]:6.1f}" if _finite(row.xy_mm) else "—"]
    cells.append(format_xyz(row.xyz_tri, row.sd_tri, row.nearest_frame, row.outside_region))
    if cameras == ["side", "front"]:
        diff = row.difference_mm
        net = format_xyz(row.xyz_net, row.sd_net, row.nearest_frame, row.outside_region)
        net = Text(net + "!", style="yellow") if row.net_check == "inconsistent" and net != "—" else net
        cells += [net, f"{diff:.1f}" if diff is not None else "—"]
    cells.append(Text(f"{row.residual_px:.2f}", style="red" if row.residual_px > 2.0 else "")
                 if _finite(row.residual_px) else "—")
    return cells


class MarkerTable(DataTable):
    DEFAULT_CSS = """
    MarkerTable { height: auto; max-height: 11; }
    """

    can_focus = False  # display only: keys belong to the frame views

    def __init__(self, cameras: list[str], id: str | None = None) -> None:
        super().__init__(id=id, cursor_type="row", zebra_stripes=True, show_cursor=True)
        self.cameras = list(cameras)
        self._shape: tuple = ()
        self._shown: dict[int, list] = {}

    def on_mount(self) -> None:
        for label, width in columns(self.cameras):
            self.add_column(label, width=width, key=label)

    def set_rows(self, rows: list[MarkerRow], selected: int | None) -> None:
        keys = tuple(r.marker for r in rows)
        formatted = {r.marker: format_row(r, self.cameras) for r in rows}
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
