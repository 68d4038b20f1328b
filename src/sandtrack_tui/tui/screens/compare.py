"""DEM comparison: read a DEM trajectory file, align and compare with the tracked markers, plot errors."""

from __future__ import annotations

from pathlib import Path

from rich import box
from rich.columns import Columns
from rich.table import Table
from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Button, Footer, Input, Label, Select, Static

from ..core import core
from .base import TaskScreen

SUMMARY_KEYS = ("particles", "time_shift_s", "rmse_3d_mm_all", "rmse_3d_mm_median", "final_error_mm_median",
                "frechet_mm_median", "dtw_norm_mm_median", "flagged_markers", "chi2_reduced", "samples_eff",
                "p_value", "within_95_pct")


class CompareScreen(TaskScreen):
    AUTO_FOCUS = "#run"
    BINDINGS = [*TaskScreen.BINDINGS, ("ctrl+r", "go", "run")]

    def action_go(self) -> None:
        self.start()

    def __init__(self, app) -> None:
        self.cmp = core("compare", "compare", "experiment_table", "error_text_plot")
        self.dem = core("dem", "read_dem")
        self.traj = core("trajectories", "trajectory_table")
        super().__init__(app)

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static("Compare with a DEM simulation", classes="title")
            with Horizontal(classes="row"):
                yield Label("DEM file:")
                yield Input(value=str(self.main.project.get("dem_path", "")), id="dem",
                            placeholder="exchange CSV or LIGGGHTS/LAMMPS dump", compact=True)
            with Horizontal(classes="row"):
                yield Label("XYZ by:")
                yield Select([("triangulation", "triangulation"), ("network (MLP)", "mlp")],
                             value="triangulation", allow_blank=False, id="method", compact=True)
                # marker ids in a project are the operator's or auto-seed's, not the DEM's particle ids
                yield Select([("match by nearest start", "nearest"), ("match by id", "id"),
                              ("by id, else nearest", "auto")], value="nearest", allow_blank=False, id="match",
                             compact=True)
                yield Button("Compare", id="run", variant="primary", compact=True)
            with Horizontal(classes="row"):
                yield Label("DEM sd (mm):")
                yield Input(value="0", id="dem_sd", compact=True, classes="short",
                            tooltip="the DEM's own uncertainty per axis, added to the experiment's")
                yield Label("experiment sd if not known (mm):")
                yield Input(value="", id="exp_sd", compact=True, classes="short", placeholder="none: no χ²",
                            tooltip="taken per axis when the XYZ carries no sd (a model file from before spreads)")
            yield self.progress_row()
            yield Static("", id="verdict")
            yield Static("", id="summary")
            yield Static("", id="plot")
        yield Footer()

    def on_mount(self) -> None:
        box = self.query_one("#dem", Input)
        if not box.value.strip() or not Path(box.value.strip()).expanduser().is_file():
            box.focus()  # nothing to run yet: type the file first

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.start()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.start()

    def start(self) -> None:
        text = self.query_one("#dem", Input).value.strip()
        dem_path = Path(text).expanduser()
        if not text or not dem_path.exists():
            self.notify(f"file not found: {dem_path}", severity="error")
            return
        try:
            dem_sd = float(self.query_one("#dem_sd", Input).value.strip() or 0)
            text_sd = self.query_one("#exp_sd", Input).value.strip()
            exp_sd = float(text_sd) if text_sd else None
        except ValueError:
            self.notify("the sd fields take a number of mm (or nothing)", severity="error")
            return
        method = str(self.query_one("#method", Select).value)
        match = str(self.query_one("#match", Select).value)
        fps = self.main.sources["side"].fps
        cmp_mod, dem_mod, traj = self.cmp, self.dem, self.traj
        width = max(self.size.width - 12, 30)

        def job(progress, should_stop):
            proj = self.main._worker_project()
            try:
                exp = cmp_mod.experiment_table(traj.trajectory_table(proj, method=method), method)
                proj.set("dem_path", str(dem_path), "remember DEM file")
            finally:
                proj.close()
            dem = dem_mod.read_dem(dem_path)
            result = cmp_mod.compare(exp, dem, name=dem_path.stem, match=match, fps=fps, dem_sd_mm=dem_sd,
                                     exp_sd_mm=exp_sd)
            return result, cmp_mod.error_text_plot(result, width=width, height=12)

        self.main.run_task("DEM comparison", job, on_result=self.show_result, refresh_points=False)

    def show_result(self, result) -> None:
        cmp, plot = result
        summary = Table(box=box.SIMPLE_HEAD, show_header=True, title="Summary", title_justify="left")
        summary.add_column("figure")
        summary.add_column("value", justify="right")
        for k in SUMMARY_KEYS:
            if k in cmp.summary:
                v = cmp.summary[k]
                summary.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
        per = cmp.per_particle
        parts = [summary]
        if len(per):
            cols = [c for c in ("marker", "particle_id", "rmse_3d_mm", "final_error_mm", "frechet_mm",
                                "dtw_norm_mm", "chi2_reduced", "p_value", "within_95_pct", "flagged")
                    if c in per.columns]
            table = Table(box=box.SIMPLE_HEAD, title="Per marker", title_justify="left")
            for c in cols:
                table.add_column(c, justify="right")
            for r in per[cols].itertuples(index=False):
                table.add_row(*(f"{v:.2g}" if isinstance(v, float) and abs(v) < 0.01 else
                                f"{v:.2f}" if isinstance(v, float) else str(v) for v in r),
                              style="red" if getattr(r, "flagged", False) else None)
            parts.append(table)
        self.query_one("#verdict", Static).update(f"{cmp.name}: {cmp.summary.get('verdict', '')}")
        self.query_one("#summary", Static).update(Columns(parts, padding=(0, 4)))
        self.query_one("#plot", Static).update(plot)
