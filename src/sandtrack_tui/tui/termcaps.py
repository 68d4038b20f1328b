"""Which way the terminal can show real pixels: the kitty graphics protocol, sixel, or neither.

Asked once, before the UI starts (Textual reads the terminal's input from then on): a kitty
graphics query, the cell size in pixels, the number of sixel colour registers, then the primary
device attributes (DA1). Every terminal answers DA1, so its answer ends the wait; a terminal that
understands the kitty query answers it first, and a "4" among DA1's attributes means sixel.

Inside tmux the answers are tmux's own: it drops the kitty query (kitty images do not pass through
it) and lists sixel only when it was built with it, so the choice is right there too.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import select
import struct
import termios
import time
import tty
from dataclasses import dataclass

MODES = ("auto", "kitty", "sixel", "blocks")
KITTY_QUERY_ID = 7431
QUERIES = (f"\x1b_Gi={KITTY_QUERY_ID},s=1,v=1,a=q,t=d,f=24;AAAA\x1b\\"  # kitty graphics
           "\x1b[16t"  # cell size in pixels
           "\x1b[14t"  # text area size in pixels (for terminals that do not report the cell size)
           "\x1b[?1;1;0S"  # XTSMGRAPHICS: number of sixel colour registers
           "\x1b[c")  # primary device attributes: answered by every terminal, ends the wait
DEFAULT_CELL_PX = (10, 20)
MAX_COLORS = 256
MIN_SIXEL_COLORS = 64  # fewer registers than this posterise the sand

_KITTY_REPLY = re.compile(rb"\x1b_Gi=" + str(KITTY_QUERY_ID).encode() + rb"(?:,[^;]*)?;([^\x1b]*)\x1b\\")
_DA1 = re.compile(rb"\x1b\[\?([\d;]*)c")
_CELL = re.compile(rb"\x1b\[6;(\d+);(\d+)t")
_TEXT_AREA = re.compile(rb"\x1b\[4;(\d+);(\d+)t")
_COLORS = re.compile(rb"\x1b\[\?1;0;(\d+)S")


@dataclass(frozen=True)
class Graphics:
    """How frames are drawn: `mode` is "kitty", "sixel" or "blocks"; `cell_px` is a cell's
    (width, height) in pixels; `colors` the palette size for sixel; `reason` says why."""

    mode: str
    cell_px: tuple[int, int] = DEFAULT_CELL_PX
    colors: int = MAX_COLORS
    reason: str = ""


@dataclass(frozen=True)
class Replies:
    """What the terminal said to QUERIES."""

    kitty: bool = False
    da1: tuple[int, ...] | None = None
    cell_px: tuple[int, int] | None = None
    text_area_px: tuple[int, int] | None = None
    colors: int | None = None

    @property
    def sixel(self) -> bool:
        return self.da1 is not None and 4 in self.da1


def parse_replies(data: bytes) -> Replies:
    kitty = _KITTY_REPLY.search(data)
    da1 = _DA1.search(data)
    cell = _CELL.search(data)
    area = _TEXT_AREA.search(data)
    colors = _COLORS.search(data)
    return Replies(
        kitty=bool(kitty and kitty.group(1) == b"OK"),
        da1=tuple(int(v) for v in da1.group(1).split(b";") if v) if da1 else None,
        cell_px=(int(cell.group(2)), int(cell.group(1))) if cell and int(cell.group(1)) and int(cell.group(2))
        else None,
        text_area_px=(int(area.group(2)), int(area.group(1))) if area else None,
        colors=int(colors.group(1)) if colors else None,
    )


def cell_size(replies: Replies, winsize: tuple[int, int, int, int] | None) -> tuple[int, int] | None:
    """A cell's (width, height) in pixels: the terminal's answer, else the window size's pixel
    fields (rows, cols, x pixels, y pixels), else the text area's size over the cells."""
    if replies.cell_px:
        return replies.cell_px
    if winsize:
        rows, cols, xpx, ypx = winsize
        if rows and cols and xpx >= cols and ypx >= rows:
            return xpx // cols, ypx // rows
        if rows and cols and replies.text_area_px:
            w, h = replies.text_area_px
            if w >= cols and h >= rows:
                return w // cols, h // rows
    return None


def choose(requested: str, replies: Replies | None, winsize: tuple[int, int, int, int] | None = None) -> Graphics:
    """The drawing mode for `--graphics requested`, given the terminal's replies (None: not a terminal)."""
    if requested not in MODES:
        raise ValueError(f"--graphics must be one of {', '.join(MODES)}")
    if requested == "blocks":
        return Graphics("blocks", reason="asked for")
    if replies is None:
        return Graphics("blocks", reason="not a terminal")
    cell = cell_size(replies, winsize)
    colors = min(replies.colors, MAX_COLORS) if replies.colors and replies.colors > 1 else MAX_COLORS
    if requested == "auto":
        if replies.kitty:
            requested = "kitty"
        elif not replies.sixel:
            return Graphics("blocks", reason="the terminal offers neither kitty graphics nor sixel")
        elif cell is None:
            # sixel draws in the terminal's pixels: without the cell size the picture would not fit its cells
            return Graphics("blocks", reason="sixel, but the terminal does not tell its cell size")
        elif colors < MIN_SIXEL_COLORS:
            return Graphics("blocks", reason=f"sixel with only {colors} colour registers")
        else:
            requested = "sixel"
        reason = "detected"
    else:
        reason = "asked for" + ("" if (replies.kitty if requested == "kitty" else replies.sixel)
                                else " (the terminal did not confirm it)")
    return Graphics(requested, cell or DEFAULT_CELL_PX, max(colors, MIN_SIXEL_COLORS), reason)


def query(fd: int, timeout: float = 1.5) -> bytes:
    """Send QUERIES to the terminal on `fd` and return its answers (up to DA1's, or what came
    within `timeout` s). The terminal mode is restored afterwards."""
    old = termios.tcgetattr(fd)
    data = b""
    try:
        tty.setraw(fd, termios.TCSANOW)
        os.write(fd, QUERIES.encode())
        deadline = time.monotonic() + timeout
        while not _DA1.search(data):
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                break
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            data += chunk
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)
    return data


def winsize(fd: int) -> tuple[int, int, int, int] | None:
    with contextlib.suppress(OSError):
        return struct.unpack("HHHH", fcntl.ioctl(fd, termios.TIOCGWINSZ, b"\0" * 8))
    return None


def detect(requested: str = "auto", fd: int | None = None, timeout: float = 1.5) -> Graphics:
    """Ask the terminal (the controlling tty unless `fd` is given) and choose the mode."""
    if requested == "blocks":
        return choose("blocks", None)
    own = None
    if fd is None:
        try:
            fd = own = os.open("/dev/tty", os.O_RDWR | os.O_NOCTTY)
        except OSError:
            return choose(requested, None)
    try:
        if not os.isatty(fd):
            return choose(requested, None)
        return choose(requested, parse_replies(query(fd, timeout)), winsize(fd))
    except (OSError, termios.error):
        return choose(requested, None)
    finally:
        if own is not None:
            os.close(own)
