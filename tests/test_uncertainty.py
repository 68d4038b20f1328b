"""Every XYZ with its sd: the triangulation's first-order sd covers the true errors of Monte Carlo
pixel noise and calibration errors on a synthetic rig; the calibration's covariance survives the file;
a seed frame gives nearest-frame XYZ; the sd columns reach the export; the live table shows X ± sd."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import SAMPLE_DATA, ellipsoid_coverage, write_clip
from sandtrack_tui.camera import Calibration, Camera, CameraUncertainty
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.regression.spread import coverage
from sandtrack_tui.regression.synthetic import study_rig
from sandtrack_tui.store import Project
from sandtrack_tui.tracking.pixel_sd import point_sd_px
from sandtrack_tui.xyz import COV_COLUMNS, SD_COLUMNS, compute_xyz, triangulate_with_sd
from sandtrack_tui.xyz_pixels import camera_columns, xyz_from_pixels

Z95 = 1.959963984540054
VOLUME = ((-150, 150), (0, 150), (-150, 150))


def _points(rng, n):
    return np.stack([rng.uniform(*VOLUME[k], n) for k in range(3)], axis=1)


def _rig(rmse=0.5):
    rig = study_rig()
    for c in rig.cameras.values():
        c.rmse_px = rmse
    return rig


def test_pixel_noise_alone_is_covered_95_pct():
    """Each point's own pixel sd (0.2-1.5 px in one camera, 0.35 px in the other): ±1.96 sd holds 95 %."""
    rig = _rig()
    rng = np.random.default_rng(1)
    n = 20_000
    X = _points(rng, n)
    sd = {"side": rng.uniform(0.2, 1.5, n), "front": np.full(n, 0.35)}
    pix = {c: rig.project_world(c, X) + rng.normal(size=(n, 2)) * sd[c][:, None] for c in sd}
    xyz, _, full = triangulate_with_sd(rig, pix, sd, refine=True, covariance=True)
    out = full[:, :3]
    cov = coverage(xyz - X, out)
    assert np.all(np.abs(cov - 0.95) < 0.006), cov  # measured 0.950 per axis (binomial sd 0.0015)
    # the axes' errors are correlated: the 95 % ellipsoid of the full covariance holds 95 % in 3-D (measured
    # 0.947), the sd alone read as independent axes less (measured 0.942, 5 binomial sd below)
    assert abs(ellipsoid_coverage(xyz - X, full) - 0.95) < 0.006
    assert ellipsoid_coverage(xyz - X, np.hstack([out, np.zeros_like(out)])) < 0.945
    # the sd follows the pixels': the noisy half of the side camera gives larger sd
    noisy = sd["side"] > 0.85
    assert np.median(out[noisy, 2]) > 1.3 * np.median(out[~noisy, 2])


def test_calibration_errors_are_covered_only_with_their_covariance():
    """Cameras drawn around the truth from a known parameter covariance (pose, camera matrix, lens): the
    XYZ sd covers the errors only when that covariance is propagated."""
    names = ["rx", "ry", "rz", "tx", "ty", "tz", "fx", "fy", "cx", "cy", "d0", "d1"]
    sd_par = np.array([4e-4, 4e-4, 4e-4, 0.4, 0.4, 0.8, 2.0, 2.0, 1.5, 1.5, 2e-3, 2e-3])
    rng = np.random.default_rng(2)
    true = _rig(rmse=0.2)
    cov = {}
    for c in true.cameras:
        A = rng.normal(size=(len(names), len(names))) * 0.3 + np.eye(len(names))
        C = A @ A.T
        d = np.sqrt(np.diag(C))
        cov[c] = (C / np.outer(d, d)) * np.outer(sd_par, sd_par)
    errs, with_cal, without, fulls = [], [], [], []
    for _ in range(400):
        est = Calibration({n: _drawn(cam, names, rng.multivariate_normal(np.zeros(len(names)), cov[n]))
                           for n, cam in true.cameras.items()}, true.world_from_rig,
                          uncertainty={n: CameraUncertainty(names, cov[n]) for n in true.cameras})
        X = _points(rng, 20)
        pix = {c: true.project_world(c, X) + rng.normal(0, 0.2, (len(X), 2)) for c in true.cameras}
        sd = {c: np.full(len(X), 0.2) for c in pix}
        xyz, _, full = triangulate_with_sd(est, pix, sd, refine=True, covariance=True)
        s1 = full[:, :3]
        fulls.append(full)
        est.uncertainty = {}
        _, _, s0 = triangulate_with_sd(est, pix, sd, refine=True)
        errs.append(xyz - X)
        with_cal.append(s1)
        without.append(s0)
    e, s1, s0 = np.concatenate(errs), np.concatenate(with_cal), np.concatenate(without)
    assert np.all(np.abs(coverage(e, s1) - 0.95) < 0.03), coverage(e, s1)  # measured 0.951 / 0.950 / 0.955
    assert np.all(coverage(e, s0) < 0.4)  # the pixels alone: far too narrow (measured 0.16-0.21)
    # in 3-D, the full covariance's 95 % ellipsoid: measured 0.939 (the 20 points of a draw share its cameras:
    # about 400 independent samples, sd 0.011)
    assert abs(ellipsoid_coverage(e, np.concatenate(fulls)) - 0.95) < 0.025


