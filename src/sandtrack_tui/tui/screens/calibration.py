"""Calibration summary: each camera's intrinsics, pose and errors; load a calibration.toml."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Button, Footer, Input, Label, Markdown, Static

from ...camera import Calibration, euler_angles_deg
from ...errors import SandtrackError
from .base import TaskScreen


def summary_markdown(cal: Calibration | None) -> str:
    if cal is None:
        return ("No calibration yet. Calibrate with `sandtrack calibrate` (ChArUco video) or load a "
                "`calibration.toml` below.")
    lines = ["| camera | model | size | fx | fy | cx | cy | centre mm (rig) | angles ° | rmse px |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, c in cal.cameras.items():
        K = c.matrix
        ctr = ", ".join(f"{v:.0f}" for v in c.center_mm)
        ang = ", ".join(f"{v:.1f}" for v in euler_angles_deg(c.R))
        rmse = "—" if c.rmse_px is None else f"{c.rmse_px:.3f}"
        lines.append(f"| {name} | {c.model} | {c.width}×{c.height} | {K[0, 0]:.1f} | {K[1, 1]:.1f} | "
                     f"{K[0, 2]:.1f} | {K[1, 2]:.1f} | {ctr} | {ang} | {rmse} |")
    names = list(cal.cameras)
    if len(names) >= 2:
        a, b = cal.cameras[names[0]], cal.cameras[names[1]]
        base = float(np.linalg.norm(a.center_mm - b.center_mm))
        lines.append(f"\nBaseline {names[0]}–{names[1]}: **{base:.1f} mm**")
    if cal.report:
        lines.append("\n**Report**\n")
        for k, v in cal.report.items():
            if isinstance(v, (int, float, str)):
                lines.append(f"- {k}: {v:.4g}" if isinstance(v, float) else f"- {k}: {v}")
    return "\n".join(lines)


class CalibrationScreen(TaskScreen):
    def compose(self) -> ComposeResult:
        with VerticalScroll():
            yield Static("Calibration", classes="title")
            yield Markdown(summary_markdown(self.main._calibration), id="summary")
            with Horizontal(classes="row"):
                yield Label("Load calibration.toml:")
                yield Input(placeholder="path/to/calibration.toml", id="path")
                yield Button("Load", id="load", variant="primary", compact=True)
        yield Footer()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        self.load()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.load()

    def load(self) -> None:
        path = Path(self.query_one("#path", Input).value.strip()).expanduser()
        try:
            cal = Calibration.load(path)
            self.main.project.set_calibration(cal)
        except (SandtrackError, OSError) as exc:
            self.notify(str(exc), severity="error")
            return
        self.main.calibration_changed()
        self.query_one("#summary", Markdown).update(summary_markdown(cal))
        self.notify(f"calibration loaded from {path}")
