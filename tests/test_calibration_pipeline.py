"""End-to-end calibration on rendered board images through known cameras (exact truth), the CLI,
and the messages for bad input."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.board import BoardSpec
from sandtrack_tui.calibration.pipeline import calibrate_videos
from sandtrack_tui.calibration.report import relative_pose_errors
from sandtrack_tui.calibration.synthetic import write_session
from sandtrack_tui.calibration.world_uncertainty import SHARED_VIEW_ERROR
from sandtrack_tui.camera import Calibration
from sandtrack_tui.cli import main
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.triangulation import triangulate
from sandtrack_tui.triangulation_sd import camera_noise_px

# synthetic.stereo_rig's lenses, for the tests whose subject is not the lens choice
TRUE_LENSES = {"side": "tangential", "front": "tangential"}


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    folder = tmp_path_factory.mktemp("calib_session")
    s = write_session(folder, n_views=22, seed=5)
    s["folder"] = folder
    return s


@pytest.fixture(scope="module")
def result(session):
    return calibrate_videos(session["videos"], session["board"], reference_frame=0, with_points=True)


def test_recovers_true_cameras(session, result):
    err = relative_pose_errors(result.calibration, session["truth"])
    # measured: focal 0.021 %, principal point 1.06 px, 0.064 deg, 0.44 mm; reprojection 0.020 px, board 0.023 mm
    assert err["focal_rel_err"] < 3.2e-4
    assert err["principal_point_err_px"] < 1.6
    assert err["rotation_err_deg"] < 0.1
    assert err["translation_err_mm"] < 0.66
    assert result.report["reprojection_rmse_px"] < 0.03
    assert result.report["board_rmse_mm"] < 0.035


def test_the_image_region_the_board_covered_is_kept(session, result, tmp_path):
    """Each camera's region is the hull of its corners in the bundle adjustment: every calibration point lies
    inside it, an image corner the board never reached outside."""
    from sandtrack_tui.calibration.region import region_labels

    cal = result.calibration
    assert set(cal.regions) == {"side", "front"}
    for n in ("side", "front"):
        assert 10.0 < result.report["per_camera"][n]["calibrated_region_pct"] < 100.0
    pts = result.points
    pix = {"side": pts[["xs", "ys"]].to_numpy(float), "front": pts[["xf", "yf"]].to_numpy(float)}
    assert set(region_labels(cal, pix, len(pts))) == {"inside"}
    corner = {"side": np.array([[2.0, 2.0]]), "front": pix["front"][:1]}
    assert list(region_labels(cal, corner, 1)) == ["outside"]
    cal.save(tmp_path / "c.toml")
    assert all(np.allclose(Calibration.load(tmp_path / "c.toml").regions[n], cal.regions[n]) for n in cal.regions)


def test_world_frame_and_points_match_truth(session, result):
    truth = session["truth"]
    # the world frame from the flat board of frame 0: a point 300 mm away lands within 0.15 mm (measured 0.10)
    probe = np.array([[0.0, 0.0, 0.0], [200.0, 50.0, 300.0]])
    assert np.abs(result.calibration.to_world(probe) - truth.to_world(probe)).max() < 0.15
    pts = result.points
    assert list(pts.columns) == ["frame", "corner_id", "xs", "ys", "xf", "yf", "X_mm", "Y_mm", "Z_mm"]
    corners = session["board"].corner_points_mm()
    true_xyz = np.array([truth.to_world(corners[c] @ session["poses"][f][:3, :3].T + session["poses"][f][:3, 3])[0]
                         for f, c in zip(pts.frame, pts.corner_id, strict=True)])
    err = np.linalg.norm(true_xyz - pts[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), axis=1)
    assert err.mean() < 0.067  # measured 0.044 mm
    # the frame-0 board lies flat: its corners have world Y = 0 and start at the origin
    flat = pts[pts.frame == 0]
    assert np.abs(flat.Y_mm).max() < 1e-6
    # and triangulating the table's own pixels gives its XYZ back
    xyz, res = triangulate(result.calibration, {"side": pts[["xs", "ys"]].to_numpy(),
                                                "front": pts[["xf", "yf"]].to_numpy()})
    assert np.linalg.norm(xyz - pts[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), axis=1).mean() < 0.044  # measured 0.029
    assert np.nanmedian(res) < 0.0075  # px, measured 0.0049


def test_cli_json_writes_files_and_project(session, tmp_path, capsys):
    from sandtrack_tui.store import Project

    proj = tmp_path / "exp.sandtrack"
    Project.create(proj).close()
    ref = tmp_path / "reference.toml"
    ref.write_text("frame = 0\norigin_mm = [10.0, 0.0, 5.0]\n")
    board = tmp_path / "board.toml"
    session["board"].save(board)
    out, pts = tmp_path / "calibration.toml", tmp_path / "points.csv"
    code = main(["calibrate", "--board", str(board), "--side", session["videos"]["side"], "--front",
                 session["videos"]["front"], "-o", str(out), "--points", str(pts), "--reference", str(ref),
                 "--project", str(proj), "--export-caliscope", str(tmp_path / "camera_array.toml"), "--json"])
    assert code == 0
    r = json.loads(capsys.readouterr().out)
    for key in ("reprojection_rmse_px", "board_rmse_mm", "per_camera", "views_used", "points", "seconds"):
        assert key in r
    assert r["reprojection_rmse_px"] < 0.03 and r["points"] > 400  # measured 0.020 px
    assert set(r["per_camera"]) == {"side", "front"} and r["per_camera"]["side"]["rmse_px"] < 0.021  # 0.014
    cal = Calibration.load(out)
    for n in ("side", "front"):  # the report's camera is the file's, with its sd; the single-camera fit apart
        c = r["per_camera"][n]
        assert c["fx"] == pytest.approx(cal.cameras[n].matrix[0, 0], abs=1e-9) and 0 < c["fx_sd_px"] < 1.0
        assert abs(c["fx"] - session["truth"].cameras[n].matrix[0, 0]) < 6 * c["fx_sd_px"]
        assert set(c["single_camera_fit"]) == {"fx", "fy", "cx", "cy", "distortion"}
        # the corners screened, the misdetected ones counted, the rest's noise the file's (a clean render: 0.01 px)
        assert 0 <= c["misdetected_corners"] < 0.1 * c["corners_screened"]
        assert c["noise_px"] == pytest.approx(cal.uncertainty[n].noise_px) and max(c["noise_px"]) < 0.02
        # and a view's shared shift, which its pose absorbed, allowed for in a corner's pixel sd (kept in the file)
        unc = cal.uncertainty[n]
        assert unc.view_shared_px == pytest.approx([SHARED_VIEW_ERROR * v for v in unc.noise_px])
        assert camera_noise_px(cal, n) == pytest.approx(np.hypot(unc.noise_px, unc.view_shared_px))
        assert c["view_shared_px"] == pytest.approx(unc.view_shared_px)
    from sandtrack_tui.cli.cmd_calibrate import _text

    assert _text(r).count("corners misdetected (beyond 5 robust sd: not in the calibration points)") == 2
    assert " ".join(_text(r).split()).count("allowed for in a corner's pixel sd: x ") == 2
    # each view's own board pose error, measured from the frames both cameras saw (a still board per frame: only
    # the render's detection biases, measured 0.055 / 0.031 / 0.005 mm; test_bundle_covariance checks a motion)
    motion = r["view_motion"]
    assert motion["views"] > 10 and max(motion["translation_sd_mm"]) < 0.1 and max(motion["rotation_sd_deg"]) < 0.1
    assert "as if the board moved between the cameras' exposures" in _text(r)
    # the world frame's sd (the cameras' part included) against its rotation's true error: measured 4.2 / 0.04 /
    # 0.9 sd about X / Y / Z, the bundle adjustment's covariance being a lower bound (README: it under-states the
    # sample's true camera errors about twice in sd)
    assert cal.rig_uncertainty is not None and len(cal.rig_uncertainty.parameters) >= 6
    rot_sd = np.array(r["world"]["rotation_sd_mrad"]) / 1e3
    dR = cal.world_from_rig[:3, :3] @ session["truth"].world_from_rig[:3, :3].T
    err = np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]) / 2
    assert np.all(rot_sd > 0) and np.all(np.abs(err) < 6 * rot_sd), (err, rot_sd)
    table = pd.read_csv(pts)
    assert len(table) == r["points"]
    flat = table[table.frame == 0]
    # origin_mm shifts the board origin: each corner of the flat board sits at origin + its board position
    # (board x along world X, board y along Z)
    on_board = session["board"].corner_points_mm()[flat.corner_id.to_numpy()]
    assert len(flat) > 10
    assert np.allclose(flat[["X_mm", "Y_mm", "Z_mm"]].to_numpy(),
                       np.stack([10 + on_board[:, 0], 0 * on_board[:, 0], 5 + on_board[:, 1]], axis=1), atol=1.5)
    with Project.open(proj) as p:
        stored = p.calibration()
        assert stored is not None and np.allclose(stored.world_from_rig, cal.world_from_rig)
        assert p.board() == session["board"]
    # Caliscope round trip through the CLI import
    code = main(["calibrate", "--import-caliscope", str(tmp_path / "camera_array.toml"), "--names", "side,front",
                 "-o", str(tmp_path / "imported.toml"), "--json"])
    assert code == 0
    capsys.readouterr()
    imp = Calibration.load(tmp_path / "imported.toml")
    X = np.array([[50.0, 10.0, 100.0]])
    assert np.allclose(imp.project_world("front", X), cal.project_world("front", X), atol=1e-6)


def test_cli_from_points(result, tmp_path, capsys):
    # pixel/XYZ table of several board poses spread in depth -> cameras
    pts = tmp_path / "points.csv"
    result.points.to_csv(pts, index=False)
    out = tmp_path / "fp.toml"
    assert main(["calibrate", "--from-points", str(pts), "-o", str(out), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["reprojection_rmse_px"] < 0.031  # measured 0.020 px
    cal = Calibration.load(out)
    fx_true = result.calibration.cameras["side"].matrix[0, 0]
    # measured 1.2e-5 (4.6e-6 while the points held the 62 corners the screening leaves out, which the
    # bundle adjustment that gave fx_true keeps)
    assert abs(cal.cameras["side"].matrix[0, 0] / fx_true - 1) < 1.8e-5
    side = r["per_camera"]["side"]
    assert side["fx"] == pytest.approx(cal.cameras["side"].matrix[0, 0], abs=1e-9) and side["fx_sd_px"] > 0
    assert main(["calibrate", "--from-points", str(pts), "-o", str(out)]) == 0
    assert f"side: fx {side['fx']:.2f} ± {side['fx_sd_px']:.2f} px (1 sd of the fit), RMSE" in capsys.readouterr().out


def _cli_error(args, capsys) -> str:
    assert main(args) == 1
    return capsys.readouterr().err


def test_bad_input_messages(session, tmp_path, capsys):
    board = tmp_path / "board.toml"
    session["board"].save(board)
    side, front = session["videos"]["side"], session["videos"]["front"]
    # no board file
    assert "board file not found" in _cli_error(
        ["calibrate", "--board", str(tmp_path / "nope.toml"), "--side", side, "--front", front, "-o", "x.toml"], capsys)
    # wrong board (other dictionary): nothing found, says what to check
    wrong = tmp_path / "wrong.toml"
    BoardSpec(columns=8, rows=5, square_mm=30.0, dictionary="DICT_6X6_250").save(wrong)
    err = _cli_error(["calibrate", "--board", str(wrong), "--side", side, "--front", front, "-o", "x.toml",
                      "--budget", "6"], capsys)
    assert "no board found" in err and "dictionary" in err
    # the board seen by one camera only: front sees a blank scene
    blank = tmp_path / "blank"
    blank.mkdir()
    for f in range(22):
        cv2.imwrite(str(blank / f"{f:05d}.png"), np.full((540, 960), 110, np.uint8))
    err = _cli_error(["calibrate", "--board", str(board), "--side", side, "--front", str(blank), "-o", "x.toml"],
                     capsys)
    assert "no board found in camera front" in err
    # too few views: only three frames
    few = {}
    for n in ("side", "front"):
        d = tmp_path / f"few_{n}"
        d.mkdir()
        for f in range(3):
            shutil.copy(f"{session['videos'][n]}/{f:05d}.png", d / f"{f:05d}.png")
        few[n] = str(d)
    err = _cli_error(["calibrate", "--board", str(board), "--side", few["side"], "--front", few["front"], "-o",
                      "x.toml"], capsys)
    assert "only" in err and "record at least" in err
    # a missing video
    assert "not found" in _cli_error(["calibrate", "--board", str(board), "--side", "missing.mp4", "--front", front,
                                      "-o", "x.toml"], capsys)
    # one camera only
    assert "two cameras" in _cli_error(["calibrate", "--board", str(board), "--side", side, "-o", "x.toml"], capsys)


def test_face_on_views_are_rejected(tmp_path):
    from sandtrack_tui.calibration.intrinsics import calibrate_intrinsics
    from sandtrack_tui.calibration.rig import BoardView
    from sandtrack_tui.calibration.synthetic import stereo_rig

    board = BoardSpec(columns=8, rows=5, square_mm=30.0)
    cam = stereo_rig().cameras["side"]
    pts = board.corner_points_mm()
    views = {}
    for f in range(12):  # board moved sideways, always parallel to the image
        T = np.eye(4)
        T[:3, 3] = [-120 + 20 * (f % 4), -60 + 30 * (f // 4), 600 + 5 * f]
        uv = cam.project(pts @ T[:3, :3].T + T[:3, 3])
        views[f] = BoardView(frame=f, source_frame=f, ids=np.arange(len(pts)), corners=uv)
    with pytest.raises(SandtrackError, match="face-on"):
        calibrate_intrinsics("side", views, board, (cam.width, cam.height))


def test_fractional_sync_offset_is_interpolated(tmp_path):
    """The front camera started 3.5 frames after the side camera while the board kept moving: the front
    corners are interpolated to the side camera's instants, so the rig comes out right."""
    from sandtrack_tui.calibration.geometry import to_T
    from sandtrack_tui.calibration.synthetic import _write_mp4, render, stereo_rig

    board = BoardSpec(columns=8, rows=5, square_mm=30.0, dictionary="DICT_4X4_50")
    truth = stereo_rig()
    w, h = board.size_mm

    def pose(t):
        T = to_T(np.array([0.5 * np.sin(1.3 * t), 0.45 * np.sin(0.9 * t + 1), 0.2 * np.sin(0.7 * t)]), np.zeros(3))
        c = np.array([150 * np.sin(1.1 * t), 70 * np.sin(1.7 * t + 0.5), 700 + 120 * np.sin(0.8 * t)])
        T[:3, 3] = c - T[:3, :3] @ np.array([w / 2, h / 2, 0])
        return T

    fps, n, offset = 25.0, 40, 3.5 / 25.0
    _write_mp4(tmp_path / "side.mp4", render(truth.cameras["side"], board, [pose(k / fps) for k in range(n)]), fps)
    _write_mp4(tmp_path / "front.mp4", render(truth.cameras["front"], board,
                                              [pose(k / fps + offset) for k in range(n)], seed=1), fps)
    res = calibrate_videos({"side": str(tmp_path / "side.mp4"), "front": str(tmp_path / "front.mp4")}, board,
                           offsets_s={"front": offset}, detect_budget=40, models=TRUE_LENSES)
    err = relative_pose_errors(res.calibration, truth)
    assert err["rotation_err_deg"] < 0.033 and err["translation_err_mm"] < 0.42  # measured 0.022 deg, 0.28 mm
    assert err["focal_rel_err"] < 0.001  # measured 0.068 %


