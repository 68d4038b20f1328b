"""An operator's session, driven by Pilot: the guard rails (unsynced tracking, auto-seed identities,
merge and rename), projects of one and of three cameras, ids that never overlap, the marker list."""

from __future__ import annotations

import contextlib
import math
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import POLL_LIMIT_S
from sandtrack_tui.store import Project
from sandtrack_tui.tui.app import SandtrackApp
from test_tui_app import SIZE, aio, click_source, settle
from tui_synth import N_FRAMES, calibration, make_frames, true_xy, true_xyz


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return make_frames(tmp_path_factory.mktemp("frames3"), cameras=("side", "front", "top"))


def new_project(folder, frames, cameras=("side", "front"), synced=True, calibrated=False) -> Project:
    proj = Project.create(folder / "exp.sandtrack", {c: frames / c for c in cameras})
    if synced:
        proj.set("sync_offset_s", 0.0)
    if calibrated:
        proj.set_calibration(calibration(cameras))
    return proj


async def seed_by_clicks(pilot, app, marker, cameras=("side", "front"), bead=None):
    """Select `marker` and click its bead (bead `marker` of the synthetic scene unless given) in each camera."""
    await pilot.press(str(marker))
    for cam in cameras:
        await click_source(pilot, app, cam, *true_xy(bead or marker, app.cam_index(cam), cam))


async def until_idle(pilot, app, timeout=POLL_LIMIT_S):
    await settle(pilot, app, lambda: app.bg_task is None, timeout=timeout)


# -- 1. tracking unsynced cameras asks first ------------------------------------------------------
@aio
async def test_tracking_unsynced_cameras_asks_first(tmp_path, frames, monkeypatch):
    import sandtrack_tui.sync as sync
    from sandtrack_tui.tui.screens.prompts import SyncFirst

    project = new_project(tmp_path, frames, synced=False)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await seed_by_clicks(pilot, app, 1)
        await pilot.press("r")
        await pilot.pause()
        assert isinstance(app.screen, SyncFirst)
        await pilot.press("escape")  # cancel: nothing tracked
        await until_idle(pilot, app)
        assert set(project.points()["status"]) == {"manual"} and not project.sync_confirmed()

        # sync now: the offset the sync measures is stored (one edit), then the tracking asked for runs
        measured = SimpleNamespace(offset_s=0.0, summary=lambda: "offset +0.00 ms (test)")
        monkeypatch.setattr(sync, "estimate_offset", lambda a, b, method="auto": measured)
        await pilot.press("r")
        await pilot.pause()
        await pilot.press("s")
        await until_idle(pilot, app)
        await settle(pilot, app, lambda: app.bg_task is None and len(project.points()) > 2)
        await until_idle(pilot, app)
        assert project.sync_confirmed() and project.sync_offset_s == 0.0
        assert len(project.points(marker=1, camera="side")) == N_FRAMES


@aio
async def test_the_sync_screen_says_how_far_the_sound_path_can_shift_an_audio_offset(tmp_path, frames, monkeypatch):
    """F2 with a calibrated project: the audio offset comes with the bound of the clap's sound path between the
    two cameras (250 mm apart here: ±0.73 ms)."""
    from textual.widgets import Static

    import sandtrack_tui.sync as sync
    from sandtrack_tui.tui.screens.sync import SyncScreen

    project = new_project(tmp_path, frames, synced=False, calibrated=True)
    measured = SimpleNamespace(offset_s=0.0123, method="audio", summary=lambda: "offset +12.30 ms (test)")
    monkeypatch.setattr(sync, "estimate_offset", lambda a, b, method="auto": measured)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("f2")
        await settle(pilot, app, lambda: isinstance(app.screen, SyncScreen))
        await pilot.press("ctrl+r")
        await until_idle(pilot, app)
        await settle(pilot, app, lambda: "±" in str(app.screen.query_one("#result", Static).render()))
        text = str(app.screen.query_one("#result", Static).render())
        assert "offset +12.30 ms (test)" in text and "sound path may shift it by up to ±0.73 ms" in text


@aio
async def test_track_anyway_is_asked_once_per_session(tmp_path, frames):
    project = new_project(tmp_path, frames, synced=False)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await seed_by_clicks(pilot, app, 2)
        await pilot.press("t")
        await pilot.pause()
        await pilot.press("t")  # track anyway
        await until_idle(pilot, app)
        assert len(project.points(marker=2, camera="front")) == N_FRAMES
        await pilot.press("home", "t")
        await pilot.pause()
        assert app.screen is app._main_screen and not project.sync_confirmed()  # not asked again
        await until_idle(pilot, app)


