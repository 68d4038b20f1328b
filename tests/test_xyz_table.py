"""XYZ table: sub-frame sync interpolation, statuses, triangulation and MLP rows against exact truth."""

from __future__ import annotations

import copy
import json

import numpy as np
import pandas as pd
import pytest

from conftest import write_clip
from sandtrack_tui.cli import main
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.regression import TrainConfig, train
from sandtrack_tui.regression.synthetic import calibration_points, study_rig
from sandtrack_tui.store import Project
from sandtrack_tui.xyz import XYZ_COLUMNS, compute_xyz, project_calibration, xyz_at_frame, xyz_columns

FPS = 50.0
N_FRAMES = 40
OFFSET_S = 0.0137  # front started 0.685 frames later: every side frame falls between two front frames
START = {1: (-80.0, 40.0, -100.0), 2: (60.0, 20.0, 40.0), 3: (0.0, 70.0, 60.0), 4: (0.0, -250.0, 0.0)}
VELOCITY = {1: (0.0, 0.0, 200.0), 2: (100.0, 0.0, -150.0), 3: (-50.0, 30.0, 100.0), 4: (0.0, 0.0, 0.0)}


def position(marker: int, t: np.ndarray) -> np.ndarray:
    return np.asarray(START[marker]) + np.outer(t, VELOCITY[marker])


@pytest.fixture(scope="module")
def rig():
    return study_rig()


@pytest.fixture(scope="module")
def model_file(rig, tmp_path_factory):
    pts = calibration_points(rig, n_points=4000, seed=2)
    model = train(pts, TrainConfig(hidden=(128, 128), dropout=0.0, epochs=25, batch_size=256, lr=3e-3,
                                   residual=False, patience=25))
    path = tmp_path_factory.mktemp("model") / "model.pt"
    model.save(path)
    return path


@pytest.fixture
def project(tmp_path, rig):
    side = write_clip(tmp_path / "side.mp4", n_frames=N_FRAMES, bframes=0)
    front = write_clip(tmp_path / "front.mp4", n_frames=N_FRAMES, bframes=0)
    proj = Project.create(tmp_path / "exp.sandtrack", {"side": side, "front": front})
    proj.set_calibration(rig)
    proj.set("sync_offset_s", OFFSET_S)
    rows = []
    for m in START:
        proj.add_marker(f"m{m}", m)
        t = np.arange(N_FRAMES) / FPS
        side_px = rig.project_world("side", position(m, t))
        front_px = rig.project_world("front", position(m, t + OFFSET_S))  # front frame j shows side time j/fps + offset
        for i in range(N_FRAMES):
            if not (m == 3 and i == 5):  # side has no point there
                rows.append((i, "side", m, *side_px[i], "tracked"))
            if m == 1 and i == 10:
                rows.append((i, "front", m, None, None, "lost"))
            elif m == 2 and i == 20:
                rows.append((i, "front", m, *front_px[i], "occluded"))
            else:
                rows.append((i, "front", m, *front_px[i], "tracked"))
    proj.set_points(rows, "synthetic tracks")
    yield proj
    proj.close()


