"""Misdetected board corners: flagged from their residuals against the board poses, the camera's noise
measured without them, and the calibration points left without them."""

from __future__ import annotations

import numpy as np
import pytest

from sandtrack_tui.board import BoardSpec
from sandtrack_tui.calibration.detect import BoardView
from sandtrack_tui.calibration.misdetections import screen_corners
from sandtrack_tui.calibration.points import calibration_points
from sandtrack_tui.calibration.rig import fit_frame_poses
from sandtrack_tui.calibration.synthetic import board_poses, stereo_rig

BOARD = BoardSpec(columns=8, rows=5, square_mm=25.0, dictionary="DICT_4X4_50")


def _views(noise=(0.06, 0.04), n_views: int = 60, share_bad: float = 0.02, seed: int = 0):
    """Two cameras' views of posed boards: Gaussian noise per image axis, and `share_bad` of the corners
    moved 0.5-3 px in a random direction. Returns the rig, views, poses and the moved (camera, frame, id)."""
    rng = np.random.default_rng(seed)
    cal = stereo_rig()
    pts = BOARD.corner_points_mm()
    poses = dict(enumerate(board_poses(n_views, BOARD, seed=seed)))
    views, moved = {}, set()
    for n, cam in cal.cameras.items():
        views[n] = {}
        for f, T in poses.items():
            px = cam.project(pts @ T[:3, :3].T + T[:3, 3])
            ids = np.flatnonzero((px[:, 0] > 0) & (px[:, 0] < cam.width) & (px[:, 1] > 0) & (px[:, 1] < cam.height))
            px = px[ids] + rng.normal(0.0, noise, (len(ids), 2))
            bad = rng.random(len(ids)) < share_bad
            angle = rng.uniform(0, 2 * np.pi, bad.sum())
            px[bad] += rng.uniform(0.5, 3.0, bad.sum())[:, None] * np.stack([np.cos(angle), np.sin(angle)], 1)
            moved |= {(n, f, int(i)) for i in ids[bad]}
            views[n][f] = BoardView(frame=f, source_frame=f, ids=ids, corners=px)
    # the board poses fitted to the detections, as the calibration's are
    return cal, views, fit_frame_poses(cal, views, BOARD, sorted(poses), poses), moved


def test_moved_corners_are_flagged_and_the_noise_is_the_rest():
    cal, views, poses, moved = _views()
    screen = screen_corners(cal, views, BOARD, poses)
    left_out = {(n, f, int(i)) for n, vs in views.items() for f, v in vs.items()
                for i in np.setdiff1d(v.ids, screen.kept[n][f].ids)}
    assert len(moved) > 40
    assert moved <= left_out  # every corner moved 0.5 px or more (8+ sd)
    assert len(left_out - moved) <= 2  # a Gaussian corner beyond 5 sd: about 1 in 270,000
    for n in ("side", "front"):
        assert screen.noise_px[n] == pytest.approx([0.06, 0.04], rel=0.04)
        assert screen.robust_sd_px[n] == pytest.approx([0.06, 0.04], rel=0.08)
        assert screen.misdetected[n] == sum(1 for c in moved if c[0] == n)
        assert screen.summary(n)["corners_screened"] == sum(len(v) for v in views[n].values())
    # the calibration points from the kept views hold no moved corner
    pts = calibration_points(cal, screen.kept, BOARD, poses)
    rows = set(zip(pts.frame, pts.corner_id, strict=True))
    assert not {(f, i) for _, f, i in moved} & rows
    assert len(rows) > 0.95 * len(calibration_points(cal, views, BOARD, poses))


def test_clean_views_lose_nothing_and_a_few_residuals_are_not_judged():
    cal, views, poses, moved = _views(share_bad=0.0, seed=1)
    screen = screen_corners(cal, views, BOARD, poses)
    assert not moved and sum(screen.misdetected.values()) <= 1 and len(screen.frames_changed) <= 1
    few = {n: {f: vs[f] for f in list(vs)[:0]} for n, vs in views.items()}
    few["side"] = {0: BoardView(0, 0, views["side"][0].ids[:5], views["side"][0].corners[:5] + 2.0)}
    screen = screen_corners(cal, few, BOARD, poses)
    assert screen.misdetected == {"side": 0, "front": 0}
    assert np.isnan(screen.noise_px["front"]).all() and screen.noise_px["side"][0] > 1.0
