"""End to end on a calibrated synthetic project: tracks -> `sandtrack export` (real XYZ) -> DLTdv
-> `sandtrack compare` against a DEM run made from the true motion, shifted in time."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from conftest import write_clip
from sandtrack_tui import dem as D
from sandtrack_tui import trajectories as tr
from sandtrack_tui.cli import main
from sandtrack_tui.regression.synthetic import study_rig
from sandtrack_tui.store import Project

FPS = 50.0
N = 60
OFFSET_S = 0.0137
SHIFT_S = 0.0833  # DEM time t = experiment time t + shift


def position(m: int, t: np.ndarray) -> np.ndarray:
    """At rest, then pushed along X from t = 0.3 s (smoothly), marker-dependent."""
    u = np.clip(t - 0.3, 0, None)
    s = 1 - np.exp(-4 * u)
    return np.column_stack([-60 + 40 * m + 50 * s, 10 * m + 8 * s, 20 - 5 * m + 3 * s])


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    d = tmp_path_factory.mktemp("pipe")
    rig = study_rig()
    side = write_clip(d / "side.mp4", n_frames=N, bframes=0)
    front = write_clip(d / "front.mp4", n_frames=N, bframes=0)
    proj = Project.create(d / "exp.sandtrack", {"side": side, "front": front})
    proj.set_calibration(rig)
    proj.set("sync_offset_s", OFFSET_S)
    rows = []
    t = np.arange(N) / FPS
    for m in (1, 2, 3):
        proj.add_marker(f"m{m}", m)
        sp = rig.project_world("side", position(m, t))
        fp = rig.project_world("front", position(m, t + OFFSET_S))
        rows += [(i, "side", m, *sp[i], "tracked") for i in range(N)]
        rows += [(i, "front", m, *fp[i], "tracked") for i in range(N)]
    proj.set_points(rows, "synthetic tracks")
    proj.close()
    return d / "exp.sandtrack"


def test_export_compare_chain(project, tmp_path, capsys):
    out = tmp_path / "traj.csv"
    assert main(["export", str(project), "-o", str(out), "--method", "triangulation", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    # the study rig's calibration keeps no parameter covariance: its sd is the tracked pixels' part alone
    assert summary["sd_holds"] == ("triangulation sd: each tracked point's sd (its match score) only: the "
                                   "calibration file keeps no parameter covariance (calibrate from videos or "
                                   "points to have it)")
    df = pd.read_csv(out)
    assert list(df.columns) == tr.TIDY_COLUMNS
    good = df.dropna(subset=["X_mm"])
    truth = np.concatenate([position(m, g["time_s"].to_numpy()) for m, g in good.groupby("marker")])
    err = np.linalg.norm(good.sort_values(["marker", "frame"])[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - truth, axis=1)
    assert np.median(err) < 0.005  # mm: the exported XYZ is the true motion (measured 0.0033)

    # DLTdv export: side pixels of point 2 (= marker 2) as stored, y flipped by the video height
    assert main(["export", str(project), "-o", str(tmp_path / "trial"), "--format", "dltdv",
                 "--method", "triangulation"]) == 0
    capsys.readouterr()
    with Project.open(project) as p:
        height = p.videos()["side"].height
        side_pts = p.points(camera="side", marker=2)
    xy = pd.read_csv(tmp_path / "trial-xypts.csv")
    np.testing.assert_allclose(xy["pt2_cam1_X"], side_pts["x_px"], atol=1e-4)
    np.testing.assert_allclose(height - xy["pt2_cam1_Y"], side_pts["y_px"], atol=1e-4)
    xyz = pd.read_csv(tmp_path / "trial-xyzpts.csv")
    ok = xyz["pt2_X"].notna().to_numpy()
    assert ok.sum() >= N - 1  # the first side frame precedes the front video's start
    # (front pixels are interpolated between frames: < 1 mm off at the motion's kink)
    np.testing.assert_allclose(xyz["pt2_X"][ok], position(2, np.arange(N) / FPS)[ok, 0], atol=1.0)

    # DEM run = true motion on its own clock (metres), particle 3 drifting
    td = np.arange(-0.2, 1.6, 0.005)
    rows = []
    for m in (1, 2, 3):
        p = position(m, td + SHIFT_S)
        if m == 3:
            p[:, 2] += 25.0 * np.clip(td + SHIFT_S - 0.3, 0, None)
        rows.append(pd.DataFrame({"particle_id": m, "time_s": td, "X_mm": p[:, 0], "Y_mm": p[:, 1], "Z_mm": p[:, 2]}))
    D.write_exchange_csv(pd.concat(rows), tmp_path / "dem.csv", units="m")
    assert main(["compare", str(out), str(tmp_path / "dem.csv"), "--json", "--flag-mm", "1"]) == 0
    res = json.loads(capsys.readouterr().out)["runs"][0]
    assert abs(res["time_shift_s"] - SHIFT_S) * FPS < 0.061  # frames, measured 0.041
    assert res["summary"]["flagged_markers"] == [3]
    # the project itself as EXPERIMENT gives the same alignment
    assert main(["compare", str(project), str(tmp_path / "dem.csv"), "--method", "triangulation", "--json",
                 "--flag-mm", "1"]) == 0
    res2 = json.loads(capsys.readouterr().out)["runs"][0]
    assert res2["time_shift_s"] == pytest.approx(res["time_shift_s"], abs=1e-3)
