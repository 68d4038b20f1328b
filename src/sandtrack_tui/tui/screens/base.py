"""Common frame for the task screens: a title, a body, a log line, a progress bar, escape to go back."""

from __future__ import annotations

from textual.binding import Binding
from textual.screen import Screen


class TaskScreen(Screen):
    DEFAULT_CSS = """
    TaskScreen { padding: 0 1; }
    TaskScreen .title { text-style: bold; color: $accent; margin-bottom: 1; }
    TaskScreen .row { height: auto; margin-bottom: 1; }
    TaskScreen .row > * { margin-right: 1; }
    TaskScreen Input { width: 1fr; }
    TaskScreen .result { height: auto; margin-top: 1; }
    """
    BINDINGS = [Binding("escape", "back", "back")]

    def __init__(self, app) -> None:
        super().__init__()
        self.main = app

    def action_back(self) -> None:
        self.dismiss()
