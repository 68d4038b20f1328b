"""Pixels always leave: a project whose cameras give no millimetres (one camera without a scale, two
cameras without a calibration or network) exports its pixel trajectories in every format, mm columns empty,
with one line saying why; a method asked for by name still refuses."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.cli import main
from sandtrack_tui.store import Project

FRAMES, HEIGHT = 4, 48


def _project(tmp_path, cameras) -> tuple:
    """A project of image folders with two markers per camera, their true pixels known."""
    videos = {}
    for cam in cameras:
        (tmp_path / cam).mkdir()
        for f in range(FRAMES):
            cv2.imwrite(str(tmp_path / cam / f"{f:03d}.png"), np.full((HEIGHT, 64, 3), 128, np.uint8))
        videos[cam] = tmp_path / cam
    truth = {(f, cam, m): (10.25 + 3 * f + 20 * m + k, 30.5 - 2 * f + k)
             for f in range(FRAMES) for k, cam in enumerate(cameras) for m in (1, 2)}
    path = tmp_path / "p.sandtrack"
    with Project.create(path, videos) as proj:
        proj.set("sync_offset_s", 0.0)
        proj.set_points([(f, cam, m, x, y, "tracked") for (f, cam, m), (x, y) in truth.items()], "points")
    return path, truth


@pytest.mark.parametrize("cameras", [("side",), ("side", "front")])
def test_tidy_csv_and_parquet_hold_the_pixels_and_say_why(tmp_path, capsys, cameras):
    path, truth = _project(tmp_path, cameras)
    for suffix in (".csv", ".parquet"):
        out = tmp_path / f"traj{suffix}"
        assert main(["export", str(path), "-o", str(out), "--json"]) == 0
        captured = capsys.readouterr()
        result = json.loads(captured.out)
        assert result["pixels_only"].startswith("pixel trajectories only")
        why = [line for line in captured.err.splitlines() if "pixel trajectories only" in line]
        assert len(why) == 1 and ("without a scale" in why[0] if len(cameras) == 1 else "calibration" in why[0])
        df = pd.read_csv(out) if suffix == ".csv" else pd.read_parquet(out)
        assert len(df) == 2 * FRAMES and set(df["method"]) == {"pixels"}
        assert df[["X_mm", "Y_mm", "Z_mm", "residual_px"]].isna().all().all()
        for cam, (cx, cy) in zip(cameras, (("xs", "ys"), ("xf", "yf")), strict=False):
            for r in df.itertuples():
                assert (getattr(r, cx), getattr(r, cy)) == pytest.approx(truth[(r.frame, cam, r.marker)], abs=1e-6)


def test_dltdv_holds_the_pixels_and_empty_xyz(tmp_path, capsys):
    path, truth = _project(tmp_path, ("side", "front"))
    assert main(["export", str(path), "-o", str(tmp_path / "trial"), "--format", "dltdv"]) == 0
    assert "pixel trajectories only" in capsys.readouterr().err
    xy = pd.read_csv(tmp_path / "trial-xypts.csv")
    xyz = pd.read_csv(tmp_path / "trial-xyzpts.csv")
    assert len(xy) == FRAMES and xyz.isna().all().all()
    for f in range(FRAMES):
        for n, m in enumerate((1, 2), start=1):
            for k, cam in enumerate(("side", "front"), start=1):
                x, y = truth[(f, cam, m)]
                assert xy[f"pt{n}_cam{k}_X"][f] == pytest.approx(x)
                assert xy[f"pt{n}_cam{k}_Y"][f] == pytest.approx(HEIGHT - y)  # DLTdv's y is up


def test_a_method_asked_by_name_still_refuses(tmp_path, capsys):
    path, _ = _project(tmp_path, ("side", "front"))
    assert main(["export", str(path), "-o", str(tmp_path / "t.csv"), "--method", "triangulation"]) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if "error" in line]
    assert len(err) == 1 and "no calibration" in err[0] and not (tmp_path / "t.csv").exists()


def test_the_ui_export_writes_the_pixels_and_says_why(tmp_path):
    from conftest import POLL_LIMIT_S
    from sandtrack_tui.tui.app import SandtrackApp
    from test_tui_app import aio, settle

    path, _ = _project(tmp_path, ("side",))
    out = tmp_path / "ui.csv"

    @aio
    async def run():
        app = SandtrackApp(path)
        async with app.run_test(size=(100, 30)) as pilot:
            await settle(pilot, app)
            app.clear_notifications()
            await pilot.press("e")
            await pilot.pause()
            app.screen.query_one("#path").value = str(out)
            await pilot.press("ctrl+r")
            await settle(pilot, app, lambda: app.bg_task is None and out.exists(), timeout=POLL_LIMIT_S)
            await pilot.pause()
            return [n.message for n in app._notifications]

    notes = run()
    assert any("pixel trajectories only" in n and "without a scale" in n for n in notes), notes
    assert set(pd.read_csv(out)["method"]) == {"pixels"}