def test_a_weakly_heard_clap_gives_its_best_guess_which_the_board_checks(tmp_path, monkeypatch):
    """Audio sync below its confidence threshold: its best guess is used, with a warning, and the board's
    reprojection error accepts a right guess and refuses a wrong one (the videos here start together)."""
    import sandtrack_tui.sync as sync

    s = write_session(tmp_path, n_views=12, seed=3, flat_reference=False, video_fps=25.0)
    guess = {"offset_s": 0.0}

    def weak(side, front, method="auto", min_confidence=sync.MIN_CONFIDENCE, **_):
        if min_confidence > 0.2:
            raise sync.LowConfidence("audio sync is not reliable (confidence 0.20 < 0.35)")
        return sync.SyncResult(guess["offset_s"], guess["offset_s"] * 25.0, 0.2, "audio", 25.0)

    monkeypatch.setattr(sync, "estimate_offset", weak)
    res = calibrate_videos(s["videos"], s["board"], detect_budget=12, models=TRUE_LENSES)
    assert res.report["sync"]["front"]["method"] == "audio (weak)" and res.report["reprojection_rmse_px"] < 0.3
    assert any("heard only weakly in front (sync confidence 0.20): its best guess, +0.0 ms, is used" in w
               for w in res.report["warnings"])
    guess["offset_s"] = 0.2  # five frames off: the board's views pair wrongly
    with pytest.raises(SandtrackError, match="cameras disagree"):
        calibrate_videos(s["videos"], s["board"], detect_budget=12, models=TRUE_LENSES)


