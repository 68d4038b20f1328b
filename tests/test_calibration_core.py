"""Exact-answer tests of the calibration maths: projection, world frame, Kabsch, bundle adjustment,
triangulation, calibration from known points, Caliscope files."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sandtrack_tui.board import BoardSpec
from sandtrack_tui.calibration.bundle import BundleState, bundle_adjust
from sandtrack_tui.calibration.caliscope import export_caliscope, import_caliscope
from sandtrack_tui.calibration.detect import BoardView
from sandtrack_tui.calibration.from_points import calibrate_from_points, decompose_projection, dlt_projection
from sandtrack_tui.calibration.geometry import distort_project, inv_T, kabsch, radial_is_monotonic, rodrigues, to_T
from sandtrack_tui.calibration.report import relative_pose_errors
from sandtrack_tui.calibration.rig import _drop_blurred, make_observations
from sandtrack_tui.calibration.synthetic import board_poses, stereo_rig
from sandtrack_tui.calibration.world import world_from_board_pose, world_from_known_points
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.triangulation import epipolar_distance, triangulate

BOARD = BoardSpec(columns=8, rows=5, square_mm=30.0, dictionary="DICT_4X4_50")


def test_projection_matches_opencv():
    rng = np.random.default_rng(0)
    X = rng.uniform([-300, -200, 500], [300, 200, 1200], (200, 3))
    K = np.array([[900.0, 0, 650], [0, 905, 350], [0, 0, 1]])
    d = np.array([-0.3, 0.1, 0.001, -0.002, -0.02])
    ref, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, d)
    assert np.abs(distort_project(X, K, d) - ref.reshape(-1, 2)).max() < 1e-9
    df = np.array([0.05, -0.01, 0.002, -0.001])
    reff, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, df)
    assert np.abs(distort_project(X, K, df, "fisheye") - reff.reshape(-1, 2)).max() < 1e-9
    r = rng.normal(size=(20, 3))
    assert np.abs(rodrigues(r) - np.array([cv2.Rodrigues(v)[0] for v in r])).max() < 1e-12


def test_k3_guard_flags_folding_distortion():
    K = np.array([[900.0, 0, 640], [0, 900, 360], [0, 0, 1]])
    assert radial_is_monotonic(np.array([-0.3, 0.1, 0, 0, -0.01]), K, (1280, 720))
    # a large negative k3 turns the radius back before the image corner
    assert not radial_is_monotonic(np.array([0.1, 0.2, 0, 0, -3.0]), K, (1280, 720))


def test_world_frame_convention():
    # board lying flat: board x -> world +X, board y -> world +Z, board z -> world -Y, origin at origin_mm
    T_rig_board = to_T(np.array([0.3, -0.2, 0.1]), np.array([10.0, 50.0, 800.0]))
    W = world_from_board_pose(T_rig_board, origin_mm=(100.0, 0.0, -20.0))
    P = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    rig = P @ T_rig_board[:3, :3].T + T_rig_board[:3, 3]
    world = rig @ W[:3, :3].T + W[:3, 3]
    assert np.allclose(world[0], [100, 0, -20])
    assert np.allclose(world[1] - world[0], [1, 0, 0])
    assert np.allclose(world[2] - world[0], [0, 0, 1])
    assert np.allclose(world[3] - world[0], [0, -1, 0])


def test_kabsch_recovers_transform_and_rejects_collinear():
    rng = np.random.default_rng(1)
    T = to_T(np.array([0.5, 1.0, -0.3]), np.array([100.0, -20, 300]))
    src = rng.normal(size=(10, 3)) * 200
    dst = src @ T[:3, :3].T + T[:3, 3]
    assert np.allclose(kabsch(src, dst), T, atol=1e-9)
    W, res = world_from_known_points(src, dst)
    assert res < 1e-9 and np.allclose(W, T, atol=1e-9)
    line = np.outer(np.arange(5.0), [1, 2, 3])
    with pytest.raises(SandtrackError, match="line"):
        world_from_known_points(line, line)


def _exact_views(truth, poses):
    pts = BOARD.corner_points_mm()
    views = {n: {} for n in truth.names}
    for n, cam in truth.cameras.items():
        for f, T in enumerate(poses):
            uv = cam.project(pts @ T[:3, :3].T + T[:3, 3])
            ok = (uv[:, 0] > 0) & (uv[:, 0] < cam.width) & (uv[:, 1] > 0) & (uv[:, 1] < cam.height)
            if ok.sum() >= 6:
                views[n][f] = BoardView(frame=f, source_frame=f, ids=np.nonzero(ok)[0], corners=uv[ok])
    return views


def test_bundle_adjustment_recovers_exact_rig_from_perturbed_start():
    truth = stereo_rig()
    poses = board_poses(15, BOARD, seed=3)
    views = _exact_views(truth, poses)
    frames = sorted(set(views["side"]) | set(views["front"]))
    obs = make_observations(views, truth.names, frames, BOARD)
    rng = np.random.default_rng(0)
    cams = [truth.cameras[n] for n in truth.names]
    state = BundleState(
        cam_rvec=np.array([c.rvec + (rng.normal(0, 0.01, 3) if i else 0) for i, c in enumerate(cams)]),
        cam_tvec=np.array([c.tvec + (rng.normal(0, 5, 3) if i else 0) for i, c in enumerate(cams)]),
        K=np.array([c.matrix * [[1.02, 1, 1], [1, 1.02, 1], [1, 1, 1]] for c in cams]),
        dist=[np.zeros(5) for _ in cams], models=["pinhole"] * 2,
        frame_rvec=np.array([cv2.Rodrigues(poses[f][:3, :3])[0].ravel() + rng.normal(0, 0.01, 3) for f in frames]),
        frame_tvec=np.array([poses[f][:3, 3] + rng.normal(0, 3, 3) for f in frames]),
        fixed_k3=[True, True])
    out, info = bundle_adjust(state, obs)
    assert info["initial_rmse_px"] > 5
    assert info["rmse_px"] < 1e-3
    for i, c in enumerate(cams):
        assert np.allclose(out.K[i], c.matrix, rtol=1e-5)
        assert np.allclose(out.dist[i][:4], c.distortion[:4], atol=1e-5)
    assert np.allclose(out.cam_tvec[1], cams[1].tvec, atol=1e-3)


def test_triangulation_exact_and_residual_flags_mismatch():
    truth = stereo_rig()
    rng = np.random.default_rng(2)
    X = rng.uniform([-150, -80, 600], [150, 80, 850], (50, 3))
    px = {n: c.project(X) for n, c in truth.cameras.items()}
    for refine in (False, True):
        xyz, res = triangulate(truth, px, refine=refine, world=False)
        assert np.abs(xyz - X).max() < 1e-6
        assert res.max() < 1e-6
    bad = {"side": px["side"], "front": px["front"] + [0, 15.0]}
    _, res = triangulate(truth, bad, refine=True, world=False)
    assert res.min() > 2.0
    d = epipolar_distance(truth, "side", px["side"], "front", px["front"])
    assert d.max() < 1e-6


def test_triangulation_survives_degenerate_points():
    truth = stereo_rig()
    px = {"side": np.array([[np.nan, np.nan], [480.0, 270.0]]), "front": np.array([[100.0, 100.0], [np.nan, 5.0]])}
    xyz, res = triangulate(truth, px, refine=True)
    assert np.isnan(xyz).all() and np.isnan(res).all()


def test_from_points_recovers_cameras():
    truth = stereo_rig(size=(1280, 720), focal=(1000.0, 950.0))
    truth.world_from_rig = to_T(np.array([0.2, -0.1, 0.05]), np.array([50.0, -100, 20]))
    rng = np.random.default_rng(4)
    Xw = rng.uniform([-200, -150, 550], [200, 150, 900], (400, 3))
    Xw = truth.to_world(Xw)
    import pandas as pd

    df = pd.DataFrame({"X_mm": Xw[:, 0], "Y_mm": Xw[:, 1], "Z_mm": Xw[:, 2]})
    for n, col in (("side", "s"), ("front", "f")):
        uv = truth.project_world(n, Xw) + rng.normal(0, 0.05, (len(Xw), 2))
        df[f"x{col}"], df[f"y{col}"] = uv[:, 0], uv[:, 1]
    # the cameras' own model forced; then the automatic choice, which may drop terms the data do not
    # resolve (here the front camera's k2, worth under 1 px at the image edge)
    for lens, max_rotation_deg in (("standard", 0.05), ("auto", 0.1)):
        cal = calibrate_from_points(df, {"side": ("xs", "ys"), "front": ("xf", "yf")}, lens=lens)
        err = relative_pose_errors(cal, truth)
        # measured (standard / auto): focal 0.015 / 0.018 %, principal point 0.42 / 1.00 px, 0.14 / 0.30 mm
        assert err["focal_rel_err"] < 2.7e-4
        assert err["principal_point_err_px"] < 1.5
        assert err["rotation_err_deg"] < max_rotation_deg
        assert err["translation_err_mm"] < 0.45
        assert cal.report["reprojection_rmse_px"] < 0.1
        xyz, _ = triangulate(cal, {"side": df[["xs", "ys"]].to_numpy(), "front": df[["xf", "yf"]].to_numpy()})
        assert np.linalg.norm(xyz - Xw, axis=1).mean() < 0.1


def test_dlt_decomposition_is_exact():
    K = np.array([[800.0, 0, 320], [0, 810, 240], [0, 0, 1]])
    T = to_T(np.array([0.1, 0.2, 0.3]), np.array([10.0, 20, 500]))
    X = np.random.default_rng(0).uniform(-100, 100, (30, 3))
    uv = distort_project(X @ T[:3, :3].T + T[:3, 3], K, np.zeros(5))
    K2, R2, t2 = decompose_projection(dlt_projection(X, uv))
    assert np.allclose(K2, K, atol=1e-6) and np.allclose(R2, T[:3, :3], atol=1e-9)
    assert np.allclose(t2, T[:3, 3], atol=1e-6)


def test_from_points_rejects_planar_points():
    import pandas as pd

    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(5.0)), -1).reshape(-1, 2) * 30
    df = pd.DataFrame({"X_mm": g[:, 0], "Y_mm": g[:, 1], "Z_mm": 0.0, "xs": g[:, 0], "ys": g[:, 1],
                       "xf": g[:, 0] + 3, "yf": g[:, 1]})
    with pytest.raises(SandtrackError, match="one plane"):
        calibrate_from_points(df, {"side": ("xs", "ys"), "front": ("xf", "yf")})


def test_caliscope_round_trip(tmp_path):
    truth = stereo_rig()
    truth.world_from_rig = to_T(np.array([1.2, 0.1, -0.4]), np.array([300.0, 20, -50]))
    path = tmp_path / "camera_array.toml"
    export_caliscope(truth, path)
    back = import_caliscope(path, names=["side", "front"])
    assert back.names == ["side", "front"]
    for n in truth.names:
        a, b = truth.cameras[n], back.cameras[n]
        assert np.allclose(a.matrix, b.matrix) and np.allclose(a.distortion, b.distortion)
        assert np.allclose(to_T(a.rvec, a.tvec), to_T(b.rvec, b.tvec), atol=1e-9)
    assert np.allclose(back.world_from_rig, truth.world_from_rig, atol=1e-9)
    # same world point, same pixels
    X = np.array([[10.0, 20.0, 30.0]])
    assert np.allclose(truth.project_world("front", X), back.project_world("front", X))


def test_caliscope_config_with_rodrigues_rotation(tmp_path):
    p = tmp_path / "config.toml"
    p.write_text("""
