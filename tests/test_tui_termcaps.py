"""Choosing how frames are drawn: the terminal's answers to the capability queries, over a real pty."""

from __future__ import annotations

import os
import threading
import time

import pytest

from fake_terminal import answer
from sandtrack_tui.tui.termcaps import QUERIES, Replies, choose, detect, parse_replies

KITTY_TERM = b"\x1b_Gi=7431;OK\x1b\\\x1b[6;20;10t\x1b[?62;22c"  # kitty: graphics reply, no sixel
SIXEL_TERM = b"\x1b[6;18;9t\x1b[4;900;1800t\x1b[?1;0;1024S\x1b[?63;1;2;4;6;9;15;22c"  # xterm -ti vt340
PLAIN_TERM = b"\x1b[?62;22c"  # e.g. GNOME Terminal: answers DA1 only
TMUX_NO_SIXEL = b"\x1b[?1;2c"  # tmux 3.3: drops the kitty query, no sixel in its own DA1


@pytest.mark.parametrize("data,mode,cell,colors", [
    (KITTY_TERM, "kitty", (10, 20), 256),
    (SIXEL_TERM, "sixel", (9, 18), 256),
    (PLAIN_TERM, "blocks", (10, 20), 256),
    (TMUX_NO_SIXEL, "blocks", (10, 20), 256),
    (b"\x1b_Gi=7431;ENOENT:no\x1b\\\x1b[?62;4;22c\x1b[6;16;8t", "sixel", (8, 16), 256),  # a refusal is no kitty
])
def test_auto_picks_what_the_terminal_offers(data, mode, cell, colors):
    g = choose("auto", parse_replies(data))
    assert (g.mode, g.cell_px, g.colors) == (mode, cell, colors)
    assert g.reason


def test_cell_size_from_the_window_size_or_the_text_area():
    sixel_no_cell = parse_replies(b"\x1b[?62;4c")
    assert choose("auto", sixel_no_cell).mode == "blocks"  # sixel cannot be placed without the cell size
    assert choose("auto", sixel_no_cell, (50, 200, 2000, 1100)).cell_px == (10, 22)
    with_area = parse_replies(b"\x1b[4;1000;1600t\x1b[?62;4c")
    assert choose("auto", with_area, (50, 200, 0, 0)).cell_px == (8, 20)


def test_forced_modes_and_no_terminal():
    assert choose("blocks", parse_replies(KITTY_TERM)).mode == "blocks"
    forced = choose("sixel", parse_replies(PLAIN_TERM))
    assert forced.mode == "sixel" and "did not confirm" in forced.reason
    assert choose("kitty", parse_replies(KITTY_TERM)).reason == "asked for"
    assert choose("kitty", None).mode == "blocks"  # output is not a terminal
    few = parse_replies(b"\x1b[6;20;10t\x1b[?1;0;16S\x1b[?62;4c")
    assert choose("auto", few).mode == "blocks"  # 16 colour registers would posterise the sand
    assert choose("sixel", few).mode == "sixel"
    with pytest.raises(ValueError):
        choose("iterm", parse_replies(PLAIN_TERM))


def test_replies_parse_every_field():
    r = parse_replies(b"junk" + SIXEL_TERM)
    assert r == Replies(kitty=False, da1=(63, 1, 2, 4, 6, 9, 15, 22), cell_px=(9, 18), text_area_px=(1800, 900),
                        colors=1024)
    assert r.sixel


def _terminal(master: int, kitty: bool, sixel: bool, stop: threading.Event) -> None:
    """The far end of the pty: answers the queries like a terminal would."""
    seen = b""
    while not stop.is_set():
        try:
            data = os.read(master, 4096)
        except OSError:
            return
        replies, seen = answer(seen + data, kitty, sixel, (9, 18))
        if replies:
            os.write(master, replies)


@pytest.mark.parametrize("kitty,sixel,mode", [(True, False, "kitty"), (False, True, "sixel"), (False, False, "blocks")])
def test_detect_over_a_pty(kitty, sixel, mode):
    master, slave = os.openpty()
    stop = threading.Event()
    far = threading.Thread(target=_terminal, args=(master, kitty, sixel, stop), daemon=True)
    far.start()
    try:
        t0 = time.perf_counter()
        g = detect("auto", fd=slave, timeout=60.0)
        elapsed = time.perf_counter() - t0
    finally:
        stop.set()
        os.close(slave)
        os.close(master)
    assert g.mode == mode
    if mode != "blocks":
        assert g.cell_px == (9, 18)
    assert elapsed < 30.0  # DA1 ends the wait, not the timeout


def test_detect_when_the_terminal_never_answers():
    master, slave = os.openpty()
    try:
        t0 = time.perf_counter()
        g = detect("auto", fd=slave, timeout=0.3)
        assert time.perf_counter() - t0 < 30.0  # gave up
        assert os.read(master, 4096) == QUERIES.encode()  # asked once, then gave up
    finally:
        os.close(slave)
        os.close(master)
    assert g.mode == "blocks"
