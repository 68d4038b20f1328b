"""Dialogs and task screens wrap their text to their width at every terminal size from 100 x 30 up: no line
is cut at a dialog's edge. Snapshots of the unsynced-tracking prompt at 100 x 30 and 200 x 55 and of the
marker list at 100 x 30; update after an intended change with `pytest tests/test_tui_dialogs.py --snapshot-update`."""

from __future__ import annotations

import pandas as pd
import pytest
from textual.app import App
from textual.widgets import Static

from sandtrack_tui.tui.app import SandtrackApp
from sandtrack_tui.tui.screens import SCREENS, open_screen
from sandtrack_tui.tui.screens.autoseed import AutoSeedScreen
from sandtrack_tui.tui.screens.picker import MarkerPicker, PickerRow
from sandtrack_tui.tui.screens.prompts import AskNumber, AskText, AutoSeedChoice, Confirm, SyncFirst
from test_tui_app import aio, settle
from tui_synth import make_project

SIZES = [(100, 30), (200, 55)]


def _dialogs(app) -> dict:
    """How to open each dialog and task screen."""
    seeds = pd.DataFrame([(m, c, 0, 100.0 + m, 50.0, 14, 14, 0.3) for m in (1, 2) for c in ("side", "front")],
                         columns=["marker", "camera", "frame", "x_px", "y_px", "w", "h", "epipolar_px"])
    screens = {
        "sync first": lambda: SyncFirst("side and front"),
        "auto-seed choice": AutoSeedChoice,
        "confirm": lambda: Confirm("tracking is running; quit anyway? (points so far are saved)"),
        "ask text": lambda: AskText("Length between the two ends (301.2 px apart), in mm:"),
        "ask number": lambda: AskNumber("Marker 3 is the same bead as which marker? (that id stays; 3 goes: its "
                                        "points move to it)", None, 1, 999),
        "auto-seed": lambda: AutoSeedScreen(seeds, ("side", "front")),
        "marker list": lambda: MarkerPicker(app, _picker_rows(), ["side", "front"], "side"),
        **{name: (lambda name=name: open_screen(name, app)) for name in SCREENS},
    }
    return {"help": app.action_help, **{name: (lambda make=make: app.push_screen(make()))
                                        for name, make in screens.items()}}


def _picker_rows() -> list[PickerRow]:
    return [PickerRow(m, f"bead {m}", {"side": "tracked", "front": "lost"}, 10.0 * m, 3) for m in (1, 2, 3)]


def _cut(screen, width: int) -> list[str]:
    """Every text widget reaching past its container's content or the terminal's edge."""
    return [f"{type(w).__name__}#{w.id} {w.region} in {w.parent.content_region}" for w in screen.query(Static)
            if w.region.width and (w.region.right > w.parent.content_region.right or w.region.right > width)]


def test_every_dialog_wraps_its_text_to_its_width(tmp_path):
    project = make_project(tmp_path)

    @aio
    async def run():
        app = SandtrackApp(project)
        async with app.run_test(size=SIZES[0]) as pilot:
            for size in SIZES:
                await pilot.resize_terminal(*size)
                await settle(pilot, app, lambda s=size: (app.size.width, app.size.height) == s)
                for name, show in _dialogs(app).items():
                    show()
                    await pilot.pause()
                    assert _cut(app.screen, size[0]) == [], f"{name} at {size}"
                    if name == "sync first":  # the whole prompt is on screen, every line of it
                        shown = " ".join(str(w.render()) for w in app.screen.query(Static) if w.region.height)
                        assert "track anyway (cameras that start together)" in shown and "escape" in shown
                    if name == "auto-seed choice":
                        shown = " ".join(str(w.render()) for w in app.screen.query(Static) if w.region.height)
                        assert "paired across cameras" in shown and "new ids" in shown and "escape" in shown
                    app.pop_screen()
                    await pilot.pause()

    run()
    project.close()


class _Host(App):
    """A bare app showing one dialog (the main screen's pictures would make the snapshot large)."""

    def __init__(self, dialog) -> None:
        super().__init__()
        self.dialog = dialog

    def on_mount(self) -> None:
        self.push_screen(self.dialog)


@pytest.mark.parametrize("size", [(100, 30), (200, 55)], ids=lambda s: f"{s[0]}x{s[1]}")
def test_sync_prompt_snapshot(snap_compare, size):
    assert snap_compare(_Host(SyncFirst("side and front")), terminal_size=size)


def test_marker_list_snapshot(snap_compare):
    class Main:  # what the marker list asks of the app: nothing until a key is pressed
        marker_list = [(1, "bead 1")]

    assert snap_compare(_Host(MarkerPicker(Main(), _picker_rows(), ["side", "front"], "side")), terminal_size=(100, 30))
