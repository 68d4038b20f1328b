"""The terminal UI drawing real pixels (kitty graphics, sixel) and half-blocks, driven by Pilot: what
it writes for the terminal, decoded, against the frames; and the same app over a real pty."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from conftest import POLL_LIMIT_S
from fake_terminal import FakeTerminal, PtyTerminal
from sandtrack_tui.tui.app import SandtrackApp
from sandtrack_tui.tui.frame_view import HALF, ViewTransform
from sandtrack_tui.tui.graphics import compose, pixel_transform
from sandtrack_tui.tui.termcaps import Graphics
from sandtrack_tui.tui.tiles import TOLERANCE
from test_tui_app import aio, settle
from tui_synth import N_FRAMES, make_frames, make_project, render, true_xy

SIZE = (100, 30)
CELL = (8, 16)
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return make_frames(tmp_path_factory.mktemp("frames"))


@pytest.fixture
def project(tmp_path, frames):
    proj = make_project(tmp_path, frames=frames, calibrated=True)
    rows = [(f, cam, m, *true_xy(m, f, cam), "manual") for f in range(N_FRAMES) for cam in ("side", "front")
            for m in (1, 2)]
    proj.set_points(pd.DataFrame(rows, columns=["frame", "camera", "marker", "x_px", "y_px", "status"]), "seeds")
    yield proj
    proj.close()


def expected_view(frame_index: int, camera: str, region) -> np.ndarray:
    """The frame the view shows, resampled by OpenCV on its own to the view's pixels (RGB)."""
    img = render(frame_index, camera)
    tf = pixel_transform(ViewTransform.make(img.shape[1], img.shape[0], region.width, region.height), CELL[0])
    out = np.zeros((2 * tf.rows, tf.cols, 3), np.uint8)
    w, h = round(img.shape[1] / tf.s), round(img.shape[0] / tf.s)
    x0, y0 = round(-tf.x0 / tf.s), round(-tf.y0 / tf.s)
    out[y0:y0 + h, x0:x0 + w] = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)[:, :, ::-1]
    return out


def check_views(app, term: FakeTerminal) -> None:
    for v in app.views():
        r = v.content_region
        screen = term.region(r.x, r.y, r.width, r.height).astype(np.int16)
        # what the app meant to show (frame + overlays), within the tolerance and the palette's error
        meant = compose(v.pixels, v.tf, CELL, v.overlays)
        err = np.abs(screen - meant).max(axis=2)
        assert err.max() <= 18 and err.mean() < 4.2, (v.camera, err.max(), err.mean())  # measured 12, 2.8
        # the frame itself, resampled independently: equal but for overlay pixels
        err = np.abs(screen - expected_view(app.cam_index(v.camera), v.camera, r)).max(axis=2)
        # measured: median 3, 0.5 % of the pixels (the overlays) over TOLERANCE + 24
        assert np.median(err) <= 4 and (err > TOLERANCE + 24).mean() < 0.008, (v.camera, np.median(err))


@pytest.mark.parametrize("mode", ["kitty", "sixel"])
@aio
async def test_views_are_real_pixels_and_follow_every_step(project, mode):
    app = SandtrackApp(project, graphics=Graphics(mode, CELL))
    out: list[str] = []
    app.write_graphics = out.append
    term = FakeTerminal(*SIZE, CELL)
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        await pilot.pause(0.1)
        assert all(v.graphics is not None for v in app.views())
        assert not any(HALF in seg.text for v in app.views() for y in range(3) for seg in v.render_line(y))
        term.feed("".join(out))
        check_views(app, term)
        full = len("".join(out))
        for _ in range(3):
            out.clear()
            await pilot.press("right")
            await settle(pilot, app)
            await pilot.pause(0.05)
            term.feed("".join(out))
            check_views(app, term)
        assert app.frame == 3
        # zoomed in past the frame's own pixels: each source pixel is a block of screen pixels
        out.clear()
        for _ in range(3):
            await pilot.press("plus")
        await settle(pilot, app, lambda: app.view("side").tf is not None and app.view("side").tf.s < CELL[0])
        await pilot.pause(0.05)
        term.feed("".join(out))
        out.clear()
        v = app.view("side")
        r, ptf = v.content_region, pixel_transform(v.tf, CELL[0])
        screen = term.region(r.x, r.y, r.width, r.height).astype(np.int16)
        src = render(3, "side")[:, :, ::-1].astype(np.int16)
        us, vs = np.meshgrid(np.arange(4, screen.shape[1], 9), np.arange(4, screen.shape[0], 9))
        xs = np.floor(ptf.x0 + (us + 0.5) * ptf.s).astype(int)
        ys = np.floor(ptf.y0 + (vs + 0.5) * ptf.s).astype(int)
        ok = (xs >= 0) & (xs < src.shape[1]) & (ys >= 0) & (ys < src.shape[0])
        err = np.abs(screen[vs[ok], us[ok]] - src[ys[ok], xs[ok]]).max(axis=1)
        # (this synthetic sand's per-channel noise is what a 256-colour palette fits worst)
        assert ptf.s < 1 and np.median(err) <= 8 and (err > TOLERANCE + 24).mean() < 0.03
        await pilot.press("0")
        await settle(pilot, app, lambda: app.zoom["side"] == 1.0)
        await pilot.pause(0.05)
        term.feed("".join(out))
        out.clear()
        check_views(app, term)
        # another screen on top, then back: kitty takes its images off and puts them back without
        # pixels; sixel draws its tiles again over the text Textual wrote (headless: none is written)
        out.clear()
        await pilot.press("question_mark")
        await settle(pilot, app, lambda: not any(v.graphics.canvas.visible for v in app.views()))
        hidden = "".join(out)
        term.feed(hidden)
        if mode == "kitty":
            assert not term.placements and "a=T" not in hidden
        await pilot.press("escape")
        await settle(pilot, app, lambda: all(v.graphics.canvas.visible for v in app.views()))
        await pilot.pause(0.05)
        back = "".join(out)[len(hidden):]
        term.feed(back)
        check_views(app, term)
        if mode == "kitty":
            assert "a=T" not in back and len(back) < full / 10
        out.clear()
        await pilot.press("q")
    if mode == "kitty":  # quitting frees the images, every one
        term.feed("".join(out))
        assert not term.placements and not term.images


