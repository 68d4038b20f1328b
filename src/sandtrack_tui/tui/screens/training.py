"""TrainingScreen (waits for the core module sandtrack_tui.regression)."""

from __future__ import annotations

from ..core import core
from .base import TaskScreen


class TrainingScreen(TaskScreen):
    def __init__(self, app) -> None:
        core("regression", "__missing__")
        super().__init__(app)
