"""Export the trajectories: format, method, path."""

from __future__ import annotations

from pathlib import Path

from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Button, Footer, Input, Label, Select, Static

from ..core import core
from .base import TaskScreen


class ExportScreen(TaskScreen):
    AUTO_FOCUS = "#export"
    BINDINGS = [*TaskScreen.BINDINGS, ("ctrl+r", "go", "run")]

    def action_go(self) -> None:
        self.export()

    def __init__(self, app) -> None:
        self.traj = core("trajectories", "export_table", "export", "FORMATS")
        super().__init__(app)

    def default_path(self, fmt: str) -> str:
        """In the folder sandtrack was started from (the sample project lives in a data folder)."""
        suffix = {"csv": ".csv", "parquet": ".parquet", "dltdv": ""}[fmt]
        return str(Path.cwd() / f"{self.main.project.path.stem}_trajectories{suffix}")

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static("Export trajectories", classes="title")
            yield Static("One row per frame of the first camera, marker and method: frame, time_s, marker, each "
                         "camera's status and pixels, X_mm Y_mm Z_mm, method, residual_px. DLTdv writes "
                         "PREFIX-xypts.csv (cam1, cam2, … in the project's camera order), -xyzpts.csv, -xyzres.csv, "
                         "-offsets.csv.")
            with Horizontal(classes="row"):
                yield Label("Format:")
                yield Select([(f, f) for f in self.traj.FORMATS], value="csv", allow_blank=False, id="format",
                             compact=True)
                yield Label("XYZ by:")
                yield Select([("triangulation + network", "both"), ("triangulation", "triangulation"),
                              ("network (MLP)", "mlp")], value="both", allow_blank=False, id="method", compact=True)
            with Horizontal(classes="row"):
                yield Label("Path:")
                yield Input(value=self.default_path("csv"), id="path", compact=True)
                yield Button("Export", id="export", variant="primary", compact=True)
            yield self.progress_row()
            yield Static("", id="result", classes="result")
        yield Footer()

    def on_select_changed(self, event: Select.Changed) -> None:
        if event.select.id == "format":
            self.query_one("#path", Input).value = self.default_path(str(event.value))

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.export()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.export()

    def export(self) -> None:
        fmt = str(self.query_one("#format", Select).value)
        method = str(self.query_one("#method", Select).value)
        path = Path(self.query_one("#path", Input).value.strip()).expanduser()
        if not path.parent.is_dir():
            self.notify(f"folder does not exist: {path.parent}", severity="error")
            return
        heights = {c: v.height for c, v in self.main.project.videos().items()}
        traj = self.traj

        def job(progress, should_stop):
            proj = self.main._worker_project()
            try:
                df, pixels_only = traj.export_table(proj, method=method)
            finally:
                proj.close()
            written = traj.export(df, path, fmt, heights=heights)
            return df, written, pixels_only

        self.query_one("#result", Static).update("[yellow]exporting…[/]")
        self.main.run_task("export", job, on_result=self.show_result, refresh_points=False)

    def show_result(self, result) -> None:
        df, written, pixels_only = result
        methods = ", ".join(sorted(df["method"].dropna().unique())) if len(df) else "none"
        files = "\n".join(f"  {p}" for p in written)
        self.query_one("#result", Static).update(
            f"[green]wrote {len(df)} rows[/] ({df['marker'].nunique() if len(df) else 0} markers; methods: "
            f"{methods}) to\n{files}" + (f"\n[yellow]{pixels_only}[/]" if pixels_only else ""))
        if pixels_only:
            self.notify(f"exported {len(df)} rows: {pixels_only}", severity="warning", timeout=10)
        else:
            self.notify(f"exported {len(df)} rows")
