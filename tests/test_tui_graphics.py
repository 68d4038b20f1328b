"""Real pixels: the escape codes sandtrack emits, decoded by an independent terminal model
(fake_terminal.py), against the frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fake_terminal import UNSET, FakeTerminal
from sandtrack_tui.tui import sixel
from sandtrack_tui.tui.frame_view import STATUS_RGB, MarkerMark, Overlays, ViewTransform
from sandtrack_tui.tui.graphics import compose, palette_png, pixel_transform, render_view
from sandtrack_tui.tui.tiles import TOLERANCE, GraphicsView

CELL = (8, 16)
COLS, ROWS = 60, 20  # a view of 480 x 320 screen pixels
ORIGIN = (3, 2)  # the view's first cell on the screen


def sand(w=960, h=540, markers=(), seed=0):
    """Sand-coloured texture (BGR) with 9 px blue markers at `markers` (source px)."""
    rng = np.random.default_rng(seed)
    img = np.clip(np.array([120, 170, 200]) + rng.normal(0, 22, (h // 2, w // 2, 3)), 0, 255).astype(np.uint8)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_LINEAR)
    img[:, : w // 5] = (60, 80, 90)  # a dark wall
    for x, y in markers:
        cv2.circle(img, (int(x * 16), int(y * 16)), 72, (190, 70, 20), -1, cv2.LINE_AA, shift=4)
    return img


def reference(frame_bgr: np.ndarray, tf: ViewTransform) -> np.ndarray:
    """The region a whole-frame view shows, at the view's pixels, by OpenCV directly (area average)."""
    ptf = pixel_transform(tf, CELL[0])
    out = np.zeros((2 * ptf.rows, ptf.cols, 3), np.uint8)
    h, w = frame_bgr.shape[:2]
    x0, y0 = round(-ptf.x0 / ptf.s), round(-ptf.y0 / ptf.s)
    out[y0:y0 + round(h / ptf.s), x0:x0 + round(w / ptf.s)] = cv2.resize(
        frame_bgr, (round(w / ptf.s), round(h / ptf.s)), interpolation=cv2.INTER_AREA)[:, :, ::-1]
    return out


def shown(term: FakeTerminal) -> np.ndarray:
    return term.region(*ORIGIN, COLS, ROWS).astype(np.int16)


def draw(mode: str, frames, overlays=None):
    """GraphicsView output for each frame; yields (frame, pixels, payload)."""
    out: list[str] = []
    gv = GraphicsView(mode, CELL, 256, 0, out.append)
    tf = ViewTransform.make(frames[0].shape[1], frames[0].shape[0], COLS, ROWS)
    for frame in frames:
        px = render_view(frame, tf, CELL)
        gv.draw(px, tf, overlays or Overlays(), "", ORIGIN)
        yield gv, tf, px, "".join(out)
        out.clear()


@pytest.mark.parametrize("mode", ["kitty", "sixel"])
def test_decoded_stream_is_the_frame(mode):
    frame = sand(markers=[(500.3, 300.7), (700.0, 120.2)])
    term = FakeTerminal(80, 26, CELL)
    gv, tf, px, data = next(draw(mode, [frame]))
    term.feed(data)
    screen = shown(term)
    assert not np.all(screen == UNSET, axis=2).any()  # every pixel of the view was drawn
    # against what the view meant to show: only the palette's error (256 colours for noisy sand)
    err = np.abs(screen - compose(px, tf, CELL, Overlays())).max(axis=2)
    assert err.mean() < 5 and np.percentile(err, 99) <= 12 and err.max() <= 21  # measured 4.1, 10, 14
    # against the frame resampled by OpenCV on its own
    err = np.abs(screen - reference(frame, tf)).max(axis=2)
    assert err.mean() < 5 and np.percentile(err, 99) <= 12
    # the markers are there, at their pixels
    for x, y in [(500.3, 300.7), (700.0, 120.2)]:
        u, v = (int(round(float(c))) for c in pixel_transform(tf, CELL[0]).source_to_display(x, y))
        b, g, r = screen[v, u][::-1]
        assert b > r + 60, (x, y, screen[v, u])


@pytest.mark.parametrize("mode", ["kitty", "sixel"])
def test_steps_send_only_what_moved_and_stay_within_the_tolerance(mode):
    frames = [sand(markers=[(400 + 6 * k, 300)], seed=0) for k in range(6)]
    frames[3] = np.clip(frames[3].astype(np.int16) + np.random.default_rng(3).integers(-6, 7, frames[3].shape),
                        0, 255).astype(np.uint8)  # sensor noise everywhere: under the tolerance
    term = FakeTerminal(80, 26, CELL)
    sizes = []
    for k, (gv, tf, _, data) in enumerate(draw(mode, frames)):
        term.feed(data)
        sizes.append(len(data))
        screen = shown(term)
        c = gv.canvas
        # what the canvas believes is shown (sixel gives colours in percent: within 1.3 levels)
        assert np.abs(screen - c.palette.colours[c.shown_idx]).max() <= (0 if mode == "kitty" else 1), k
        # each pixel: its palette colour now, or what it was last sent as, within the tolerance of now
        now = np.all(c.shown_idx == c.idx)
        moved = np.abs(c.rgb.astype(np.int16) - c.sent).max(axis=2)
        assert now or moved[c.shown_idx != c.idx].max() <= TOLERANCE, k
        assert np.abs(screen - c.rgb).max() <= TOLERANCE + 24, k  # 24: the palette's error on this sand
        u, v = (int(round(float(c))) for c in pixel_transform(tf, CELL[0]).source_to_display(400 + 6 * k, 300))
        assert screen[v, u, 2] > screen[v, u, 0] + 60, k  # the marker shows where it is now
    assert max(sizes[1:]) < sizes[0] / 10  # a moving marker: a few tiles, not the view
    assert sizes[3] < sizes[0] / 10 and sizes[4] < sizes[0] / 10  # noise (and its end) sends (almost) nothing