@aio
async def test_blocks_when_the_terminal_has_no_graphics(project):
    app = SandtrackApp(project, graphics=Graphics("blocks"))
    out: list[str] = []
    app.write_graphics = out.append
    async with app.run_test(size=SIZE) as pilot:
        await settle(pilot, app)
        assert all(v.graphics is None for v in app.views())
        assert any(HALF in seg.text for seg in app.view("side").render_line(5))
        await pilot.press("right")
        await settle(pilot, app)
    assert out == []


def test_over_a_real_pty(tmp_path, frames):
    """`sandtrack tui` on a pseudo-terminal that offers sixel: it detects sixel itself, and the screen
    rebuilt from everything it wrote shows the frame in the side view with no cell lost to text, also
    after another screen covered it."""
    try:
        proj = make_project(tmp_path, frames=frames)
        proj.close()
        env = dict(os.environ, TERM="xterm-256color", COLORTERM="truecolor",
                   PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
        term = PtyTerminal([sys.executable, "-m", "sandtrack_tui", "tui", str(proj.path)], *SIZE, CELL,
                           sixel=True, env=env)
    except OSError as exc:
        pytest.skip(f"no pseudo-terminal here: {exc}")
    screen = FakeTerminal(*SIZE, CELL)
    fed = 0

    def side_view():
        """The side view's cells on screen now (the pictures in the left half), or None."""
        nonlocal fed
        out = term.output()
        screen.feed(out[fed:])
        fed = len(out)
        ys, xs = np.nonzero(screen.graphics_mask()[:, : SIZE[0] // 2 * CELL[0]])
        if not len(ys):
            return None
        col, row = xs.min() // CELL[0], ys.min() // CELL[1]
        return col, row, (xs.max() + 1) // CELL[0] - col, (ys.max() + 1) // CELL[1] - row

    def shows(frame_index: int) -> bool:
        view = side_view()
        if view is None or f"frame {frame_index}/" not in screen.line(0):
            return False
        col, row, cols, rows = view
        if not screen.graphics_mask()[row * CELL[1]:(row + rows) * CELL[1], col * CELL[0]:(col + cols) * CELL[0]].all():
            return False  # text over the view
        region = type("R", (), {"width": cols, "height": rows})
        err = np.abs(screen.region(col, row, cols, rows).astype(np.int16)
                     - expected_view(frame_index, "side", region)).max(axis=2)
        return np.median(err) <= 4 and (err > TOLERANCE + 24).mean() < 0.03

    def wait_for(condition, what: str) -> None:
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < POLL_LIMIT_S:  # polled until it holds
            if condition():
                return
            if term.proc.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"the screen never showed {what}")

    try:
        wait_for(lambda: shows(0), "frame 0")
        term.write(b"\x1b[C\x1b[C")
        wait_for(lambda: shows(2), "frame 2")
        term.write(b"?")
        wait_for(lambda: not shows(2), "the help screen over the view")
        term.write(b"\x1b")
        wait_for(lambda: shows(2), "frame 2 again after the help screen")
    finally:
        code = term.close()
    assert code == 0
    out = term.output()
    assert b"\x1bP0;1;0q" in out and b"a=T" not in out  # sixel chosen, no kitty image sent


def test_graphics_option(project, monkeypatch, capsys):
    from sandtrack_tui.cli import main
    from sandtrack_tui.tui import termcaps

    asked, chosen = [], []
    monkeypatch.setattr(termcaps, "detect", lambda requested: asked.append(requested) or Graphics("sixel", (9, 18)))
    monkeypatch.setattr(SandtrackApp, "run", lambda app: chosen.append(app.pixels.graphics))
    assert main(["tui", str(project.path)]) == 0
    assert main(["tui", str(project.path), "--graphics", "kitty"]) == 0
    assert asked == ["auto", "kitty"] and chosen[-1] == Graphics("sixel", (9, 18))
    with pytest.raises(SystemExit) as exc:
        main(["tui", str(project.path), "--graphics", "iterm"])
    assert exc.value.code == 2 and "--graphics" in capsys.readouterr().err
    assert main(["tui", str(project.path.with_name("missing.sandtrack")), "--graphics", "sixel"]) == 1
    assert asked == ["auto", "kitty"]  # a project that does not open never queries the terminal