def _drawn(cam: Camera, names, delta) -> Camera:
    rvec, tvec, K, d = cam.rvec.copy(), cam.tvec.copy(), cam.matrix.copy(), np.zeros(5)
    d[:len(cam.distortion)] = cam.distortion
    for name, v in zip(names, delta, strict=True):
        if name[0] == "r":
            rvec["xyz".index(name[1])] += v
        elif name[0] == "t":
            tvec["xyz".index(name[1])] += v
        elif name in ("fx", "fy", "cx", "cy"):
            K[{"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}[name]] += v
        else:
            d[int(name[1:])] += v
    return Camera(cam.name, cam.width, cam.height, K, d, rvec, tvec, rmse_px=cam.rmse_px)


def test_the_calibration_file_keeps_the_covariance_and_older_files_load_without(tmp_path):
    rig = _rig()
    C = np.diag([1e-8, 2e-8, 3e-8, 0.1, 0.2, 0.3])
    rig.uncertainty = {"front": CameraUncertainty(["rx", "ry", "rz", "tx", "ty", "tz"], C, 0.21)}
    rig.save(tmp_path / "cal.toml")
    back = Calibration.load(tmp_path / "cal.toml")
    assert back.uncertainty["front"].parameters == ["rx", "ry", "rz", "tx", "ty", "tz"]
    assert np.allclose(back.uncertainty["front"].covariance, C) and back.uncertainty["front"].sigma_px == 0.21
    old = Calibration.load(SAMPLE_DATA / "ground_truth" / "cameras.toml")
    assert old.uncertainty == {}
    bad = (tmp_path / "cal.toml").read_text().replace("sigma_px = 0.21", "sigma_px = 0.21\ncovariance = [[1, 2]]")
    bad = bad.replace("covariance = [\n", "old_covariance = [\n", 1)
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(SandtrackError, match="uncertainty of camera front: malformed"):
        Calibration.load(tmp_path / "bad.toml")


def test_pixels_csv_reads_each_cameras_sd(tmp_path):
    rig = _rig(rmse=0.3)
    X = _points(np.random.default_rng(3), 50)
    df = pd.DataFrame({"xs": 0.0, "ys": 0.0, "xf": 0.0, "yf": 0.0}, index=range(len(X)))
    df[["xs", "ys"]], df[["xf", "yf"]] = rig.project_world("side", X), rig.project_world("front", X)
    base, _ = xyz_from_pixels(df, camera_columns(df.columns), rig, method="triangulation")
    # asked for, the covariances between the axes follow the sd; an input column of that name is kept aside
    full, notes = xyz_from_pixels(df.assign(cov_XY_mm2=1.0), camera_columns(df.columns), rig,
                                  method="triangulation", covariance=True)
    assert not set(COV_COLUMNS) & set(base.columns) and list(full.columns).index("cov_XY_mm2") == \
        list(full.columns).index("sd_Z_mm") + 1
    assert "cov_XY_mm2_input" in full.columns and any("cov_XY_mm2_input" in n for n in notes)
    assert np.array_equal(full[list(SD_COLUMNS)].to_numpy(), base[list(SD_COLUMNS)].to_numpy())
    doubled, _ = xyz_from_pixels(df.assign(sd_px=2 * 0.3 / np.sqrt(2)), camera_columns(df.columns), rig,
                                 method="triangulation")
    one, _ = xyz_from_pixels(df.assign(sd_px_front=0.0, sd_px_side=0.3 / np.sqrt(2)), camera_columns(df.columns),
                             rig, method="triangulation")
    s0, s2, s1 = (t[list(SD_COLUMNS)].to_numpy() for t in (base, doubled, one))
    assert np.isfinite(s0).all() and np.allclose(s2, 2 * s0)  # the RMSE per axis is the default
    assert (s1 < s0).all()  # a noise-free front camera


def test_xyz_says_what_the_sd_holds(tmp_path):
    from sandtrack_tui.camera import RigUncertainty

    rig = _rig(rmse=0.3)
    X = _points(np.random.default_rng(4), 20)
    df = pd.DataFrame({"xs": 0.0, "ys": 0.0, "xf": 0.0, "yf": 0.0}, index=range(len(X)))
    df[["xs", "ys"]], df[["xf", "yf"]] = rig.project_world("side", X), rig.project_world("front", X)

    def told(cal, table=df):
        out, notes = xyz_from_pixels(table, camera_columns(table.columns), cal, method="triangulation")
        return out[list(SD_COLUMNS)].to_numpy(), next(n for n in notes if n.startswith("triangulation sd:"))

    bare, note = told(rig)
    assert note.endswith("only: the calibration file keeps no parameter covariance (calibrate from videos or "
                         "points to have it)") and "each camera's pixel noise" in note
    assert "each row's sd_px" in told(rig, df.assign(sd_px=0.2))[1]
    names = ["rx", "ry", "rz", "tx", "ty", "tz"]
    rig.uncertainty = {"front": CameraUncertainty(names, np.diag([1e-8] * 3 + [0.5] * 3))}
    front, note = told(rig)
    assert "each camera's parameter covariance alone" in note and note.endswith("none for side)")
    assert (front > bare).all()
    joint = np.kron(np.eye(2), np.diag([1e-8] * 3 + [0.5] * 3))
    params = [f"{c}/{p}" for c in ("side", "front") for p in names]
    rig.rig_uncertainty = RigUncertainty(params, joint, np.zeros((6, 12)), np.zeros((6, 6)))
    assert told(rig)[1].endswith("cameras together (world = first camera)")
    rig.rig_uncertainty = RigUncertainty(params, joint, np.zeros((6, 12)), np.eye(6) * 0.01)
    both, note = told(rig)
    assert note.endswith("cameras together with the world frame's") and (both > front).all()


def test_many_rows_on_several_threads_give_the_same_xyz_and_sd(monkeypatch):
    import sandtrack_tui.cores
    import sandtrack_tui.xyz as xyz_module

    rig = _rig(rmse=0.3)
    names = ["rx", "ry", "rz", "tx", "ty", "tz", "fx", "fy", "cx", "cy", "d0"]
    rig.uncertainty = {c: CameraUncertainty(names, np.eye(len(names)) * 1e-6) for c in rig.cameras}
    rng = np.random.default_rng(5)
    X = _points(rng, 997)
    pixels = {c: rig.project_world(c, X) + rng.normal(0, 0.3, (len(X), 2)) for c in ("side", "front")}
    pixels["front"][::7] = np.nan
    sd = {"side": rng.uniform(0.05, 0.5, (len(X), 2)), "front": 0.2}
    one = triangulate_with_sd(rig, pixels, sd, True)
    monkeypatch.setattr(xyz_module, "PARALLEL_ROWS", 100)
    monkeypatch.setattr(sandtrack_tui.cores, "usable_cores", lambda: 3)
    three = triangulate_with_sd(rig, pixels, sd, True)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(one, three, strict=True))
    assert np.isfinite(one[2][1:7]).all() and np.isnan(one[2][::7]).all()  # one camera: no XYZ, no sd


def test_pixel_sd_of_the_tracker_by_status():
    sd = point_sd_px([0.97, 0.90, 0.9, 0.9, 0.9], ["tracked", "tracked", "manual", "occluded", "interpolated"])
    assert 0.08 < sd[0] < sd[1] < 0.3 and np.isnan(sd[2]) and np.isinf(sd[3:]).all()


FPS = 50.0
OFFSET_S = 0.011  # front frame j shows side time j / fps + offset: side frame k lies between front k-1 and k


@pytest.fixture
def seeded(tmp_path):
    rig = _rig(rmse=0.2)
    side = write_clip(tmp_path / "side.mp4", n_frames=6, bframes=0)
    front = write_clip(tmp_path / "front.mp4", n_frames=6, bframes=0)
    proj = Project.create(tmp_path / "exp.sandtrack", {"side": side, "front": front})
    proj.set_calibration(rig)
    proj.set("sync_offset_s", OFFSET_S)
    proj.add_marker("m1", 1)

    def at(t):
        return np.array([[20.0, 60.0, -30.0]]) + np.outer(t, [150.0, 0.0, 50.0])

    yield proj, rig, at
    proj.close()


def test_a_seed_frame_gets_xyz_from_the_nearest_frame(seeded):
    proj, rig, at = seeded
    k = 2  # side frame 2 (t = 0.04 s) falls between front frames 1 and 2; front is seeded at 2 only
    proj.set_points([(k, "side", 1, *rig.project_world("side", at([k / FPS]))[0], "manual"),
                     (k, "front", 1, *rig.project_world("front", at([k / FPS + OFFSET_S]))[0], "manual")], "seed")
    row = compute_xyz(proj, method="triangulation").set_index("frame").loc[k]
    assert row["xyz_source"] == "nearest_frame" and np.isfinite(row[["X_mm", "Y_mm", "Z_mm"]].astype(float)).all()
    assert row[list(SD_COLUMNS)].isna().all()  # the motion over the offset is not known yet: no sd
    # the front track goes on: its speed sets how far the nearest frame may be off, and the sd covers it
    j = np.array([3, 4])
    front = rig.project_world("front", at(j / FPS + OFFSET_S))
    proj.set_points([(int(f), "front", 1, *p, "tracked") for f, p in zip(j, front, strict=True)], "track")
    table = compute_xyz(proj, method="triangulation").set_index("frame")
    row = table.loc[k]
    err = np.abs(row[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float) - at([k / FPS])[0])
    sd = row[list(SD_COLUMNS)].to_numpy(float)
    assert row["xyz_source"] == "nearest_frame" and np.isfinite(sd).all()
    assert err.max() > 0.3 and (err <= Z95 * sd).all()  # off by the motion, and honest about it
    assert table.loc[3, "xyz_source"] == "interpolated"


def test_sd_and_source_columns_reach_csv_and_parquet(seeded, tmp_path):
    from sandtrack_tui.trajectories import export, trajectory_table

    proj, rig, at = seeded
    rows = []
    for i in range(1, 6):
        rows.append((i, "side", 1, *rig.project_world("side", at([i / FPS]))[0], "tracked", 0.95, 20.0, 1.0))
        rows.append((i, "front", 1, *rig.project_world("front", at([i / FPS + OFFSET_S]))[0], "tracked", 0.95,
                     20.0, 1.0))
    proj.set_points(rows, "tracks")
    table = trajectory_table(proj, method="triangulation")
    with_cov = trajectory_table(proj, method="triangulation", covariance=True)
    assert not set(COV_COLUMNS) & set(table.columns)
    assert with_cov.drop(columns=list(COV_COLUMNS)).equals(table)  # the same table, the covariances beside
    for fmt, name in (("csv", "t.csv"), ("parquet", "t.parquet")):
        export(with_cov, tmp_path / name, fmt)
        back = pd.read_csv(tmp_path / name) if fmt == "csv" else pd.read_parquet(tmp_path / name)
        assert {*SD_COLUMNS, *COV_COLUMNS, "xyz_source"} <= set(back.columns)
        measured = back[back["X_mm"].notna()]
        assert len(measured) >= 4 and np.isfinite(measured[list(SD_COLUMNS)].to_numpy()).all()
        c = measured[list(COV_COLUMNS)].to_numpy()
        s = measured[list(SD_COLUMNS)].to_numpy()
        rho = c / np.stack([s[:, 0] * s[:, 1], s[:, 0] * s[:, 2], s[:, 1] * s[:, 2]], axis=1)
        assert np.isfinite(c).all() and (np.abs(rho) < 1).all() and (np.abs(rho) > 0.01).any()
    # the command line's XYZ table: the same covariances, in mm² to 1e-6
    from sandtrack_tui.cli import main

    assert main(["xyz", str(proj.path), "-o", str(tmp_path / "x.csv"), "--method", "triangulation",
                 "--covariance"]) == 0
    cli = pd.read_csv(tmp_path / "x.csv")
    got, want = cli[list(COV_COLUMNS)].to_numpy(), with_cov[list(COV_COLUMNS)].to_numpy()
    assert np.isfinite(got).sum() >= 12 and np.allclose(got, want, atol=5e-7, equal_nan=True)
    # a tracked point's sd comes from its match score (0.95: 0.155 px per axis), not the camera's 0.2 px RMSE
    sd_tracked = table.loc[table["X_mm"].notna(), "sd_Z_mm"].median()
    proj.set_points([(r[0], r[1], r[2], r[3], r[4], "tracked", 0.80, 20.0, 1.0) for r in rows], "worse matches")
    worse = trajectory_table(proj, method="triangulation")
    assert worse.loc[worse["X_mm"].notna(), "sd_Z_mm"].median() > 2 * sd_tracked



@pytest.mark.skipif(not (SAMPLE_DATA / "model.pt").is_file(), reason="sample_data/ is not in this checkout")
def test_live_table_shows_xyz_plus_minus_sd_right_after_a_seed(tmp_path):
    """One seed per camera (the front at its nearest frame only): the table shows XYZ at once, marked
    "~" (nearest frame) with "±?" (no motion known yet); with the front frames around, a number after ±."""
    from sandtrack_tui.cli.cmd_tui import sample_project
    from sandtrack_tui.tracking.run import seed_marker
    from sandtrack_tui.tui.app import SandtrackApp
    from test_tui_app import aio, settle

    side = pd.read_csv(SAMPLE_DATA / "ground_truth" / "markers_side.csv")
    front = pd.read_csv(SAMPLE_DATA / "ground_truth" / "markers_front.csv")

    @aio
    async def run():
        app = SandtrackApp(sample_project(SAMPLE_DATA, tmp_path / "sample.sandtrack"))
        async with app.run_test(size=(220, 55)) as pilot:
            await settle(pilot, app)
            first, _ = app.common_range()
            app.go_to(first + 5)
            marker, f = 3, app.frame
            s = side[(side.frame == f) & (side.marker == marker)].iloc[0]
            seed_marker(app.project, marker, "side", f, s.x_px, s.y_px)
            j = app.cam_index("front")
            t = front[(front.frame == j) & (front.marker == marker)].iloc[0]
            seed_marker(app.project, marker, "front", j, t.x_px, t.y_px)
            app.after_edit()
            table = app._w["table"]

            def cell() -> str:
                return str(table.get_row(str(marker))[5]) if len(table.rows) == 1 else "—"

            await settle(pilot, app, lambda: cell() != "—")
            assert cell().startswith("~") and cell().endswith("±?")
            for k in (j - 1, j + 1):  # the front track on either side: interpolated, the sd known
                b = front[(front.frame == k) & (front.marker == marker)].iloc[0]
                seed_marker(app.project, marker, "front", k, b.x_px, b.y_px)
            app.after_edit()
            await settle(pilot, app, lambda: "±?" not in cell())
            value = cell().split("±")
            assert not value[0].startswith("~") and 0 < float(value[1]) < 1.0

    run()
