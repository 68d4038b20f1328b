"""Train the pixel -> XYZ network on calibration points: progress, then the test metrics."""

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


def metrics_table(metrics: dict):
    rows = [(k, v) for k, v in metrics.items() if isinstance(v, (int, float, str)) and not isinstance(v, bool)]
    if not rows:
        return "(no model yet)"
    half = (len(rows) + 1) // 2
    tables = []
    for chunk in (rows[:half], rows[half:]):
        t = Table(box=box.SIMPLE_HEAD)
        t.add_column("metric")
        t.add_column("value", justify="right")
        for k, v in chunk:
            t.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
        tables.append(t)
    return Columns(tables, padding=(0, 4))


class TrainingScreen(TaskScreen):
    AUTO_FOCUS = "#train"
    BINDINGS = [*TaskScreen.BINDINGS, ("ctrl+r", "go", "run")]

    def action_go(self) -> None:
        self.start()

    def __init__(self, app) -> None:
        self.reg = core("regression", "train", "TrainConfig", "load_points")
        super().__init__(app)

    def compose(self) -> ComposeResult:
        info = self.main.project.get("model") or {}
        with VerticalScroll():
            yield Static("Train the regression model (pixels -> XYZ)", classes="title")
            yield Static(f"Current model: {info.get('path', 'none')}", id="current")
            with Horizontal(classes="row"):
                yield Label("Calibration points CSV:")
                yield Input(value=str(self.main.project.get("calibration_points", "")), id="points",
                            placeholder="points.csv: frame, corner_id, xs, ys, xf, yf, X_mm, Y_mm, Z_mm", compact=True)
            with Horizontal(classes="row"):
                yield Select([("full", "full"), ("quick preview", "fast")], value="full", allow_blank=False,
                             id="config", compact=True)
                yield Button("Train", id="train", variant="primary", compact=True)
            yield self.progress_row()
            yield Static("", id="status", classes="result")
            yield Static(metrics_table(info.get("metrics", {})), id="metrics")
        yield Footer()

    def on_mount(self) -> None:
        box = self.query_one("#points", Input)
        if not box.value.strip() or not Path(box.value.strip()).expanduser().is_file():
            box.focus()  # nothing to run yet: type the file first

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.start()

    def start(self) -> None:
        text = self.query_one("#points", Input).value.strip()
        path = Path(text).expanduser()
        if not text or not path.is_file():
            self.notify(f"file not found: {path}", severity="error")
            return
        reg = self.reg
        cfg = reg.TrainConfig.fast() if self.query_one("#config", Select).value == "fast" else reg.TrainConfig()
        cal = self.main._calibration
        out = self.main.project.path.with_name(self.main.project.path.stem + "_model.pt")
        status = self.query_one("#status", Static)

        def job(progress, should_stop):
            points = reg.load_points(path)
            total = cfg.total_epochs(cal is not None)
            last = {}

            def on_epoch(epoch, loss, val_mm):
                last.update(epoch=epoch, val_mm=val_mm)
                progress(epoch, total)
                self.main.call_from_thread(status.update, f"epoch {epoch}/{total}: validation error {val_mm:.2f} mm")

            model = reg.train(points, cfg, calibration=cal, progress=on_epoch, should_stop=should_stop)
            model.save(out)
            proj = self.main._worker_project()
            try:
                metrics = {k: v for k, v in model.metrics.items() if isinstance(v, (int, float, str, bool))}
                proj.set("model", {"path": str(out), "metrics": metrics}, "train regression model")
                proj.set("calibration_points", str(path), "remember calibration points")
            finally:
                proj.close()
            return model

        self.main.run_task("training", job, on_result=self.show_result, refresh_points=False)

    def show_result(self, model) -> None:
        stopped = model.metrics.get("stopped")
        note = f" (training ended: {stopped})" if isinstance(stopped, str) else ""
        self.query_one("#status", Static).update(
            f"[green]model saved[/]: {self.main.project.get('model')['path']}{note}; the live table now shows "
            "XYZ by the network")
        self.query_one("#metrics", Static).update(metrics_table(model.metrics))
        self.main.refresh_all()
