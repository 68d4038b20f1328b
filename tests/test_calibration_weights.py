"""Per-view noise weighting in the bundle adjustment, and the windowed board search."""

from __future__ import annotations

import numpy as np

from sandtrack_tui.board import BoardSpec
from sandtrack_tui.calibration.bundle import BundleState, bundle_adjust, residuals, view_weights
from sandtrack_tui.calibration.detect import BoardDetector, BoardView
from sandtrack_tui.calibration.geometry import from_T, to_T
from sandtrack_tui.calibration.rig import make_observations
from sandtrack_tui.calibration.synthetic import board_poses, render, stereo_rig

BOARD = BoardSpec(columns=8, rows=5, square_mm=30.0, dictionary="DICT_4X4_50")


def _noisy_problem(n_frames: int, sigma_of_view, seed: int = 0):
    """Exact stereo views with Gaussian noise of a per-(camera, frame) level; the true state."""
    truth = stereo_rig()
    poses = board_poses(n_frames, BOARD, seed=seed)
    rng = np.random.default_rng(seed)
    pts = BOARD.corner_points_mm()
    views = {n: {} for n in truth.names}
    for ci, (n, cam) in enumerate(truth.cameras.items()):
        for f, T in enumerate(poses):
            uv = cam.project(pts @ T[:3, :3].T + T[:3, 3])
            ok = (uv[:, 0] > 0) & (uv[:, 0] < cam.width) & (uv[:, 1] > 0) & (uv[:, 1] < cam.height)
            if ok.sum() >= 12:
                uv = uv[ok] + rng.normal(0, sigma_of_view(ci, f), (ok.sum(), 2))
                views[n][f] = BoardView(frame=f, source_frame=f, ids=np.nonzero(ok)[0], corners=uv)
    frames = sorted(set(views["side"]) & set(views["front"]))
    obs = make_observations(views, truth.names, frames, BOARD)
    cams = [truth.cameras[n] for n in truth.names]
    rt = [from_T(poses[f]) for f in frames]
    state = BundleState(cam_rvec=np.array([c.rvec for c in cams]), cam_tvec=np.array([c.tvec for c in cams]),
                        K=np.array([c.matrix for c in cams]), dist=[c.distortion.copy() for c in cams],
                        models=["pinhole"] * 2, frame_rvec=np.array([r for r, _ in rt]),
                        frame_tvec=np.array([t for _, t in rt]), fixed_k3=[True, True])
    return truth, obs, state, frames


def test_view_weights_follow_the_noise_of_each_view():
    noisy = {3, 8, 11, 17, 25}
    _, obs, state, frames = _noisy_problem(40, lambda c, f: 0.8 if f in noisy else 0.2, seed=1)
    state, _ = bundle_adjust(state, obs, free_intrinsics=False)
    w = view_weights(residuals(state, obs), obs)
    frame_of = np.array(frames)[obs.frame]
    bad = np.isin(frame_of, list(noisy))
    # a 4x larger noise is 16x less weight; the estimate of each view is good to a factor of about 2
    assert 1 / 40 < np.median(w[bad]) < 1 / 6
    assert 0.7 < np.median(w[~bad]) < 1.4


def test_view_weights_are_one_when_views_share_one_noise_level():
    _, obs, state, _ = _noisy_problem(40, lambda c, f: 0.3, seed=2)
    state, _ = bundle_adjust(state, obs, free_intrinsics=False)
    w = view_weights(residuals(state, obs), obs)
    # the spread of the per-view estimates is sampling noise only: shrunk to (almost) no weighting
    assert np.all((w > 0.8) & (w < 1.25))


