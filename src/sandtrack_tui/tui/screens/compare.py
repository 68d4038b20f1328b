"""CompareScreen (waits for the core module sandtrack_tui.compare)."""

from __future__ import annotations

from ..core import core
from .base import TaskScreen


class CompareScreen(TaskScreen):
    def __init__(self, app) -> None:
        core("compare", "__missing__")
        super().__init__(app)
