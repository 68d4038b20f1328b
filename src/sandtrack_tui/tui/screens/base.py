"""Common frame for the task screens: a title, a body, a progress row while a task runs, escape to go back."""

from __future__ import annotations

from textual.binding import Binding
from textual.containers import Horizontal
from textual.screen import Screen
from textual.widgets import Label, ProgressBar


class TaskScreen(Screen):
    DEFAULT_CSS = """
    TaskScreen { padding: 0 1; }
    TaskScreen .title { text-style: bold; color: $accent; margin-bottom: 1; }
    TaskScreen .row { height: auto; margin-bottom: 0; }
    TaskScreen .row > * { margin-right: 1; }
    TaskScreen .row Label { padding-top: 0; }
    TaskScreen Input { width: 1fr; }
    TaskScreen Select { width: 34; }
    TaskScreen .result { height: auto; margin-top: 1; }
    TaskScreen #progress-row { height: 1; display: none; }
    TaskScreen #progress-row.-running { display: block; }
    TaskScreen #progress-row ProgressBar { width: 1fr; }
    """
    BINDINGS = [Binding("escape", "back", "back"), Binding("ctrl+c", "cancel_task", "cancel task", show=False)]

    def __init__(self, app) -> None:
        super().__init__()
        self.main = app

    def progress_row(self) -> Horizontal:
        return Horizontal(Label("", id="progress-label"), ProgressBar(id="progress-bar", show_eta=True),
                          id="progress-row")

    # called by the app for the running task
    def task_started(self, name: str) -> None:
        if self.query("#progress-row"):
            self.query_one("#progress-label", Label).update(f"{name} (ctrl+c cancels) ")
            self.query_one("#progress-bar", ProgressBar).update(total=None, progress=0)
            self.query_one("#progress-row").add_class("-running")

    def task_progress(self, done: int, total: int, text: str = "") -> None:
        if self.query("#progress-bar"):
            self.query_one("#progress-bar", ProgressBar).update(total=max(total, 1), progress=done)
            if text:
                self.query_one("#progress-label", Label).update(f"{text} ")

    def task_finished(self) -> None:
        if self.query("#progress-row"):
            self.query_one("#progress-row").remove_class("-running")

    def action_cancel_task(self) -> None:
        self.main.action_cancel()

    def action_back(self) -> None:
        self.dismiss()
