"""Sync: estimate the offset between the cameras from their audio (or video), review, apply."""

from __future__ import annotations

from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Button, Footer, Input, Label, Select, Static

from ...video import synced_camera
from ..core import core
from .base import TaskScreen


class SyncScreen(TaskScreen):
    AUTO_FOCUS = "#run"
    BINDINGS = [*TaskScreen.BINDINGS, ("ctrl+r", "go", "run")]

    def action_go(self) -> None:
        self.run_sync()

    def __init__(self, app) -> None:
        super().__init__(app)
        self.result = None

    def compose(self) -> ComposeResult:
        off = self.main.project.sync_offset_s
        with VerticalScroll():
            yield Static("Sync the cameras", classes="title")
            yield Static(f"Current offset: [b]{off * 1000:+.2f} ms[/] (the front camera started that much later "
                         f"than the side camera; side time t = front time t - offset)", id="current")
            with Horizontal(classes="row"):
                yield Select([("auto (audio, else video)", "auto"), ("audio", "audio"), ("video", "video")],
                             value="auto", allow_blank=False, id="method", compact=True)
                yield Button("Run sync", id="run", variant="primary", compact=True)
            yield Static("", id="result", classes="result")
            with Horizontal(classes="row"):
                yield Label("Offset (ms):")
                yield Input(value=f"{off * 1000:.3f}", id="offset", type="number", compact=True)
                yield Button("Apply", id="apply", variant="success", compact=True)
        yield Footer()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "run":
            self.run_sync()
        elif event.button.id == "apply":
            self.apply()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.apply()

    def run_sync(self) -> None:
        sync = core("sync", "estimate_offset")
        camera = synced_camera(self.main.cameras)
        if camera is None:
            self.notify("nothing to sync: " + ("one camera" if len(self.main.cameras) == 1 else
                                               "these cameras are taken as started together (no front camera)"),
                        severity="warning")
            return
        videos = self.main.project.videos()
        a, b = videos[self.main.ref].path, videos[camera].path
        method = self.query_one("#method", Select).value
        self.query_one("#result", Static).update("[yellow]running…[/] (the progress bar below the main view)")

        def job(progress, should_stop):
            return sync.estimate_offset(a, b, method=method)

        self.main.run_task("sync", job, on_result=self.show_result, refresh_points=False)

    def show_result(self, res) -> None:
        self.result = res
        text = res.summary() if hasattr(res, "summary") else str(res)
        camera = synced_camera(self.main.cameras)
        sync = core("sync", "sound_path_bound_s", "sound_path_line")
        bound = sync.sound_path_bound_s(self.main._calibration, self.main.ref, camera) \
            if getattr(res, "method", "") == "audio" and camera is not None else None
        if bound is not None:
            text += "\n" + sync.sound_path_line(bound)
        self.query_one("#result", Static).update(f"[green]{text}[/]\nPress Apply to use it.")
        self.query_one("#offset", Input).value = f"{res.offset_s * 1000:.3f}"
        self.query_one("#apply", Button).focus()

    def apply(self) -> None:
        try:
            ms = float(self.query_one("#offset", Input).value)
        except ValueError:
            self.notify("type the offset in milliseconds", severity="error")
            return
        self.main.apply_sync_offset(ms / 1000.0)
        self.query_one("#current", Static).update(f"Current offset: [b]{ms:+.2f} ms[/] (saved; u undoes it in the "
                                                  "main view)")
        self.notify(f"sync offset set to {ms:+.2f} ms")
