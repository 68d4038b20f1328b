"""Digital twin: the calibration board drawn only around each pose's plate and shadow gives exactly the pixels of
computing every pixel of the board's window (the committed sample videos depend on it, byte for byte)."""

import cv2
import numpy as np
import pytest

from sandtrack_tui.twin.board_motion import (
    BOARD_PPM,
    PLATE_MARGIN_MM,
    SHUTTER_S,
    BoardMotion,
    BoardRenderer,
    _remap_points,
    _times,
)
from sandtrack_tui.twin.rig import LIGHT_DIR, SAND_Y
from sandtrack_tui.twin.sample import BOARD, _make_view


def _draw_every_pixel(painter: BoardRenderer, view, img, poses):
    """Reference: every pose computed on every pixel of the window holding all plates and shadows."""
    pts = np.concatenate([painter._corners_world(R, t) for R, t in poses])
    bb = view.image_bbox(pts.min(0) - 5, pts.max(0) + 5, pad=3)
    L = LIGHT_DIR
    feet = pts - L * ((pts[:, 1] - SAND_Y) / L[1])[:, None]
    bbs = view.image_bbox(np.minimum(feet.min(0), pts.min(0)) - 8, np.maximum(feet.max(0), pts.max(0)) + 8, pad=3)
    y0, y1, x0, x1 = bbs
    ys, xs = slice(y0, y1), slice(x0, x1)
    base = img[ys, xs].astype(np.float32)
    acc = np.zeros_like(base)
    d = view.d[ys, xs].astype(np.float64)
    depth = view.depth[ys, xs]
    P = view.P[ys, xs].astype(np.float64)
    is_sand = np.isfinite(depth) & (P[..., 1] < SAND_Y + 40)
    inb = np.zeros(depth.shape, bool)
    by0, by1, bx0, bx1 = bb
    inb[by0 - y0 : by1 - y0, bx0 - x0 : bx1 - x0] = True
    for R, t in poses:
        lam_s = painter._hit(P, np.broadcast_to(L, P.shape), R, t)[0]
        out = np.where((is_sand & np.isfinite(lam_s))[..., None], base * 0.55, base)
        lam, u, v, facing = painter._hit(view.C, d, R, t)
        vis = inb & (lam < depth)
        n_face = -R[:, 2]
        if facing:
            tu = ((u + PLATE_MARGIN_MM) * BOARD_PPM - 0.5).astype(np.float32)
            tv = ((v + PLATE_MARGIN_MM) * BOARD_PPM - 0.5).astype(np.float32)
            alb = cv2.remap(painter.albedo, tu, tv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            col = alb[..., None] * ((0.42 + 0.62 * max(float(n_face @ L), 0.0)) * 255.0) * np.array(
                [0.96, 0.98, 1.0], np.float32)
        else:
            shade = 0.35 + 0.5 * max(float(-n_face @ L), 0.0)
            col = np.broadcast_to(np.array([0.50, 0.52, 0.55], np.float32) * shade * 255.0, out.shape)
        out = np.where(vis[..., None], col * view.vignette[ys, xs, None], out)
        acc += out
    img[ys, xs] = np.clip(acc / len(poses), 0, 255).astype(np.uint8)
    return img


@pytest.fixture(scope="module")
def front_view():
    return _make_view("front", 0)


@pytest.mark.parametrize("tau", [0.5, 2.1, 3.13, 4.02, 6.75])  # flat, lifting, fast flick, tilted, flick
def test_restricted_board_drawing_is_pixel_identical(front_view, tau):
    motion = BoardMotion(BOARD, 0)
    painter = BoardRenderer(BOARD)
    poses = [motion.pose(tau + SHUTTER_S * (j / 3 - 0.5)) for j in range(4)]  # motion blur: 4 sub-poses
    fast = painter.draw(front_view, front_view.canvas.copy(), poses)
    ref = _draw_every_pixel(painter, front_view, front_view.canvas.copy(), poses)
    assert not np.array_equal(ref, front_view.canvas)  # the board (or its shadow) is in view
    assert np.array_equal(fast, ref)


def test_point_lookups_and_blocked_products_match_whole_array_results():
    rng = np.random.default_rng(3)
    image = rng.random((300, 500)).astype(np.float32)
    x = (rng.random((70, 90)) * 520 - 10).astype(np.float32)
    y = (rng.random((70, 90)) * 320 - 10).astype(np.float32)
    whole = cv2.remap(image, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    assert np.array_equal(_remap_points(image, x.ravel(), y.ravel()), whole.ravel())
    a = rng.normal(size=(10_000, 3)) * 300
    m = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    assert np.array_equal(_times(a, m, rows=999), (a.reshape(100, 100, 3) @ m).reshape(-1, 3))


def test_the_board_rests_where_it_is_told_then_moves_alike():
    from sandtrack_tui.twin.board_motion import FLAT_UNTIL_S, LIFT_S, R_REF, REF_ORIGIN

    default, moved = BoardMotion(BOARD, 3), BoardMotion(BOARD, 3, REF_ORIGIN + [30.0, 0.0, -45.0])
    for t in (0.0, 0.5 * FLAT_UNTIL_S):
        assert np.array_equal(default.pose(t)[0], R_REF) and np.array_equal(default.pose(t)[1], REF_ORIGIN)
        assert np.array_equal(moved.pose(t)[1], REF_ORIGIN + [30.0, 0.0, -45.0])
    later = FLAT_UNTIL_S + LIFT_S + 2.0  # lifted: the hand's motion, wherever the board lay
    assert all(np.allclose(a, b) for a, b in zip(default.pose(later), moved.pose(later), strict=True))