def test_triangulation_rows_match_the_true_positions(project):
    table = compute_xyz(project, method="triangulation")
    assert list(table.columns) == XYZ_COLUMNS
    assert len(table) == len(START) * N_FRAMES and set(table["method"]) == {"triangulation"}
    assert np.allclose(table["time_s"], table["frame"] / FPS)
    good = table[table["X_mm"].notna() & (table["xyz_source"] == "interpolated")]
    truth = np.concatenate([position(m, g["time_s"].to_numpy()) for m, g in good.groupby("marker")])
    good = good.sort_values(["marker", "frame"])
    err = np.linalg.norm(good[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - truth, axis=1)
    # markers move 4-5 mm per frame; taking the nearest front frame instead would err by ~1.5 mm
    assert err.max() < 0.0021  # measured 0.0014 mm
    assert good["residual_px"].max() < 0.0018  # measured 0.0012 px
    # every side frame from 1 on has an interpolated front point unless a status says otherwise
    assert len(good) == len(START) * (N_FRAMES - 1) - 2 - 1


def test_statuses_and_interpolation_rules(project):
    t = compute_xyz(project, method="triangulation").set_index(["marker", "frame"])
    # frame 0 lies before the front video started
    assert (t.xs(0, level="frame")["status_front"] == "missing").all()
    # a lost front point spoils the two side frames that interpolate across it, and only those
    for i in (10, 11):
        assert t.loc[(1, i), "status_front"] == "lost" and np.isnan(t.loc[(1, i), "X_mm"])
    assert np.isfinite(t.loc[(1, 9), "X_mm"]) and np.isfinite(t.loc[(1, 12), "X_mm"])
    # an occluded (estimated) front point is used but reported
    assert t.loc[(2, 20), "status_front"] == "occluded" and np.isfinite(t.loc[(2, 20), "X_mm"])
    assert t.loc[(2, 19), "status_front"] == "tracked"
    # a side frame without a side point still gets its row
    assert t.loc[(3, 5), "status_side"] == "missing" and np.isnan(t.loc[(3, 5), "X_mm"])
    assert t.loc[(3, 5), "status_front"] == "tracked" and np.isfinite(t.loc[(3, 5), "xf"])


def test_mlp_rows_beside_triangulation_and_outside_flag(project, model_file):
    project.set("model", {"path": str(model_file)})
    both = compute_xyz(project, method="both")
    assert set(both["method"]) == {"triangulation", "mlp", "mlp_outside"}
    assert len(both) == 2 * len(START) * N_FRAMES
    mlp = both[both["method"].isin(["mlp", "mlp_outside"])]
    # marker 4 sits 250 mm under the sand: outside anything the board covered
    m4 = mlp[(mlp["marker"] == 4) & mlp["X_mm"].notna()]
    assert len(m4) == N_FRAMES - 1 and (m4["method"] == "mlp_outside").all()
    inside = mlp[(mlp["marker"] != 4) & mlp["X_mm"].notna()]
    assert (inside["method"] == "mlp").all()
    truth = np.concatenate([position(m, g["time_s"].to_numpy()) for m, g in inside.groupby("marker")])
    inside = inside.sort_values(["marker", "frame"])
    err = np.linalg.norm(inside[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - truth, axis=1)
    assert err.mean() < 5.4  # a small, briefly trained net; the marker layout spans ~200 mm (measured 3.6)
    assert inside["residual_px"].notna().all()
    nan_policy = compute_xyz(project, method="mlp", outside="nan")
    assert set(nan_policy["method"]) == {"mlp"} and nan_policy.loc[nan_policy["marker"] == 4, "X_mm"].isna().all()
    # the rig states no pixel noise and the points no sd: the triangulation has no sd, the MLP's is unchecked
    assert set(inside["network_check"]) == {"unchecked"} and set(both["network_check"]) == {"unchecked", ""}
    # with one, every MLP row with an sd is checked against the triangulation, the same whether the
    # triangulation rows are asked for or not
    cal = copy.deepcopy(project_calibration(project))
    for cam in cal.cameras.values():
        cam.rmse_px = 0.3
    both = compute_xyz(project, method="both", calibration=cal)
    mlp = both[both["method"] == "mlp"]
    with_sd = mlp["sd_X_mm"].notna()
    assert set(mlp.loc[with_sd, "network_check"]) == {"ok", "inconsistent"}  # measured 2.5 % inconsistent
    assert set(mlp.loc[mlp["X_mm"].isna(), "network_check"]) == {""}
    assert set(both.loc[both["method"] == "triangulation", "network_check"]) == {""}
    alone = compute_xyz(project, method="mlp", calibration=cal)
    pd.testing.assert_frame_equal(alone[alone["method"] == "mlp"].reset_index(drop=True), mlp.reset_index(drop=True))


def test_single_frame_matches_the_full_table(project, model_file):
    project.set("model", {"path": str(model_file)})
    full = compute_xyz(project, method="both")
    for frame in (0, 11, 27, N_FRAMES - 1):
        one = xyz_at_frame(project, frame)
        expect = full[full["frame"] == frame].reset_index(drop=True)
        pd.testing.assert_frame_equal(one, expect)
    assert xyz_at_frame(project, N_FRAMES + 50).empty


def test_explicit_methods_need_their_inputs(project):
    with pytest.raises(SandtrackError, match="no regression model"):
        compute_xyz(project, method="mlp")
    assert set(compute_xyz(project, method="both")["method"]) == {"triangulation"}
    with pytest.raises(SandtrackError, match="unknown method"):
        compute_xyz(project, method="magic")


def test_cli_xyz_frame_and_csv(project, model_file, tmp_path, capsys):
    project.set("model", {"path": str(model_file)})
    path = str(project.path)
    assert main(["xyz", path, "--frame", "12", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frame"] == 12 and len(out["table"]) == 2 * len(START)
    assert set(out["table"][0]) == set(XYZ_COLUMNS)
    assert main(["xyz", path, "-o", str(tmp_path / "xyz.csv"), "--method", "triangulation", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    csv = pd.read_csv(tmp_path / "xyz.csv")
    assert list(csv.columns) == XYZ_COLUMNS and len(csv) == out["rows"] == len(START) * N_FRAMES
    assert out["sd_holds"].startswith("triangulation sd: each tracked point's sd (its match score)")
    # --covariance: the covariances between the axes after the sd, in mm² to 1e-6; the rest as before
    assert main(["xyz", path, "-o", str(tmp_path / "cov.csv"), "--method", "triangulation", "--covariance"]) == 0
    capsys.readouterr()
    cov = pd.read_csv(tmp_path / "cov.csv")
    assert list(cov.columns) == xyz_columns(["side", "front"], covariance=True)
    assert cov.drop(columns=["cov_XY_mm2", "cov_XZ_mm2", "cov_YZ_mm2"]).equals(csv)
    assert cov["cov_XY_mm2"].notna().equals(cov["sd_X_mm"].notna())  # (this rig keeps no noise: no sd)
    assert main(["export", path, "-o", str(tmp_path / "t.csv"), "--covariance"]) == 0
    capsys.readouterr()
    assert {"cov_XY_mm2", "cov_XZ_mm2", "cov_YZ_mm2"} <= set(pd.read_csv(tmp_path / "t.csv").columns)
    assert main(["xyz", path, "--frame", "12"]) == 0
    printed = capsys.readouterr().out
    assert "triangulation" in printed and out["sd_holds"] in printed
    assert main(["xyz", path, "--frame", "3", "--method", "residual"]) == 1
    assert "residual" in capsys.readouterr().err


def test_timeline_from_frame_times_matches_fps_and_never_extrapolates():
    from sandtrack_tui.xyz import Timeline

    cams, fps = ["side", "front"], {"side": 50.0, "front": 50.0}
    by_fps = Timeline(cams, fps, {"front": OFFSET_S}, frames={"side": 30, "front": 30})
    by_times = Timeline(cams, fps, {"front": OFFSET_S}, times={c: np.arange(30) / 50.0 for c in cams})
    i = np.arange(30)
    a, b = by_fps.position("front", i), by_times.position("front", i)
    assert np.allclose(a[1:], i[1:] - 0.685) and np.allclose(b[1:], a[1:])
    assert np.isnan(a[0]) and np.isnan(b[0])  # before the front's first frame
    late = Timeline(cams, fps, {"front": -0.1}, frames={"side": 30, "front": 30})  # front started 5 frames earlier
    assert np.allclose(late.position("front", np.array([0, 24])), [5, 29]) and np.isnan(late.position("front", 25))
    assert np.array_equal(by_fps.reference_index("front", np.array([0, 9])), [1, 10])


def test_three_cameras_and_one_camera_end_to_end(tmp_path, capsys):
    """A project of three cameras (the front one half a frame late) gives one table with every camera's
    pixels, XYZ from all three, and exports it (CSV, Parquet, DLTdv cam1..cam3); one camera gives x, y
    in mm through its scale, or one line asking for the scale."""
    import cv2

    from sandtrack_tui.scale import set_scale
    from sandtrack_tui.xyz import xyz_columns
    from tui_synth import calibration, true_xyz

    cams = ["side", "front", "top"]
    for cam in cams:
        (tmp_path / cam).mkdir()
        for f in range(4):
            cv2.imwrite(str(tmp_path / cam / f"{f}.png"), np.zeros((360, 640, 3), np.uint8))
    cal = calibration(cams)
    with Project.create(tmp_path / "three.sandtrack", {c: tmp_path / c for c in cams}) as proj:
        proj.set("sync_offset_s", 0.01)  # the front camera started half a frame later (50 fps)
        proj.set_calibration(cal)
        rows = []
        for f in range(4):
            for cam in cams:
                t = f + (0.5 if cam == "front" else 0.0)
                p = true_xyz(2, 0) + t * (true_xyz(2, 1) - true_xyz(2, 0))
                rows.append((f, cam, 2, *map(float, cal.cameras[cam].project(p[None])[0]), "tracked", None, None, None))
        proj.set_points(rows, "tracks")
    path = str(tmp_path / "three.sandtrack")
    assert main(["xyz", path, "-o", str(tmp_path / "xyz.csv")]) == 0
    table = pd.read_csv(tmp_path / "xyz.csv")
    assert list(table.columns) == xyz_columns(cams) and set(table["method"]) == {"triangulation"}
    assert table["status_front"].tolist() == ["missing", "tracked", "tracked", "tracked"]  # frame 0: before it
    truth = np.array([true_xyz(2, f) for f in table["frame"]])
    err = np.linalg.norm(table[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - truth, axis=1)
    # frame 0 from side and top only (measured 0.0005 mm, 0.0001 px)
    assert err.max() < 0.00077 and table["residual_px"].max() < 0.00015
    assert main(["export", path, "-o", str(tmp_path / "t.parquet")]) == 0
    assert list(pd.read_parquet(tmp_path / "t.parquet").columns) == xyz_columns(cams)
    assert main(["export", path, "-o", str(tmp_path / "trial"), "--format", "dltdv"]) == 0
    xy = pd.read_csv(tmp_path / "trial-xypts.csv")
    assert list(xy.columns) == [f"pt1_cam{k}_{a}" for k in (1, 2, 3) for a in "XY"]
    assert np.allclose(xy["pt1_cam3_X"], table["x_top"]) and np.allclose(xy["pt1_cam3_Y"], 360 - table["y_top"])
    assert list(pd.read_csv(tmp_path / "trial-offsets.csv").columns) == ["cam1_offset", "cam2_offset", "cam3_offset"]
    capsys.readouterr()

    with Project.create(tmp_path / "one.sandtrack", {"top": tmp_path / "top"}) as proj:
        proj.set_points([(1, "top", 5, 100.0, 50.0, "tracked", None, None, None)], "a point")
    one = str(tmp_path / "one.sandtrack")
    assert main(["xyz", one, "--frame", "1"]) == 1
    assert "scale" in capsys.readouterr().err
    with Project.open(one) as proj:
        set_scale(proj, "top", 0.25, "known length")
    assert main(["xyz", one, "--frame", "1", "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["table"][0]
    assert row["method"] == "scale" and (row["X_mm"], row["Y_mm"]) == (25.0, 12.5) and row["Z_mm"] is None