def test_world_frame_from_known_points(session, result, tmp_path):
    # known world points (here: corners placed by the reference-frame calibration) define the same world frame
    known = result.points.iloc[::25].reset_index(drop=True)
    kept = {n: c.lens for n, c in result.calibration.cameras.items()}  # the lens choice is not what is tested
    res = calibrate_videos(session["videos"], session["board"], known_points=known, models=kept)
    assert res.report["world"]["method"].startswith("known points")
    assert res.report["world"]["rmse_mm"] < 0.047  # measured 0.031
    probe = np.array([[0.0, 0.0, 0.0], [200.0, 50.0, 300.0]])
    assert np.abs(res.calibration.to_world(probe) - result.calibration.to_world(probe)).max() < 0.081  # 0.054
    # each world frame's sd at the probes (the cameras' part included) holds their difference (measured 0.71 sd)
    sd = [_world_frame_sd_at(c.rig_uncertainty, c.to_world(probe)) for c in (res.calibration, result.calibration)]
    diff = res.calibration.to_world(probe) - result.calibration.to_world(probe)
    assert np.all(np.abs(diff) < 3 * np.hypot(*sd))


def _world_frame_sd_at(unc, X):
    C = unc.world_jacobian @ unc.covariance @ unc.world_jacobian.T + unc.world_covariance
    out = []
    for x in X:
        A = np.hstack([np.array([[0, x[2], -x[1]], [-x[2], 0, x[0]], [x[1], -x[0], 0]]), np.eye(3)])
        out.append(np.sqrt(np.diag(A @ C @ A.T)))
    return np.array(out)


