"""ExportScreen (waits for the core module sandtrack_tui.trajectories)."""

from __future__ import annotations

from ..core import core
from .base import TaskScreen


class ExportScreen(TaskScreen):
    def __init__(self, app) -> None:
        core("trajectories", "__missing__")
        super().__init__(app)
