"""Board corners at the crossing of their square edges (calibration/corners.py) against the truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sandtrack_tui.board import BoardSpec
from sandtrack_tui.calibration.corners import refine_corners
from sandtrack_tui.calibration.detect import BoardDetector
from sandtrack_tui.calibration.synthetic import board_poses, render, stereo_rig

CAM = stereo_rig(size=(1280, 720), focal=(1000.0, 1000.0)).cameras["side"]


def _scene(board: BoardSpec, n: int = 4, distance_mm: float = 900.0):
    poses = board_poses(n, board, seed=3, distance_mm=distance_mm, max_tilt_deg=45)
    truths = [CAM.project(board.corner_points_mm() @ T[:3, :3].T + T[:3, 3]) for T in poses]
    return render(CAM, board, poses, noise=2.0), truths


def _errors(board: BoardSpec, images, truths, blur: float) -> tuple[np.ndarray, np.ndarray]:
    """Corner errors (px) as OpenCV finds them and after the edge refinement, over all images."""
    det = BoardDetector(board, edge_refine=False)
    margin = 0.5 * (board.square_mm - board.marker_size_mm) / board.square_mm if board.type == "charuco" else 0.5
    plain, refined = [], []
    for img, truth in zip(images, truths, strict=True):
        img = cv2.GaussianBlur(img, (0, 0), blur) if blur else img
        view = det.detect(img)
        assert view is not None
        better = refine_corners(img, np.stack([view.ids % 7, view.ids // 7], axis=1), view.corners, margin)
        # a chessboard's corner order may run either way: compare with the nearest true corner
        nearest = truth[((view.corners[:, None] - truth[None]) ** 2).sum(-1).argmin(axis=1)]
        plain.append(view.corners - nearest)
        refined.append(better - nearest)
    return np.concatenate(plain), np.concatenate(refined)


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt((e ** 2).sum(axis=1).mean()))


@pytest.mark.parametrize("kind", ["charuco", "chessboard"])
def test_edge_lines_locate_corners_better_than_opencv(kind):
    board = BoardSpec(type=kind, columns=8, rows=5, square_mm=30.0, dictionary="DICT_4X4_50")
    images, truths = _scene(board, n=3)
    for blur in (0.0, 1.2):  # sharp, and defocused / moving
        plain, refined = (_rms(e) for e in _errors(board, images, truths, blur))
        assert refined < 0.04 and refined < 0.5 * plain, (kind, blur, plain, refined)


def test_the_detector_returns_the_refined_corners():
    board = BoardSpec(columns=8, rows=5, square_mm=30.0, dictionary="DICT_4X4_50")
    img = _scene(board, n=1)[0][0]
    plain = BoardDetector(board, edge_refine=False).detect(img)
    refined = BoardDetector(board).detect(img)
    expected = refine_corners(img, np.stack([plain.ids % 7, plain.ids // 7], axis=1), plain.corners, 0.125)
    assert np.array_equal(refined.ids, plain.ids) and np.allclose(refined.corners, expected)
    assert np.abs(refined.corners - plain.corners).max() > 0.01


def test_corners_that_cannot_be_measured_keep_the_detector_position():
    board = BoardSpec(columns=8, rows=5, square_mm=30.0, dictionary="DICT_4X4_50")
    images, truths = _scene(board, n=1)
    img, truth = images[0], truths[0]
    view = BoardDetector(board, edge_refine=False).detect(img)
    grid = np.stack([view.ids % 7, view.ids // 7], axis=1)
    # The image cut through the board: corners whose edge arms leave the image stay as they were.
    x_cut = int(np.median(view.corners[:, 0]))
    part = np.ascontiguousarray(img[:, :x_cut])
    inside = view.corners[:, 0] < x_cut
    refined = refine_corners(part, grid[inside], view.corners[inside], margin=0.125)
    # (squares ~33 px here: an arm reaches ~15 px, so one of a corner's two lines crosses a cut
    # less than 8 px away whatever the board's angle; corners 20 px or more from it are measured)
    x = view.corners[inside, 0]
    near_edge, far = x > x_cut - 8, x < x_cut - 20
    assert near_edge.any() and far.sum() >= 6
    assert np.array_equal(refined[near_edge], view.corners[inside][near_edge])
    e_before = _rms(view.corners[inside][far] - truth[view.ids[inside][far]])
    e_after = _rms(refined[far] - truth[view.ids[inside][far]])
    assert e_after < 0.6 * e_before
    # Too few corners for the local homographies, or squares too small to measure: unchanged.
    assert np.array_equal(refine_corners(img, grid[:5], view.corners[:5], 0.125), view.corners[:5])
    small = cv2.resize(img, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
    assert np.array_equal(refine_corners(small, grid, view.corners * 0.25, 0.125), view.corners * 0.25)


def test_local_homographies_of_a_large_board_fit_each_neighbourhood():
    from sandtrack_tui.calibration.corners import _apply, _local_homographies

    u, v = np.meshgrid(np.arange(40.0), np.arange(30.0), indexing="ij")
    grid = np.stack([u.ravel(), v.ravel()], axis=1)  # 1,200 corners: neighbours only, not all pairs
    H_true = np.array([[31.0, 4.0, 200.0], [-3.0, 29.0, 150.0], [2e-4, 1e-4, 1.0]])
    corners = _apply(H_true[None], grid[None])[0]
    H, ok = _local_homographies(grid, corners)
    assert ok.all()
    probe = grid[:, None, :] + np.array([[0.5, 0.0], [0.0, -0.5], [0.3, 0.3]])  # points between the corners
    expected = _apply(np.broadcast_to(H_true, H.shape), probe)
    assert np.abs(_apply(H, probe) - expected).max() < 1e-6
