"""Access to core modules that a project may not have yet: a clear message instead of a crash."""

from __future__ import annotations

import importlib

from ..errors import NotAvailableYet

WHAT = {
    "tracking": "tracking",
    "xyz": "the XYZ table",
    "trajectories": "export",
    "compare": "DEM comparison",
    "regression": "training the regression model",
    "calibration": "calibration",
    "sync": "audio sync",
    "repose": "the angle of repose",
    "sweep": "the DEM parameter sweep",
}


def core(name: str, *attrs: str):
    """Import sandtrack_tui.<name> and check it offers `attrs`; NotAvailableYet otherwise."""
    what = WHAT.get(name.split(".")[0], name)
    try:
        mod = importlib.import_module(f"sandtrack_tui.{name}")
    except ImportError as exc:
        raise NotAvailableYet(f"{what} is not available yet ({exc.name or name} missing)") from None
    missing = [a for a in attrs if not hasattr(mod, a)]
    if missing:
        raise NotAvailableYet(f"{what} is not available yet (no {', '.join(missing)})")
    return mod


def available(name: str, *attrs: str) -> bool:
    try:
        core(name, *attrs)
    except NotAvailableYet:
        return False
    return True
