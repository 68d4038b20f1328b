"""Snapshot of the main screen (100 x 30): both views, overlays, timeline, status line, footer.
Update after an intended change with `pytest tests/test_tui_snapshot.py --snapshot-update`."""

from __future__ import annotations

import time

from sandtrack_tui.tui.app import SandtrackApp
from tui_synth import make_project, true_xy


async def _ready(pilot) -> None:
    app = pilot.app
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < 10:
        await pilot.pause(0.02)
        if app.views_ready():
            return


def test_main_screen_after_seeding(snap_compare, tmp_path):
    project = make_project(tmp_path)

    async def run_before(pilot) -> None:
        await pilot.pause()
        await _ready(pilot)
        app = pilot.app
        await pilot.press("1")
        v = app.view("side")
        col, row = v.tf.source_to_cell(*true_xy(1, 0))
        await pilot.click("#view-side", offset=(col + v.gutter.left, row + v.gutter.top))
        await pilot.press("right", "right")
        await _ready(pilot)
        app.clear_notifications()
        await pilot.pause()

    assert snap_compare(SandtrackApp(project, colors="truecolor"), terminal_size=(100, 30), run_before=run_before)
