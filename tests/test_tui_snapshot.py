"""Snapshot of the main screen (100 x 30): both views, overlays, timeline, status line, footer.
Update after an intended change with `pytest tests/test_tui_snapshot.py --snapshot-update`."""

from __future__ import annotations

import time

from conftest import POLL_LIMIT_S
from sandtrack_tui.tui.app import SandtrackApp
from tui_synth import make_project, true_xy


async def _ready(pilot) -> None:
    app = pilot.app
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < POLL_LIMIT_S:
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


def test_main_screen_256_colours_after_tracking_with_a_gap(snap_compare, tmp_path):
    project = make_project(tmp_path)

    async def run_before(pilot) -> None:
        await pilot.pause()
        await _ready(pilot)
        app = pilot.app
        app.clear_notifications()  # toasts would catch the clicks
        await pilot.pause()
        for marker in (1, 2):
            await pilot.press(str(marker))
            for cam in ("side", "front"):
                v = app.view(cam)
                col, row = v.tf.source_to_cell(*true_xy(marker, 0, cam))
                await pilot.click(f"#view-{cam}", offset=(col + v.gutter.left, row + v.gutter.top))
        await pilot.press("r")
        t0 = time.perf_counter()
        while app.bg_task is not None and time.perf_counter() - t0 < POLL_LIMIT_S:
            await pilot.pause(0.05)
        await pilot.press("tab", "1", *["right"] * 10, "left_square_bracket", *["right"] * 4,
                          "right_square_bracket", "delete", "escape", "home", "n")
        await _ready(pilot)
        app.clear_notifications()
        await pilot.pause()

    assert snap_compare(SandtrackApp(project, colors="256"), terminal_size=(100, 30), run_before=run_before)
