"""Screens opened from the main view (F2-F6, the command palette)."""

from __future__ import annotations

import importlib

SCREENS = {
    "sync": ("sync", "SyncScreen"),
    "calibration": ("calibration", "CalibrationScreen"),
    "training": ("training", "TrainingScreen"),
    "export": ("export", "ExportScreen"),
    "compare": ("compare", "CompareScreen"),
    "repose": ("repose", "ReposeScreen"),
}


def open_screen(name: str, app):
    module, cls = SCREENS[name]
    return getattr(importlib.import_module(f".{module}", __name__), cls)(app)