[cam_0]
size = [640, 480]
matrix = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
distortions = [0.0, 0.0, 0.0, 0.0, 0.0]
rotation = [0.0, 0.0, 0.0]
translation = [0.0, 0.0, 0.0]
[cam_1]
size = [640, 480]
matrix = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]
distortions = [0.0, 0.0, 0.0, 0.0, 0.0]
rotation = [0.0, 0.1, 0.0]
translation = [-0.5, 0.0, 0.0]
""")
    cal = import_caliscope(p)
    assert cal.names == ["cam_0", "cam_1"]
    assert np.allclose(cal.cameras["cam_1"].tvec, [-500.0, 0, 0])
    assert np.allclose(inv_T(cal.world_from_rig), np.eye(4))
    bad = tmp_path / "bad.toml"
    bad.write_text("[something]\nx = 1\n")
    with pytest.raises(SandtrackError, match="no calibrated cameras"):
        import_caliscope(bad)


def test_fisheye_rig_from_exact_views():
    from sandtrack_tui.calibration.rig import calibrate_rig

    truth = stereo_rig()
    for cam, d in zip(truth.cameras.values(), ([0.05, -0.02, 0.004, -0.001], [-0.03, 0.01, 0.0, 0.0]), strict=True):
        cam.model, cam.distortion = "fisheye", np.array(d)
    poses = board_poses(24, BOARD, seed=8)
    views = _exact_views(truth, poses)
    rr = calibrate_rig(views, BOARD, {n: (c.width, c.height) for n, c in truth.cameras.items()},
                       models={"side": "fisheye", "front": "fisheye"})
    err = relative_pose_errors(rr.calibration, truth)
    assert rr.calibration.cameras["front"].model == "fisheye"
    assert err["focal_rel_err"] < 1e-4 and err["translation_err_mm"] < 0.01
    assert rr.bundle["rmse_px"] < 1e-3


def test_blurred_views_dropped_only_when_views_are_plentiful():
    def view(f, sharpness):
        return BoardView(frame=f, source_frame=f, ids=np.arange(6), corners=np.zeros((6, 2)), sharpness=sharpness)

    # 100 views: every third one blurred (a tenth of the sharpness)
    many = {f: view(f, 10.0 if f % 3 else 1.0) for f in range(100)}
    few = {f: many[f] for f in range(40)}
    kept, dropped = _drop_blurred({"a": many, "b": few}, fraction=0.8, min_keep=60)
    assert set(kept["a"]) == {f for f in range(100) if f % 3}  # 66 sharp views left, all blurred ones gone
    assert dropped == 34
    assert kept["b"] == few  # too few views to spare any
    # never fewer than min_keep: the sharpest are kept
    graded = {f: view(f, float(f)) for f in range(100)}
    kept, _ = _drop_blurred({"a": graded}, fraction=1.5, min_keep=60)  # 25 pass the cut
    assert set(kept["a"]) == set(range(40, 100))
    assert _drop_blurred({"a": many}, fraction=0.0, min_keep=60)[0]["a"] == many