def test_the_calibration_screen_shows_each_camera_term_with_its_sd(result):
    from rich.console import Console

    from sandtrack_tui.calibration.report import camera_parameters
    from sandtrack_tui.tui.screens.calibration import summary_table

    console = Console(width=160, record=True)
    console.print(summary_table(result.calibration))
    text = console.export_text()
    side = camera_parameters(result.calibration, "side")
    assert f"{side['fx']:.1f}" in text and f"±{side['fx_sd_px']:.1f}" in text and "± 1 sd" in text
    hull = result.report["per_camera"]["side"]["calibrated_region_pct"]
    row = next(line.split() for line in text.splitlines() if line.split()[:1] == ["side"])
    assert "hull" in text and row[-1] == f"{hull:.0f}"  # the share of the image their hull spans
    noise = result.calibration.uncertainty["side"].noise_px  # the pixel noise without the misdetected corners
    assert row[-2] == f"{noise[0]:.3f}/{noise[1]:.3f}"
    assert f"{result.report['per_camera']['side']['misdetected_corners']} misdetected" in text
    world = result.calibration.rig_uncertainty.world_frame_sd()
    assert f"world frame ± {world['rotation_sd_mrad'][0]:.2f} / " in " ".join(text.split())
    motion = result.report["view_motion"]
    assert f"exposures ± {max(motion['rotation_sd_deg']):.3f}°, {max(motion['translation_sd_mm']):.3f} mm" in " ".join(
        text.split())
    assert "the calibration's parameter covariance, cameras together with the world frame's" in " ".join(text.split())
    result.calibration.rig_uncertainty, kept = None, result.calibration.rig_uncertainty
    result.calibration.uncertainty, cameras = {}, result.calibration.uncertainty
    try:
        console.print(summary_table(result.calibration))
        assert "only: the calibration file keeps no parameter covariance" in " ".join(console.export_text().split())
    finally:
        result.calibration.rig_uncertainty, result.calibration.uncertainty = kept, cameras


