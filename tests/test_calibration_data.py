"""Calibration on recorded data: the real four-webcam ChArUco session (skipped when
../shared/data/caliscope_4cam is absent) and the rendered sample_data/ session with its true
cameras (skipped when sample_data/ has not been generated)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.board import load_board
from sandtrack_tui.calibration.pipeline import calibrate_videos
from sandtrack_tui.calibration.world import load_reference
from sandtrack_tui.camera import Calibration
from sandtrack_tui.triangulation import triangulate

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "caliscope_4cam"
SAMPLE = ROOT / "sample_data"


@pytest.mark.slow
@pytest.mark.skipif(not (REAL / "cam_3.mp4").exists(), reason="real footage ../shared/data/caliscope_4cam absent")
def test_real_four_cameras_beat_caliscope_and_aniposelib():
    board = load_board(REAL / "charuco.toml")
    videos = {f"cam_{i}": str(REAL / f"cam_{i}.mp4") for i in range(4)}
    res = calibrate_videos(videos, board, offsets_s={n: 0.0 for n in videos})  # frame-aligned recording
    r = res.report
    # reference figures on this recording: Caliscope 0.647 px / 0.444 mm, aniposelib 0.556 px / 0.367 mm
    assert r["reprojection_rmse_px"] < 0.556
    assert r["board_rmse_mm"] < 0.367
    assert r["corners_detected"] > 1400
    # camera 1 sees the back of the double-sided board: found by the mirrored search
    assert r["per_camera"]["cam_1"]["mirrored_views"] > 30
    # webcam focal lengths in a plausible range and consistent with Caliscope's own intrinsics (+-5 %)
    ref_fx = {"cam_0": 894.5, "cam_1": 704.0, "cam_2": 637.2, "cam_3": 640.4}
    for n, fx in ref_fx.items():
        assert abs(res.calibration.cameras[n].matrix[0, 0] / fx - 1) < 0.05


@pytest.mark.slow
@pytest.mark.skipif(not (SAMPLE / "calibration" / "side.mp4").exists()
                    or not (SAMPLE / "ground_truth" / "cameras.toml").exists(), reason="sample_data/ not generated")
def test_sample_session_matches_true_rig():
    board = load_board(SAMPLE / "board.toml")
    frame, origin = load_reference(SAMPLE / "calibration" / "reference.toml")
    videos = {n: str(SAMPLE / "calibration" / f"{n}.mp4") for n in ("side", "front")}
    res = calibrate_videos(videos, board, reference_frame=frame, origin_mm=origin, detect_budget=30)
    truth = Calibration.load(SAMPLE / "ground_truth" / "cameras.toml")
    assert res.report["sync"]["front"]["method"] == "audio"
    for n in ("side", "front"):
        K, Kt = res.calibration.cameras[n].matrix, truth.cameras[n].matrix
        assert abs(K[0, 0] / Kt[0, 0] - 1) < 0.004
    # triangulated corners against the true world corners (every corner both cameras saw in the frames searched)
    corners = {n: pd.read_csv(SAMPLE / "ground_truth" / f"calibration_corners_{n}.csv") for n in ("side", "front")}
    side = corners["side"].set_index(["frame", "corner_id"])
    rows = []
    for f in sorted(set(res.views["side"]) & set(res.views["front"])):
        vs, vf = res.views["side"][f], res.views["front"][f]
        common, i_s, i_f = np.intersect1d(vs.ids, vf.ids, return_indices=True)
        for c, a, b in zip(common, i_s, i_f, strict=True):
            rows.append((vs.source_frame, c, *vs.corners[a], *vf.corners[b]))
    t = pd.DataFrame(rows, columns=["frame", "corner_id", "xs", "ys", "xf", "yf"])
    assert len(t) > 500
    xyz, _ = triangulate(res.calibration, {"side": t[["xs", "ys"]].to_numpy(), "front": t[["xf", "yf"]].to_numpy()},
                         refine=True)
    true_xyz = side.loc[list(zip(t.frame, t.corner_id, strict=True)), ["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
    assert np.linalg.norm(xyz - true_xyz, axis=1).mean() < 0.4