@pytest.mark.parametrize("mode", ["kitty", "sixel"])
def test_overlays_are_drawn_into_the_pixels(mode):
    frame = sand(markers=[(600, 300)])
    marks = [MarkerMark(3, "3", 600.0, 300.0, "tracked"), MarkerMark(5, "5", 300.0, 200.0, "lost", selected=True)]
    term = FakeTerminal(80, 26, CELL)
    gv, tf, px, data = next(draw(mode, [frame], Overlays(marks=marks, cursor=(800.0, 400.0))))
    term.feed(data)
    screen = shown(term)
    ptf = pixel_transform(tf, CELL[0])
    green = np.all(np.abs(screen - STATUS_RGB["tracked"]) <= 2, axis=2)
    u, v = (float(c) for c in ptf.source_to_display(600.0, 300.0))
    half = 10 / ptf.s  # the box: 10 source px around the marker
    box = green[int(v - half - 2):int(v + half + 3), int(u - half - 2):int(u + half + 3)]
    assert box[:, 0].sum() + box[:, -1].sum() + box.sum() > 20  # its outline, in the status colour
    assert not green[int(v) - 1:int(v) + 2, int(u) - 1:int(u) + 2].any()  # the marker itself is not covered
    # the ids are written in pixels, in their cells: "3" beside the box, "5" reversed (selected) on red
    labels = compose(px, tf, CELL, Overlays(marks=marks)).astype(np.int16) - compose(px, tf, CELL, Overlays())
    assert (np.abs(labels).max(axis=2) > 0).sum() > 100
    yellow = np.all(np.abs(screen - (255, 230, 0)) <= 2, axis=2)
    cu, cv = (int(round(float(c))) for c in ptf.source_to_display(800.0, 400.0))
    assert yellow[cv - 4:cv + 5, cu - 4:cu + 5].sum() >= 8  # the cursor's cross


def test_kitty_hide_and_show_send_no_pixels():
    term = FakeTerminal(80, 26, CELL)
    gv, tf, px, data = next(draw("kitty", [sand()]))
    term.feed(data)
    before = shown(term)
    term.feed(gv.canvas.hide())
    assert not term.placements  # another screen on top: the pictures are gone
    again = gv.canvas.show()
    assert "a=p" in again and "a=T" not in again and len(again) < len(data) / 20  # put back, no pixels
    term.feed(again)
    assert np.array_equal(shown(term), before)
    term.feed(gv.canvas.clear(free=True))
    assert not term.placements and not term.images


def test_sixel_tiles_under_rewritten_text_are_drawn_again():
    term = FakeTerminal(80, 26, CELL)
    gv, tf, px, data = next(draw("sixel", [sand()]))
    term.feed(data)
    before = shown(term)
    row = ORIGIN[1] + 7
    term.feed(f"\x1b[{row + 1};1H" + "notification text over the view")  # Textual writes a toast's line
    assert not np.array_equal(shown(term), before)
    gv.canvas.repainted([(row, 0, 31)])
    again = gv.canvas.flush()
    term.feed(again)
    assert np.array_equal(shown(term), before)
    assert 0 < len(again) < len(data) / 5  # the tiles under that text only


@pytest.mark.parametrize("h,w,colours", [(1, 1, 1), (5, 7, 3), (6, 6, 2), (13, 40, 256), (40, 80, 200)])
def test_sixel_encoder_round_trip(h, w, colours):
    rng = np.random.default_rng(h * w)
    palette = rng.integers(0, 256, (256, 3)).astype(np.uint8)
    idx = rng.integers(0, colours, (h, w)).astype(np.uint8)
    idx[: h // 2, : w // 2] = 0  # runs as well as noise
    term = FakeTerminal(20, 10, (w, h))
    term.feed("\x1b[2;3H" + sixel.encode(idx, sixel.colour_definitions(palette)))
    pct = (palette.astype(int) * 100 + 127) // 255
    expected = np.round(pct * 255 / 100).astype(np.uint8)[idx]
    assert np.array_equal(term.region(2, 1, 1, 1), expected)
    assert term.sixel_set[h:2 * h, 2 * w:3 * w].all() and term.sixel_set.sum() == h * w  # nothing outside


def test_palette_png_decodes_with_opencv():
    rng = np.random.default_rng(1)
    idx = rng.integers(0, 37, (40, 80)).astype(np.uint8)
    colours = rng.integers(0, 256, (37, 3)).astype(np.uint8)
    decoded = cv2.imdecode(np.frombuffer(palette_png(idx, colours), np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
    assert np.array_equal(decoded, colours[idx])


def test_ids_in_a_crowd_get_leader_lines_at_pixel_scale():
    frame = sand()
    marks = [MarkerMark(k, str(k), 500 + 14 * (k % 5), 300 + 14 * (k // 5), "tracked") for k in range(1, 21)]
    term = FakeTerminal(80, 26, CELL)
    gv, tf, px, data = next(draw("kitty", [frame], Overlays(marks=marks)))
    term.feed(data)
    screen = shown(term)
    leader = np.all(np.abs(screen - tuple(int(v * 0.7) for v in STATUS_RGB["tracked"])) <= 2, axis=2)
    assert leader.sum() > 50  # ids moved away from their beads are joined to them by a line
    # each line is one pixel wide at the terminal's resolution, not a half-block pixel (8 x 8 here)
    rows = leader.any(axis=1)
    assert leader[rows].sum(axis=1).min() <= 3