def test_a_kept_simpler_lens_puts_its_spread_in_the_covariance_and_says_so(result):
    """Wiring from videos: this session's lens choice kept, in both cameras, a simpler model than the one
    best on the left-out views (prism for side, by a difference that is not significant): the calibration's
    covariance holds the better model's extra terms, the file names it, sd_holds and the report say so."""
    from sandtrack_tui.lens import LENSES, TERMS
    from sandtrack_tui.triangulation_sd import sd_holds

    cal = result.calibration
    spread = result.report["bundle"]["lens_choice_spread"]
    assert spread.keys() == {"side", "front"}
    for name, s in spread.items():
        assert cal.uncertainty[name].better_lens == s["better_fitting"] and cal.cameras[name].lens == s["kept"]
        extra = set(LENSES[s["better_fitting"]].terms) - set(LENSES[s["kept"]].terms)
        assert extra and {f"{name}/d{TERMS.index(t)}" for t in extra} <= set(cal.rig_uncertainty.parameters)
        assert (f"lens choice's spread ({name}: {s['better_fitting']} against the kept {s['kept']}"
                in sd_holds(cal, [name]))
        assert result.report["per_camera"][name]["lens_selection"]["spread"].startswith(
            f"the XYZ sd holds the lens choice's spread: {s['better_fitting']} fitted the left-out data better")