def test_weighted_bundle_adjustment_beats_unweighted_on_mixed_noise():
    rng = np.random.default_rng(5)
    level = {(c, f): (1.5 if rng.random() < 0.3 else 0.1) for c in range(2) for f in range(60)}
    truth, obs, state, _ = _noisy_problem(60, lambda c, f: level[(c, f)], seed=5)
    K_true, t_true = state.K.copy(), state.cam_tvec[1].copy()
    start = state.copy()
    start.K = start.K * np.array([[1.01, 1, 1.003], [1, 1.01, 0.997], [1, 1, 1]])
    plain, _ = bundle_adjust(start, obs)
    weighted, _ = bundle_adjust(plain, obs, weights=view_weights(residuals(plain, obs), obs))

    def errors(s):  # worst principal point error (px), translation error of the second camera (mm)
        return np.max(np.hypot(*(s.K[:, :2, 2] - K_true[:, :2, 2]).T)), np.linalg.norm(s.cam_tvec[1] - t_true)

    (pp_plain, t_plain), (pp_w, t_w) = errors(plain), errors(weighted)
    assert pp_w < 0.5 * pp_plain and t_w < 0.5 * t_plain


def test_hint_window_search_never_loses_corners_when_the_board_moved():
    cam = stereo_rig(size=(1920, 1080), focal=(1500.0, 1500.0)).cameras["side"]
    det = BoardDetector(BOARD, edge_refine=False)  # the window search against _detect_full, both as OpenCV finds them
    T = board_poses(1, BOARD, seed=4, spread_mm=(0.0, 0.0, 0.0), max_tilt_deg=10.0)[0]
    moves = [0.0, 40.0, 160.0, 260.0]  # mm to the right: within the window, then partly and wholly out of it
    images = render(cam, BOARD, [to_T(np.zeros(3), [dx, 0.0, 0.0]) @ T for dx in moves], noise=1.0)
    hint = det.detect(images[0])
    assert hint is not None and len(hint) == BOARD.n_corners
    for img in images[1:]:
        full = det._detect_full(img)
        found = det.detect(img, hint)
        assert full is not None and found is not None and len(found) == len(full)
        assert np.abs(found.corners - full.corners).max() < 1e-4
    det.detect(images[1], hint)
    assert det.hint_hit()  # a small move is settled inside the window
    det.detect(images[2], hint)
    assert not det.hint_hit()


def test_board_seen_from_behind_is_searched_on_that_side_first():
    cam = stereo_rig(size=(960, 540), focal=(800.0, 800.0)).cameras["side"]
    T = board_poses(1, BOARD, seed=2, spread_mm=(0.0, 0.0, 0.0), max_tilt_deg=10.0)[0]
    img = np.ascontiguousarray(render(cam, BOARD, [T], noise=1.0)[0][:, ::-1])  # the board's mirror image
    det = BoardDetector(BOARD)
    first = det.detect(img)
    assert first is not None and first.mirrored and len(first) == BOARD.n_corners
    calls = []
    search = det._detect_charuco
    det._detect_charuco = lambda gray: calls.append(1) or search(gray)
    again = det.detect(img, first)
    assert again is not None and again.mirrored and len(calls) == 1  # no wasted search of the plain side
    assert np.abs(again.corners - first.corners).max() < 1e-9


def test_grey_frames_from_the_luma_plane_equal_ffmpeg_grey(tmp_path):
    import av

    from sandtrack_tui.calibration.detect import _gray_frames, _luma, open_source
    from sandtrack_tui.calibration.synthetic import _write_mp4

    rng = np.random.default_rng(0)
    images = [cv2_blur(rng.integers(0, 256, (120, 162), dtype=np.uint8)) for _ in range(6)]  # odd width: padded rows
    path = tmp_path / "clip.mp4"
    _write_mp4(path, images, 25)
    reference = []
    with av.open(str(path)) as container:
        for f in container.decode(video=0):
            reference.append(f.to_ndarray(format="gray"))
            assert np.array_equal(_luma(f), reference[-1])  # the fast path is taken, not only the fallback
    got = dict(_gray_frames(open_source(path), range(6)))
    assert sorted(got) == list(range(6))
    for k, grey in got.items():
        assert np.array_equal(grey, reference[k])


def cv2_blur(img):
    import cv2

    return cv2.GaussianBlur(img, (0, 0), 1.5)
