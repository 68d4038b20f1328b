"""Half-block rendering: area-averaged downscale, marker boost, cell <-> source mapping, strips."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sandtrack_tui.tui.frame_view import (
    BOOST_RGB,
    HALF,
    StripBuilder,
    ViewTransform,
    quantize,
    render_pixels,
)


def sand_with_markers(w=1920, h=1080, centres=(), radius=4.5, seed=0):
    rng = np.random.default_rng(seed)
    img = np.clip(np.array([120, 170, 200]) + rng.normal(0, 20, (h, w, 3)), 0, 255).astype(np.uint8)
    for x, y in centres:
        cv2.circle(img, (int(x * 16), int(y * 16)), int(radius * 16), (190, 70, 20), -1, cv2.LINE_AA, shift=4)
    return img


CENTRES = [(211.3, 317.8), (640.5, 540.2), (1000.0, 100.7), (1500.2, 900.9), (1800.6, 333.3), (77.7, 1000.1)]


@pytest.mark.parametrize("cols,rows", [(100, 30), (160, 45), (48, 23)])
def test_boost_keeps_every_9px_marker_visible(cols, rows):
    img = sand_with_markers(centres=CENTRES)
    tf = ViewTransform.make(1920, 1080, cols, rows)
    assert tf.s > 10  # a 9 px marker is well under one display pixel
    px = render_pixels(img, tf, boost=True)
    plain = render_pixels(img, tf, boost=False)
    boosted = np.all(px == BOOST_RGB, axis=2)
    assert not np.all(plain == BOOST_RGB, axis=2).any()
    for x, y in CENTRES:
        u, v = tf.source_to_display(x, y)
        u, v = int(round(float(u))), int(round(float(v)))
        assert boosted[max(v - 1, 0):v + 2, max(u - 1, 0):u + 2].any(), (x, y)
    # only near markers: at most a 3x3 patch of display pixels each
    assert boosted.sum() <= 9 * len(CENTRES)


def test_area_average_keeps_mean_colour():
    img = sand_with_markers()
    tf = ViewTransform.make(1920, 1080, 100, 30)
    px = render_pixels(img, tf, boost=False).astype(float)
    shown = px[px.sum(axis=2) > 0]  # letterbox rows are black
    np.testing.assert_allclose(shown.mean(axis=0), img.reshape(-1, 3)[:, ::-1].mean(axis=0), atol=2.0)
    assert shown.std(axis=0).max() < 1.2  # noise averaged away, no aliasing (measured 0.81)


def test_cell_mapping_round_trip_and_zoom():
    tf = ViewTransform.make(1920, 1080, 100, 30, zoom=4.0, center=(1500.0, 200.0))
    assert tf.x0 > 0 and tf.y0 >= 0
    for col, row in [(0, 0), (37, 11), (99, 29)]:
        x, y = tf.cell_to_source(col, row)
        assert tf.source_to_cell(x, y) == (col, row)
        assert x == pytest.approx(tf.x0 + (col + 0.5) * tf.s) and y == pytest.approx(tf.y0 + (2 * row + 1) * tf.s)
    # a zoomed view never leaves the image
    edge = ViewTransform.make(1920, 1080, 100, 30, zoom=4.0, center=(5000.0, -50.0))
    assert edge.x0 + 100 * edge.s == pytest.approx(1920) and edge.y0 == pytest.approx(0)


def test_strips_merge_runs_and_carry_labels():
    rgb = np.zeros((6, 10, 3), np.uint8)
    rgb[:, 5:] = (200, 100, 50)
    labels = {(1, 2): ("7", None)}
    strips = StripBuilder().build(rgb, labels)
    assert len(strips) == 3 and all(s.cell_length == 10 for s in strips)
    assert [seg.text for seg in strips[0]] == [HALF * 5, HALF * 5]
    assert "".join(seg.text for seg in strips[1]) == HALF * 2 + "7" + HALF * 7


def test_256_colours_use_palette_greys_and_keep_markers_blue():
    rgb = np.array([[[1, 100, 250], [130, 180, 254], [150, 140, 128], list(BOOST_RGB)]], np.uint8)
    q = quantize(rgb, "256").astype(int)
    greys = {0, 95, 135, 175, 215, 255} | {8 + 10 * k for k in range(24)}
    for px in q[0, :3]:
        assert px[0] == px[1] == px[2] and px[0] in greys
    assert tuple(q[0, 3]) == (0, 95, 255)


def test_boost_shows_markers_like_a_seeded_black_one_not_a_shadow():
    from sandtrack_tui.tracking.run import marker_look

    rng = np.random.default_rng(3)
    img = np.clip(np.array([120, 170, 200]) + rng.normal(0, 20, (1080, 1920, 3)), 0, 255).astype(np.uint8)
    img[300:800, 900:1500] = (img[300:800, 900:1500] * 0.55).astype(np.uint8)  # the tool's shadow
    dark = [(211.3, 317.8), (640.5, 540.2), (1000.0, 400.7), (1300.2, 700.9), (1800.6, 333.3)]
    for x, y in dark:
        cv2.circle(img, (int(x * 16), int(y * 16)), int(4.5 * 16), (25, 25, 30), -1, cv2.LINE_AA, shift=4)
    look = marker_look(img, *dark[0])
    assert look is not None and look.kind == "dark"
    tf = ViewTransform.make(1920, 1080, 100, 30)
    boosted = np.all(render_pixels(img, tf, boost=True, look=look) == BOOST_RGB, axis=2)
    assert not np.all(render_pixels(img, tf, boost=True) == BOOST_RGB, axis=2).any()  # (the blue default)
    for x, y in dark:  # in the light and in the shadow
        u, v = (int(round(float(c))) for c in tf.source_to_display(x, y))
        assert boosted[max(v - 1, 0):v + 2, max(u - 1, 0):u + 2].any(), (x, y)
    assert boosted.sum() <= 9 * len(dark)  # the shadow and its edges are not painted
