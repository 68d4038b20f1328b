"""Angle of repose of a heap (photo, video, folder, DEM dump) and the DEM parameter sweep (a RUNS.csv)."""

from __future__ import annotations

from pathlib import Path

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Button, Footer, Input, Label, Select, Static

from ...errors import SandtrackError
from ..core import core
from .base import TaskScreen

SWEEP_COLUMNS = {"repose", "angle_deg", "trajectories"}


def is_sweep_table(path: Path) -> bool:
    """A RUNS.csv (columns repose / angle_deg / trajectories), not a DEM exchange CSV."""
    if path.suffix.lower() != ".csv" or not path.is_file():
        return False
    try:
        with path.open(errors="replace") as fh:
            head = fh.readline()
    except OSError:
        return False
    cols = {c.strip().lower() for c in head.split(",")}
    return bool(cols & SWEEP_COLUMNS) and "particle_id" not in cols


class ReposeScreen(TaskScreen):
    AUTO_FOCUS = "#path"
    BINDINGS = [*TaskScreen.BINDINGS, ("ctrl+r", "go", "run")]

    def __init__(self, app) -> None:
        self.repose = core("repose", "measure_path")
        self.report = core("repose.report", "text")
        self.sweep = core("sweep", "run_sweep", "read_runs", "sweep_text")
        super().__init__(app)

    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static("Angle of repose and DEM sweep", classes="title")
            with Horizontal(classes="row"):
                yield Label("File:")
                yield Input(id="path", compact=True,
                            placeholder="photo, video, folder, DEM dump or exchange CSV; or a sweep's RUNS.csv")
            with Horizontal(classes="row"):
                yield Label("Camera file:")
                yield Input(id="calibration", compact=True, placeholder="optional calibration.toml (photos)")
                yield Select([("both flanks", "both"), ("left flank", "left"), ("right flank", "right")],
                             value="both", allow_blank=False, id="side", compact=True)
            with Horizontal(classes="row"):
                yield Label("Experiment angle (deg):")
                yield Input(id="target", compact=True, placeholder="for a sweep: the measured angle of repose")
                yield Button("Measure", id="run", variant="primary", compact=True)
            yield self.progress_row()
            yield Static("", id="result")
        yield Footer()

    def action_go(self) -> None:
        self.start()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.start()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.start()

    def _value(self, wid: str) -> str:
        return self.query_one(f"#{wid}", Input).value.strip()

    def start(self) -> None:
        text = self._value("path")
        path = Path(text).expanduser()
        if not text or not (path.exists() or any(ch in text for ch in "*?[")):
            self.notify(f"file not found: {path}", severity="error")
            return
        width = max(self.size.width - 16, 30)
        if is_sweep_table(path):
            self._start_sweep(path, width)
            return
        cal_text = self._value("calibration")
        side = str(self.query_one("#side", Select).value)
        repose, report = self.repose, self.report

        def job(progress, should_stop):
            from ...camera import Calibration

            cal = Calibration.load(Path(cal_text).expanduser()) if cal_text else None
            result = repose.measure_path(str(path), side=side, calibration=cal, progress=progress,
                                         should_stop=should_stop)
            return report.text(result, width)

        self.main.run_task("angle of repose", job, on_result=self.show_text, refresh_points=False)

    def _start_sweep(self, path: Path, width: int) -> None:
        target_text = self._value("target")
        try:
            target = float(target_text) if target_text else None
        except ValueError:
            self.notify(f"experiment angle {target_text!r} is not a number", severity="error")
            return
        sweep = self.sweep
        traj = core("trajectories", "trajectory_table")
        cmp = core("compare", "experiment_table")
        fps = self.main.sources[self.main.ref].fps

        def job(progress, should_stop):
            runs, params = sweep.read_runs(path)
            exp = None
            if "trajectories" in runs.columns:  # this project's tracked markers are the experiment
                proj = self.main._worker_project()
                try:
                    exp = cmp.experiment_table(traj.trajectory_table(proj, method="triangulation"))
                except SandtrackError:
                    exp = None  # nothing tracked yet: the sweep says the trajectories were not compared
                finally:
                    proj.close()
            res = sweep.run_sweep(runs, params, target, exp, cmp_kw={"fps": fps}, progress=progress)
            return sweep.sweep_text(res)

        self.main.run_task("DEM sweep", job, on_result=self.show_text, refresh_points=False)

    def show_text(self, text: str) -> None:
        self.query_one("#result", Static).update(Text(text))