def test_cli_track_refuses_unsynced_cameras_unless_allowed(tmp_path, frames, capsys):
    from sandtrack_tui.cli import main

    new_project(tmp_path, frames, synced=False, calibrated=True).close()
    path = str(tmp_path / "exp.sandtrack")
    assert main(["track", path, "--auto-seed", "--to", "3"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not synced" in err[0] and "--allow-unsynced" in err[0]
    with Project.open(path) as proj:
        assert proj.points().empty  # refused before seeding
    assert main(["track", path, "--auto-seed", "--to", "3", "--allow-unsynced"]) == 0
    assert "warning" in capsys.readouterr().err
    with Project.open(path) as proj:
        assert proj.points(camera="side", frame=3)["marker"].nunique() == 3


# -- 2. auto-seed knows the markers it has seen, merge and rename ---------------------------------
@aio
async def test_auto_seed_again_keeps_the_markers_ids(tmp_path, frames):
    from sandtrack_tui.tui.screens.autoseed import AutoSeedScreen

    project = new_project(tmp_path, frames, calibrated=True)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("A", "m")  # A asks: m, the markers like the seeded one
        await settle(pilot, app, lambda: isinstance(app.screen, AutoSeedScreen))
        await pilot.press("enter")
        await settle(pilot, app, lambda: app.screen is app._main_screen)
        first = project.points(frame=0, camera="side").set_index("marker")
        assert sorted(first.index) == [1, 2, 3]
        await pilot.press("r")
        await until_idle(pilot, app)
        # undo the run, seed again at the start: the same beads keep their ids
        await pilot.press("u", "home", "A", "m")
        await settle(pilot, app, lambda: isinstance(app.screen, AutoSeedScreen))
        assert sorted(app.screen.markers) == [1, 2, 3] and app.screen.seeds["existing"].all()
        await pilot.press("enter")
        await settle(pilot, app, lambda: app.screen is app._main_screen)
        assert sorted(project.markers()["id"]) == [1, 2, 3]
        # after tracking, at a later frame the markers have moved: matched by their tracked points there
        await pilot.press("r")
        await until_idle(pilot, app)
        for _ in range(20):
            await pilot.press("right")
        await pilot.press("A", "m")  # A asks: m, the markers like the seeded one
        await settle(pilot, app, lambda: isinstance(app.screen, AutoSeedScreen))
        seeds = app.screen.seeds
        assert sorted(app.screen.markers) == [1, 2, 3]
        for r in seeds[seeds.camera == "side"].itertuples():  # each id on the bead it was tracked on
            tracked = project.points(marker=r.marker, camera="side", frame=20).iloc[0]
            assert math.dist((r.x_px, r.y_px), (tracked.x_px, tracked.y_px)) < 0.01  # measured 0.002 px
        await pilot.press("escape")


def one_bead_two_ids(project) -> None:
    """Bead 1 tracked all along as marker 1, and again from frame 10 on as marker 4 (seeded twice)."""
    rows = []
    for marker, start in ((1, 0), (4, 10)):
        project.add_marker(str(marker), marker)
        for cam in ("side", "front"):
            for f in range(start, N_FRAMES):
                x, y = true_xy(1, f, cam)
                rows.append((f, cam, marker, x + 0.1 * marker, y, "manual" if f == start else "tracked", 0.9,
                             None, None))
    project.set_points(rows, "two tracks of one bead")


@aio
async def test_merge_two_ids_of_one_bead_and_rename_are_undoable(tmp_path, frames):
    project = new_project(tmp_path, frames, calibrated=True)
    one_bead_two_ids(project)
    before = project.points()
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("4", "M")
        await pilot.pause()
        await pilot.press("1", "enter")
        await pilot.pause()
        after = project.points()
        assert set(after.marker) == {1} and 4 not in set(project.markers()["id"])
        assert len(after) == 2 * N_FRAMES and app.selected == 1
        # where both had a point the manual seed (better founded than a tracked point) stays
        assert project.points(marker=1, camera="front", frame=10)["status"].iloc[0] == "manual"
        assert project.points(marker=1, camera="front", frame=11)["x_px"].iloc[0] == pytest.approx(
            true_xy(1, 11, "front")[0] + 0.1)  # a tie: marker 1's own point
        await pilot.press("u")
        assert project.points().equals(before) and 4 in set(project.markers()["id"])

        # rename from the marker list
        await pilot.press("m")
        await pilot.pause()
        await pilot.press("r")
        await pilot.pause()
        app.screen.query_one("#answer").value = "A1"
        await pilot.press("enter")
        await pilot.pause()
        await pilot.press("escape")
        await pilot.pause()
        labels = dict(project.markers()[["id", "label"]].itertuples(index=False, name=None))
        renamed = [m for m, lab in labels.items() if lab == "A1"]
        assert len(renamed) == 1 and renamed[0] in (1, 4)
        assert any(r.label == "A1" for r in app.table_rows())
        await pilot.press("u")
        assert "A1" not in set(project.markers()["label"])


# -- 4. one camera, three cameras ----------------------------------------------------------------
@aio
async def test_one_camera_project_tracks_in_2d_with_a_scale_from_a_known_length(tmp_path, frames):
    project = new_project(tmp_path, frames, cameras=("side",), synced=False)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        assert [v.camera for v in app.views()] == ["side"]
        await seed_by_clicks(pilot, app, 1, cameras=("side",))
        await pilot.press("t")  # one camera: nothing to sync, no question
        await until_idle(pilot, app)
        assert len(project.points(marker=1)) == N_FRAMES
        # a known length: 150 mm between two points 300 px apart -> 0.5 mm per px
        app.cursor["side"] = (100.0, 100.0)
        await pilot.press("c")
        app.cursor["side"] = (340.0, 280.0)
        await pilot.press("c")
        await pilot.pause()
        app.screen.query_one("#answer").value = "150"
        await pilot.press("enter")
        await pilot.pause()
        assert project.get("scale")["side"]["mm_per_px"] == pytest.approx(0.5)
        await pilot.press("right")
        await settle(pilot, app)
        row = next(r for r in app.table_rows() if r.marker == 1)
        x, y = true_xy(1, 1)
        assert np.allclose(row.xy_mm, (0.5 * x, 0.5 * y), atol=0.5)


@aio
async def test_three_cameras_in_a_grid_with_epipolar_curves_from_every_other_view(tmp_path, frames):
    cams = ("side", "front", "top")
    project = new_project(tmp_path, frames, cameras=cams, calibrated=True)
    app = SandtrackApp(project)
    async with app.run_test(size=(150, 50)) as pilot:
        await settle(pilot, app)
        assert [v.camera for v in app.views()] == list(cams)
        regions = [app.view(c).region for c in cams]
        assert regions[0].y == regions[1].y and regions[2].y > regions[0].y  # two above, one below
        await seed_by_clicks(pilot, app, 2, cameras=("side", "front"))
        app.update_overlays()
        curves = app.view("top").overlays.epipolar
        assert len(curves) == 2 and curves[0][1] != curves[1][1]  # one per other view, each its colour
        tx, ty = true_xy(2, 0, "top")
        for curve, _ in curves:
            a, b = curve[:-1], curve[1:]
            t = np.clip(np.sum((np.array([tx, ty]) - a) * (b - a), 1) / np.sum((b - a) ** 2, 1), 0, 1)
            assert np.hypot(*(a + t[:, None] * (b - a) - [tx, ty]).T).min() < 0.041  # measured 0.028 px
        await click_source(pilot, app, "top", tx, ty)
        row = next(r for r in app.table_rows() if r.marker == 2)
        # measured 0.060 mm, 0.039 px
        assert np.linalg.norm(np.array(row.xyz_tri) - true_xyz(2, 0)) < 0.09 and row.residual_px < 0.058
        await pilot.press("tab")
        assert app.active == "side"  # tab goes round every camera
        await pilot.press("t")
        await until_idle(pilot, app)
        assert {c: len(project.points(marker=2, camera=c)) for c in cams} == dict.fromkeys(cams, N_FRAMES)


# -- 5. ids never overlap, the marker list ------------------------------------------------------
def crowd(project, centre=(300.0, 180.0), n=9, spacing=10.0) -> dict[int, tuple[float, float]]:
    """n markers touching each other (10 px beads, 10 px apart) in the front view: positions only."""
    pos = {}
    for k in range(n):
        pos[k + 1] = (centre[0] + spacing * (k % 3), centre[1] + spacing * (k // 3))
    rows = [(0, "front", m, x, y, "manual", 1.0, None, None) for m, (x, y) in pos.items()]
    for m in pos:
        project.add_marker(str(m if m != 9 else "nine"), m)
    project.set_points(rows, "a crowd")
    return pos


def label_runs(labels: dict) -> list[str]:
    """Texts of the runs of label cells, row by row (a run = cells side by side)."""
    runs = []
    for r in sorted({r for r, _ in labels}):
        cols = sorted(c for rr, c in labels if rr == r)
        text = labels[(r, cols[0])][0]
        for a, b in zip(cols, cols[1:], strict=False):
            if b == a + 1:
                text += labels[(r, b)][0]
            else:
                runs.append(text)
                text = labels[(r, b)][0]
        runs.append(text)
    return runs


@contextlib.asynccontextmanager
async def crowd_in_front_view(tmp_path, frames):
    """The app on a crowd of markers, the front view active: (app, pilot, marker positions)."""
    project = new_project(tmp_path, frames)
    pos = crowd(project)
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.press("tab")
        yield app, pilot, pos


@aio
async def test_ids_never_overlap_at_any_zoom(tmp_path, frames):
    async with crowd_in_front_view(tmp_path, frames) as (app, pilot, pos):
        app.cursor["front"] = pos[5]
        for zoom in range(6):  # 1x .. 32x
            await settle(pilot, app)
            v = app.view("front")
            shown = [app._labels[m] for m, (x, y) in pos.items() if v.tf.contains(x, y)]
            assert shown, f"zoom {zoom}: no marker in view"
            assert sorted(label_runs(v._labels)) == sorted(shown), f"zoom {zoom}x: ids overlap or are missing"
            centres = {v.tf.source_to_cell(x, y)[::-1] for x, y in pos.values()}
            assert not centres & set(v._labels), f"zoom {zoom}: an id covers a marker"
            await pilot.press("plus")


@aio
async def test_marker_list_picks_out_of_a_crowd(tmp_path, frames):
    from sandtrack_tui.tui.screens.picker import MarkerPicker

    async with crowd_in_front_view(tmp_path, frames) as (app, pilot, pos):
        app.cursor["front"] = (pos[9][0] + 1, pos[9][1])
        await pilot.press("m")
        await pilot.pause()
        assert isinstance(app.screen, MarkerPicker)
        order = [r.marker for r in app.screen.shown]
        d = [math.dist(pos[m], app.cursor["front"]) for m in order]
        assert order[0] == 9 and d == sorted(d)  # nearest the cursor first
        await pilot.press("down", "enter")
        await pilot.pause()
        assert app.screen is app._main_screen and app.selected == order[1]
        assert app.cursor["front"] == pos[order[1]]
        await pilot.press("m", "slash", "n", "i", "n", "e", "enter", "enter")  # filter by name
        await pilot.pause()
        assert app.selected == 9


@aio
async def test_calibration_screen_takes_a_video_of_every_camera(tmp_path, frames, monkeypatch):
    import sandtrack_tui.calibration.pipeline as pipeline
    from sandtrack_tui.camera import Calibration
    from sandtrack_tui.tui.screens.calibration import CalibrationScreen

    cams = ("side", "front", "top")
    project = new_project(tmp_path, frames, cameras=cams)
    calls = []

    def fake(videos, board, **kw):  # the pipeline's own tests calibrate; here: what the screen hands it
        calls.append(dict(videos))
        return SimpleNamespace(calibration=calibration(cams), report={"reprojection_rmse_px": 0.1},
                               points=None, warnings=[])

    monkeypatch.setattr(pipeline, "calibrate_videos", fake)
    for cam in cams:
        (tmp_path / f"{cam}.mp4").write_bytes(b"")
    (tmp_path / "board.toml").write_text('type = "charuco"\ncolumns = 5\nrows = 4\nsquare_mm = 20.0\n'
                                         'dictionary = "DICT_4X4_50"\n')
    app = SandtrackApp(project)
    async with app.run_test(size=(120, 40)) as pilot:
        await settle(pilot, app)
        await pilot.press("f3")
        await pilot.pause()
        screen = app.screen
        assert isinstance(screen, CalibrationScreen) and screen.cameras == list(cams)
        from textual.widgets import Input

        for k, cam in enumerate(cams):
            screen.query_one(f"#video-{k}", Input).value = str(tmp_path / f"{cam}.mp4")
        screen.query_one("#board", Input).value = str(tmp_path / "board.toml")
        screen.query_one("#points", Input).value = ""
        await pilot.press("ctrl+r")
        await until_idle(pilot, app)
        assert calls and list(calls[0]) == list(cams)
        assert [str(p) for p in calls[0].values()] == [str(tmp_path / f"{c}.mp4") for c in cams]
        assert isinstance(project.calibration(), Calibration) and project.calibration().names == list(cams)


# -- touching beads seeded in one view each, made one marker by a tracking run ---------------------------
@aio
async def test_tracking_all_makes_beads_seen_in_one_view_each_one_marker_and_undo_parts_them(tmp_path):
    from crowd_synth import crowd_project, layer_mm, turned

    project, _clips, ids = crowd_project(tmp_path, turned(layer_mm(), 16, rest=4, deg_per_frame=1.2))
    front, side = ids[("front", 5)], ids[("side", 5)]
    app = SandtrackApp(project)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        app.selected = front
        await pilot.press("home", "r")  # track all forward from frame 0
        await until_idle(pilot, app)
        assert any("11 bead(s) seen in one view each made one marker" in n.message for n in app._notifications)
        marker_ids = [m for m, _ in app.marker_list]
        assert app.selected == side and front not in marker_ids and len(marker_ids) == 12
        assert set(project.points(marker=side).camera) == {"side", "front"}
        await pilot.press("u")  # the whole run, pairing included
        assert front in [m for m, _ in app.marker_list] and set(project.points(marker=side).camera) == {"side"}
    project.close()
