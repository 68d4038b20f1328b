"""The terminal UI driven by Pilot on a small synthetic experiment with known marker centres."""

from __future__ import annotations

import asyncio
import functools
import math

import numpy as np
import pandas as pd
import pytest

from conftest import POLL_LIMIT_S
from sandtrack_tui.tui.app import SandtrackApp
from tui_synth import N_FRAMES, make_frames, make_project, true_xy, true_xyz

SIZE = (100, 30)


def aio(fn):
    """Run an async test without a pytest asyncio plugin."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        return asyncio.run(fn(*args, **kwargs))

    return wrapper


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return make_frames(tmp_path_factory.mktemp("frames"))


@pytest.fixture
def project(tmp_path, frames):
    proj = make_project(tmp_path, frames=frames)
    yield proj
    proj.close()


async def settle(pilot, app, cond=None, timeout=POLL_LIMIT_S):
    """Wait until both views show what was asked for (and `cond()` holds)."""
    import time

    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        await pilot.pause(0.02)
        if app.views_ready() and (cond is None or cond()):
            return
    raise AssertionError("the UI did not settle")


async def click_source(pilot, app, camera, x, y, dcol=0, drow=0):
    """Click the cell showing source pixel (x, y) of `camera`, shifted by (dcol, drow) cells."""
    app.clear_notifications()  # a toast over the view would catch the click
    await pilot.pause()
    v = app.view(camera)
    col, row = v.tf.source_to_cell(x, y)
    await pilot.click(f"#view-{camera}", offset=(col + dcol + v.gutter.left, row + drow + v.gutter.top))
    await pilot.pause(0.05)


def stored(project, marker, camera, frame):
    p = project.points(marker=marker, camera=camera, frame=frame)
    assert len(p) == 1, f"no point for marker {marker} {camera} frame {frame}"
    r = p.iloc[0]
    return (math.nan if r["x_px"] is None else float(r["x_px"]), math.nan if r["y_px"] is None else float(r["y_px"]),
            r["status"])


@pytest.mark.parametrize("dcol,drow", [(0, 0), (1, 0), (-1, 0)])
@aio
async def test_click_maps_to_true_centre(project, dcol, drow):
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("2")
        x, y = true_xy(2, 0)
        await click_source(pilot, app, "side", x, y, dcol, drow)
        sx, sy, status = stored(project, 2, "side", 0)
        assert math.hypot(sx - x, sy - y) < 0.12  # snapped to the marker: measured 0.07-0.08 px
        assert status == "manual"
        # the mapping itself is good to about one cell: s source px per display px
        v = app.view("side")
        cx, cy = v.tf.cell_to_source(*v.tf.source_to_cell(x, y))
        assert abs(cx - x) <= v.tf.s / 2 + 1e-9 and abs(cy - y) <= v.tf.s + 1e-9


@aio
async def test_click_when_zoomed_and_in_front_view(project):
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("3", "tab")
        app.cursor["front"] = true_xy(3, 0, "front")
        await pilot.press("plus", "plus")
        await settle(pilot, app)
        v = app.view("front")
        assert v.tf.s < 4 and v.tf.x0 > 0
        x, y = true_xy(3, 0, "front")
        await click_source(pilot, app, "front", x, y, 2, 1)
        sx, sy, _ = stored(project, 3, "front", 0)
        assert math.hypot(sx - x, sy - y) < 0.12  # snapped to the marker: measured 0.07-0.08 px


@aio
async def test_keyboard_seed_and_step(project):
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("1")
        tx, ty = true_xy(1, 0)
        s = app.view("side").tf.s
        cx, cy = app.cursor["side"]
        keys = ["h" if tx < cx else "l"] * round(abs(tx - cx) / s) + ["k" if ty < cy else "j"] * round(abs(ty - cy) / s)
        await pilot.press(*keys)
        assert math.hypot(app.cursor["side"][0] - tx, app.cursor["side"][1] - ty) < s
        await pilot.press("enter")
        sx, sy, _ = stored(project, 1, "side", 0)
        assert math.hypot(sx - tx, sy - ty) < 0.053  # measured 0.035 px
        # navigation
        await pilot.press("right")
        await settle(pilot, app)
        assert app.frame == 1 and app.view("side").pixels_key[0] == 1
        await pilot.press("shift+right", "pagedown")
        assert app.frame == N_FRAMES - 1  # clamped
        await pilot.press("home")
        assert app.frame == 0
        await pilot.press("g")
        await pilot.pause()
        await pilot.press("1", "2", "enter")
        await settle(pilot, app)
        assert app.frame == 12 and app.view("front").pixels_key[0] == 12


@aio
async def test_track_correct_undo(project):
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("1")
        await click_source(pilot, app, "side", *true_xy(1, 0))
        await click_source(pilot, app, "front", *true_xy(1, 0, "front"))
        assert len(project.points(marker=1)) == 2
        await pilot.press("t")
        await settle(pilot, app, lambda: app.bg_task is None)
        pts = project.points(marker=1, camera="side")
        assert len(pts) == N_FRAMES
        err = [math.hypot(r.x_px - true_xy(1, r.frame)[0], r.y_px - true_xy(1, r.frame)[1])
               for r in pts.itertuples() if r.status in ("tracked", "manual")]
        assert len(err) >= N_FRAMES - 2 and np.mean(err) < 0.058  # measured 0.038 px
        # the timeline shows the marker as tracked all along
        assert (app.codes[(1, "side")] > 0).all()

        # delete frames 10..14 in the side view, find the gap as a problem, interpolate, undo all
        await pilot.press("tab", "home")  # the last click made the front view active
        assert app.active == "side"
        for _ in range(10):
            await pilot.press("right")
        await pilot.press("left_square_bracket")
        await pilot.press("right", "right", "right", "right", "right_square_bracket", "backspace")
        assert project.points(marker=1, camera="side", frames=(10, 14)).empty
        await pilot.press("escape", "home", "n")
        assert app.frame == 10
        await pilot.press("i")
        filled = project.points(marker=1, camera="side", frames=(10, 14))
        assert len(filled) == 5 and (filled["status"] == "interpolated").all()
        await pilot.press("u")
        assert project.points(marker=1, camera="side", frames=(10, 14)).empty
        await pilot.press("u")
        assert len(project.points(marker=1, camera="side", frames=(10, 14))) == 5
        await pilot.press("U")
        assert project.points(marker=1, camera="side", frames=(10, 14)).empty

        # nudge and occlude at frame 3
        await pilot.press("home", "right", "right", "right", "d", "d", "S")
        x, y, status = stored(project, 1, "side", 3)
        tx, ty = true_xy(1, 3)
        assert status == "manual" and abs(x - tx - 2) < 0.16 and abs(y - ty - 5) < 0.16  # 0.01 / 0.11
        await pilot.press("o")
        assert stored(project, 1, "side", 3)[2] == "occluded"


@aio
async def test_worker_error_is_a_notification(project, monkeypatch):
    import sandtrack_tui.tracking.run as run

    def broken(*a, **k):
        raise RuntimeError("boom")

    monkeypatch.setattr(run, "track_project", broken)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("r")
        await settle(pilot, app, lambda: app.bg_task is None)
        assert any("boom" in n.message for n in app._notifications)
        await pilot.press("right")  # still alive
        await settle(pilot, app)
        assert app.frame == 1


@aio
async def test_table_and_export_give_true_xyz(tmp_path, frames):
    project = make_project(tmp_path, frames=frames, calibrated=True)
    app = SandtrackApp(project)
    async with app.run_test(size=(120, 50)) as pilot:
        await settle(pilot, app)
        await pilot.press("2")
        await click_source(pilot, app, "side", *true_xy(2, 0))
        await click_source(pilot, app, "front", *true_xy(2, 0, "front"))
        # live table: XYZ by triangulation at the current frame, tiny residual
        row = next(r for r in app.table_rows() if r.marker == 2)
        assert np.linalg.norm(np.array(row.xyz_tri) - true_xyz(2, 0)) < 0.49  # measured 0.32 mm
        assert row.residual_px < 0.042  # measured 0.028 px
        # the front view shows the side point's epipolar curve through the true front position
        app.active = "side"
        app.update_overlays()
        (curve, _colour), = app.view("front").overlays.epipolar  # one other view: one curve
        fx, fy = true_xy(2, 0, "front")
        a, b = curve[:-1], curve[1:]
        t = np.clip(np.sum((np.array([fx, fy]) - a) * (b - a), 1) / np.sum((b - a) ** 2, 1), 0, 1)
        assert np.hypot(*(a + t[:, None] * (b - a) - [fx, fy]).T).min() < 0.095  # measured 0.063 px
        await pilot.press("t")
        await settle(pilot, app, lambda: app.bg_task is None)
        await pilot.press("e")
        await pilot.pause(0.2)
        out = tmp_path / "out.csv"
        app.screen.query_one("#path").value = str(out)
        await pilot.click("#export")
        await settle(pilot, app, lambda: app.bg_task is None and out.exists())
        df = pd.read_csv(out)
        tri = df[(df["method"] == "triangulation") & (df["marker"] == 2)].dropna(subset=["X_mm"])
        assert len(tri) >= N_FRAMES - 2
        err = [np.linalg.norm(np.array([r.X_mm, r.Y_mm, r.Z_mm]) - true_xyz(2, r.frame)) for r in tri.itertuples()]
        assert np.median(err) < 0.33  # measured 0.21 px
        await pilot.press("escape")
        assert app.screen is app._main_screen


@aio
async def test_auto_seed_confirm_list_then_swap_over_range(tmp_path, frames):
    from sandtrack_tui.tui.screens.autoseed import AutoSeedScreen

    project = make_project(tmp_path, frames=frames, calibrated=True)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("A", "m")  # A asks: m, the markers like the seeded one
        await settle(pilot, app, lambda: isinstance(app.screen, AutoSeedScreen))
        assert len(app.screen.markers) == 3
        await pilot.press("space", "enter")  # skip the first proposal, accept the others
        await settle(pilot, app, lambda: app.screen is app._main_screen)
        seeds = project.points(frame=0)
        assert seeds["marker"].nunique() == 2 and len(seeds) == 4
        truth = {m: true_xy(m, 0) for m in (1, 2, 3)}
        side = seeds[seeds["camera"] == "side"]
        for r in side.itertuples():
            assert min(np.hypot(r.x_px - x, r.y_px - y) for x, y in truth.values()) < 0.11  # measured 0.074
        a, b = sorted(side["marker"])
        await pilot.press("r")
        await settle(pilot, app, lambda: app.bg_task is None)
        before = project.points(camera="side")
        # swap a and b over frames 5..8
        await pilot.press(str(a), *["right"] * 5, "left_square_bracket", "right", "right", "right",
                          "right_square_bracket", "X")
        await pilot.pause()
        await pilot.press(*str(b), "enter")
        await pilot.pause()
        after = project.points(camera="side")
        pa = after[after.marker == a].set_index("frame")
        pb_before = before[before.marker == b].set_index("frame")
        pa_before = before[before.marker == a].set_index("frame")
        for f in (5, 8):
            assert pa.loc[f, "x_px"] == pb_before.loc[f, "x_px"]
        assert pa.loc[4, "x_px"] == pa_before.loc[4, "x_px"] and pa.loc[9, "x_px"] == pa_before.loc[9, "x_px"]
        await pilot.press("u")
        assert project.points(camera="side").equals(before)


@aio
async def test_help_and_screens_open_and_close(project):
    from sandtrack_tui.tui.screens.help import HelpScreen

    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("question_mark")
        await pilot.pause()
        assert isinstance(app.screen, HelpScreen)
        await pilot.press("escape")
        for key in ("f2", "f3", "f5"):
            await pilot.press(key)
            await pilot.pause()
            assert app.screen is not app._main_screen
            await pilot.press("escape")
            await pilot.pause()
            assert app.screen is app._main_screen
        await pilot.press("right")  # still responsive
        await settle(pilot, app)
        assert app.frame == 1


@aio
async def test_keys_on_other_screens_and_bad_edits_never_kill_the_app(project):
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("1")
        await click_source(pilot, app, "side", *true_xy(1, 0))
        await pilot.press("o")  # occluded: no position any more
        await pilot.press("d")  # nudging a point without a position is refused, not a crash
        assert any("no position" in n.message for n in app._notifications)
        await pilot.press("f5")
        await pilot.pause()
        before = project.history(1)["id"].iloc[0]
        await pilot.press("tab", "w", "a", "s", "d", "right", "u")  # none of these act on the main view
        assert app.frame == 0 and project.history(1)["id"].iloc[0] == before
        await pilot.press("escape")
        await pilot.pause()
        await pilot.press("right")
        await settle(pilot, app)
        assert app.frame == 1


@aio
async def test_escape_cancels_a_running_track(project, monkeypatch):
    import time as _time

    import sandtrack_tui.tracking.run as run

    seen = {}

    def slow_track(proj, markers=None, start=None, stop=None, direction="forward", progress=None,
                   should_stop=None, sources=None):
        for k in range(500):
            if should_stop():
                seen["stopped_at"] = k
                return {"direction": direction, "rows_written": k, "stopped": True}
            progress(k, 500)
            _time.sleep(0.01)
        return {"direction": direction, "rows_written": 500, "stopped": False}

    monkeypatch.setattr(run, "track_project", slow_track)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("r")
        await pilot.pause(0.3)
        assert app.bg_task is not None
        await pilot.press("right")  # the UI stays responsive while the worker runs
        await settle(pilot, app)
        assert app.frame == 1
        await pilot.press("escape")
        await settle(pilot, app, lambda: app.bg_task is None)
        assert 0 < seen["stopped_at"] < 500
        assert any("cancelled" in n.message for n in app._notifications)


@aio
async def test_boost_shows_markers_like_the_seeded_one(tmp_path, frames):
    """Blue markers: the default boost. Black markers: after a seed the boost shows markers like it,
    and a reopened project learns that from its seeds."""
    from sandtrack_tui.tui.frame_view import BOOST_RGB

    def boosted_near(app, marker):
        v = app.view("side")
        u, w = (int(round(float(c))) for c in v.tf.source_to_display(*true_xy(marker, app.frame)))
        return np.all(v.pixels[max(w - 1, 0):w + 2, max(u - 1, 0):u + 2] == BOOST_RGB, axis=2).any()

    (tmp_path / "blue").mkdir()
    blue = make_project(tmp_path / "blue", frames=frames)
    black = make_project(tmp_path / "black", frames=make_frames(tmp_path / "black", paint=(30, 25, 25), n_frames=2))
    for proj in (blue, black):
        app = SandtrackApp(proj)
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            assert boosted_near(app, 2) == (proj is blue)
            await pilot.press("1")
            await click_source(pilot, app, "side", *true_xy(1, 0))
            assert (app.look is None) == (proj is blue)
            await settle(pilot, app, lambda a=app: a.view("side").pixels_key[-1] == id(a.look))
            assert all(boosted_near(app, m) for m in (1, 2, 3))
    app = SandtrackApp(black)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app, lambda: app.look is not None and app.view("side").pixels_key[-1] == id(app.look))
        assert app.look.kind == "dark" and all(boosted_near(app, m) for m in (1, 2, 3))
    for proj in (blue, black):
        proj.close()


@aio
async def test_drag_pans_a_zoomed_view_without_seeding(project):
    from textual.events import MouseDown, MouseMove, MouseUp

    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("1", "plus", "plus")
        await settle(pilot, app)
        app.clear_notifications()
        x0 = app.view("side").tf.x0
        await pilot._post_mouse_events([MouseDown], "#view-side", (20, 10), button=1)
        await pilot._post_mouse_events([MouseMove], "#view-side", (15, 10), button=1)
        await pilot._post_mouse_events([MouseMove, MouseUp], "#view-side", (12, 10), button=1)
        await settle(pilot, app)
        s = app.view("side").tf.s
        assert app.view("side").tf.x0 == pytest.approx(x0 + 8 * s)  # dragged left by 8 cells
        assert project.points().empty  # a drag is not a click: nothing was placed


@aio
async def test_an_edit_while_the_table_computes_is_shown(project, monkeypatch):
    # The table's rows are computed in a worker from the points of the moment; a seed placed while one
    # computation runs must be shown once it ends, not the rows from before it.
    import threading

    from sandtrack_tui.tracking.run import seed_marker

    app = SandtrackApp(project)
    release, started = threading.Event(), threading.Event()
    original = SandtrackApp.table_rows

    def slow_rows(self, *args, **kwargs):
        rows = original(self, *args, **kwargs)
        if not release.is_set():
            started.set()
            release.wait(5)
        return rows

    async with app.run_test(size=(120, 50)) as pilot:  # (a view that shows the table)
        await settle(pilot, app)
        monkeypatch.setattr(SandtrackApp, "table_rows", slow_rows)
        seed_marker(app.project, 1, "side", app.frame, *true_xy(1, app.frame))
        app.after_edit()
        await settle(pilot, app, started.is_set)
        seed_marker(app.project, 2, "side", app.frame, *true_xy(2, app.frame))
        app.reload_points()
        app.update_table()  # while the rows with marker 1 alone are on their way
        release.set()
        table = app._w["table"]
        await settle(pilot, app, lambda: len(table.rows) == 2)
        assert {str(k.value) for k in table.rows} == {"1", "2"}