def test_cli_offsets_for_any_camera_and_bad_ones_are_one_line(tmp_path, monkeypatch, capsys):
    """--offset-s: a bare value is the front camera's (every other camera's where there is no front),
    CAMERA=S one camera's; a camera that is not after the first, or not a number, is refused in one line."""
    import sandtrack_tui.calibration.pipeline as pipeline

    seen = []

    def stop(videos, board, *, offsets_s=None, **kwargs):
        seen.append(offsets_s)
        raise SandtrackError("stopped here")

    monkeypatch.setattr(pipeline, "calibrate_videos", stop)
    board = tmp_path / "board.toml"
    BoardSpec().save(board)
    for d in ("a", "b", "c"):
        (tmp_path / d).mkdir()
    cams = ["--board", str(board), "--camera", f"a={tmp_path / 'a'}", "--camera", f"b={tmp_path / 'b'}",
            "--camera", f"c={tmp_path / 'c'}"]
    for extra, expected in ((["--offset-s", "0"], {"b": 0.0, "c": 0.0}),
                            (["--offset-s", "0", "--offset-s", "c=-1.5"], {"b": 0.0, "c": -1.5}),
                            ([], None)):
        assert main(["calibrate", *cams, "-o", str(tmp_path / "x.toml"), *extra]) == 1
        assert seen[-1] == expected
    capsys.readouterr()
    for bad, msg in ((["--offset-s", "a=0.1"], "--offset-s a: not a camera after the first, a (one of b, c)"),
                     (["--offset-s", "b=soon"], "--offset-s 'soon': give the offset in seconds")):
        assert main(["calibrate", *cams, "-o", str(tmp_path / "x.toml"), *bad]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert msg in err[-1] and len(err) == 1, err
