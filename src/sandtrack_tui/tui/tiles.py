"""What each view sends to the terminal: tiles of whole cells, only where the picture changed.

A tile is sent again only where some pixel's true colour moved more than `TOLERANCE` (per
channel, 0-255) from the colour it had when the tile was last sent. So the screen never strays
further than that from the frame (plus the palette's error), sensor noise sends nothing, and a step
sends only the tiles where something moved: on the sample, 8 x 2-cell tiles sent 30-60 KB per view
and step (kitty) where the whole view is ~400 KB.

Kitty tiles are images the terminal keeps, placed at their cell (z = -1: under text, so a
notification over a view stays readable); when another screen covers the views their placements
are removed and later put back without sending pixels again. Sixel tiles are pixels in the
terminal's cells: whenever the UI writes text over a view (a repaint after a notification or
another screen) the tiles there are drawn again, right after that text.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from .frame_view import Overlays, ViewTransform
from .graphics import Kitty, Palette, Sixel, compose

TILE_CELLS = (8, 2)
TOLERANCE = 16
SYNC_START, SYNC_END = "\x1b[?2026h", "\x1b[?2026l"


# --------------------------------------------------------------------------------------------
# one view's tiles
# --------------------------------------------------------------------------------------------
class TileCanvas:
    """What the terminal shows of one view, tile by tile, and the escape codes that bring it up to
    date. Tile `key` = tile row * 4096 + tile column.

    The terminal shows palette colour `shown_idx` at every pixel; `sent` is the true colour each
    pixel had when its tile was last sent. A tile is sent again when a pixel's palette index
    changed and its true colour moved more than the tolerance from `sent`: a change is judged on
    the picture, not on the palette (sensor noise that flips a pixel between two neighbouring
    palette colours sends nothing). So every pixel shows its true colour's palette colour, or one
    within the tolerance (plus the palette's error). A new palette sends the whole view."""

    def __init__(self, protocol, cell_px: tuple[int, int], colors: int = 256, tile_cells=TILE_CELLS,
                 tolerance: int = TOLERANCE) -> None:
        self.protocol = protocol
        self.cell_px = cell_px
        self.tile_cells = tile_cells
        self.tolerance = tolerance
        self.palette = Palette(colors)
        self.geometry: tuple | None = None  # (col, row, cols, rows) of the content on the screen
        self.rgb: np.ndarray | None = None  # the latest picture (rows*ch x cols*cw x 3)
        self.idx: np.ndarray | None = None  # and its palette indices
        self.sent: np.ndarray | None = None
        self.shown_idx: np.ndarray | None = None
        self.placed: set[int] = set()
        self.visible = True
        self.dirty: set[int] = set()  # tiles to send (changed, not sent yet, or text written over them)
        self.tiles_sent = 0

    # -- geometry ------------------------------------------------------------------------------
    def _tiles(self):
        """(key, cell col, cell row, cols, rows) of every tile, relative to the content's first cell."""
        _, _, cols, rows = self.geometry
        tc, tr = self.tile_cells
        for r0 in range(0, rows, tr):
            for c0 in range(0, cols, tc):
                yield (r0 // tr) * 4096 + c0 // tc, c0, r0, min(tc, cols - c0), min(tr, rows - r0)

    def _px(self, c0: int, r0: int, nc: int, nr: int):
        cw, ch = self.cell_px
        return slice(r0 * ch, (r0 + nr) * ch), slice(c0 * cw, (c0 + nc) * cw)

    # -- updates -------------------------------------------------------------------------------
    def update(self, rgb: np.ndarray, geometry: tuple[int, int, int, int], refit: bool = False) -> str:
        """Escape codes that make the terminal show `rgb` (rows*ch x cols*cw) with its first cell
        at (col, row) = geometry[:2]. `refit`: the view changed (zoom, pan, size): new palette."""
        out = []
        if geometry != self.geometry:
            out.append(self.clear())
            self.geometry = geometry
        idx = None if refit or self.palette.colours is None else self.palette.quantize(rgb)
        if idx is None or not self.palette.fits(rgb, idx):
            self.palette.fit(rgb)
            idx, refit = self.palette.quantize(rgb), True
        self.rgb, self.idx = rgb, idx
        if refit or self.sent is None:
            self.sent, self.shown_idx = rgb.copy(), idx.copy()
            self.dirty |= {t[0] for t in self._tiles()}
        else:
            ys, xs = np.nonzero(idx != self.shown_idx)
            if len(ys):
                far = np.abs(rgb[ys, xs].astype(np.int16) - self.sent[ys, xs]).max(axis=1) > self.tolerance
                cw, ch = self.cell_px
                tc, tr = self.tile_cells
                self.dirty |= set(np.unique((ys[far] // (tr * ch)) * 4096 + xs[far] // (tc * cw)).tolist())
        if self.visible:
            out.append(self.flush())
        return "".join(out)

    def flush(self) -> str:
        """The dirty tiles, sent from the latest picture."""
        if not self.dirty or self.idx is None or not self.visible:
            return ""
        col0, row0 = self.geometry[:2]
        out = []
        for key, c0, r0, nc, nr in self._tiles():
            if key not in self.dirty:
                continue
            ys, xs = self._px(c0, r0, nc, nr)
            tile = self.idx[ys, xs]
            out.append(self.protocol.tile(tile, self.palette, key, col0 + c0, row0 + r0, nc, nr))
            self.sent[ys, xs] = self.rgb[ys, xs]
            self.shown_idx[ys, xs] = tile
            self.placed.add(key)
            self.tiles_sent += 1
        self.dirty.clear()
        return "".join(out)

    def repainted(self, cells: list[tuple[int, int, int]]) -> None:
        """Text was written over these screen cells ((row, col from, col to) spans): for sixel the
        tiles under them must be drawn again."""
        if self.geometry is None or self.protocol.keeps_images:
            return
        col0, row0, cols, rows = self.geometry
        tc, tr = self.tile_cells
        for y, x1, x2 in cells:
            r = y - row0
            a, b = max(x1 - col0, 0), min(x2 - col0, cols)
            if 0 <= r < rows and a < b:
                for c in range(a // tc, (b - 1) // tc + 1):
                    self.dirty.add((r // tr) * 4096 + c)

    def hide(self) -> str:
        self.visible = False
        if not self.protocol.keeps_images:
            return ""
        return "".join(self.protocol.remove(key) for key in sorted(self.placed))

    def show(self) -> str:
        """Back on screen: kitty images are placed again; sixel tiles are drawn again."""
        self.visible = True
        if self.geometry is None:
            return ""
        if not self.protocol.keeps_images:
            self.dirty |= {t[0] for t in self._tiles()}
            return self.flush()
        col0, row0 = self.geometry[:2]
        out = [self.protocol.place(key, col0 + c0, row0 + r0, nc, nr)
               for key, c0, r0, nc, nr in self._tiles() if key in self.placed and key not in self.dirty]
        return "".join(out) + self.flush()

    def clear(self, free: bool = False) -> str:
        """Forget the picture (and take kitty's images off the screen)."""
        out = "".join(self.protocol.remove(key, free) for key in sorted(self.placed))
        self.placed.clear()
        self.geometry, self.rgb, self.idx, self.sent, self.shown_idx = None, None, None, None, None
        self.dirty.clear()
        return out


# --------------------------------------------------------------------------------------------
# the hook FrameView calls
# --------------------------------------------------------------------------------------------
class GraphicsView:
    """A FrameView's pictures as graphics. `write` sends escape codes to the terminal."""

    def __init__(self, mode: str, cell_px: tuple[int, int], colors: int, view_number: int,
                 write: Callable[[str], None]) -> None:
        protocol = Kitty(id_base=0x5A000000 + view_number * 0x100000) if mode == "kitty" else Sixel()
        self.mode = mode
        self.cell_px = cell_px
        self.canvas = TileCanvas(protocol, cell_px, colors)
        self.write = write
        self._view_key = None

    def draw(self, pixels: np.ndarray, tf: ViewTransform, overlays: Overlays, message: str,
             origin: tuple[int, int]) -> None:
        rgb = compose(pixels, tf, self.cell_px, overlays, message)
        view_key = (tf, origin)
        refit = view_key != self._view_key
        self._view_key = view_key
        self.send(self.canvas.update(rgb, (origin[0], origin[1], tf.cols, tf.rows), refit=refit))

    def send(self, data: str) -> None:
        if data:
            # one synchronized update; the cursor (and its attributes) as the UI left it
            self.write(SYNC_START + "\x1b7" + data + "\x1b8" + SYNC_END)

    def clear(self) -> None:
        self.send(self.canvas.clear())
        self._view_key = None


class ScreenGraphics:
    """The app's side: a GraphicsView per FrameView, kept in step with what Textual writes.

    `after_display` runs after every screen update Textual writes (App._display): a view that left
    the screen (another screen on top) takes its kitty images away, sixel tiles under cells that
    were just rewritten are drawn again, and a view the layout moved forgets its old tiles."""

    def __init__(self, app, graphics) -> None:
        self.app = app
        self.graphics = graphics

    @property
    def cell_px(self) -> tuple[int, int] | None:
        """What the feeder renders frames for: None = half-blocks."""
        return None if self.graphics.mode == "blocks" else self.graphics.cell_px

    def start(self, views) -> None:
        g = self.graphics
        if g.mode == "blocks":
            return
        if g.mode == "sixel":  # load the compiled encoder while the first frames decode
            from . import sixel

            threading.Thread(target=sixel.warm_up, name="sixel-warm-up", daemon=True).start()
        for k, v in enumerate(views):
            v.graphics = GraphicsView(g.mode, g.cell_px, g.colors, k, self.app.write_graphics)
        self.app.notify(f"real pixels: {g.mode} ({g.reason}), {g.cell_px[0]} x {g.cell_px[1]} px per cell; "
                        "--graphics blocks draws half-blocks (fewer bytes over a slow link)", timeout=6)

    def after_display(self, views, renderable, main_screen_shown: bool) -> None:
        views = [v for v in views if v.graphics is not None]
        if not views or renderable is None:
            return
        spans = getattr(renderable, "spans", None)
        if spans is None and hasattr(renderable, "region"):  # a full update
            r = renderable.region
            spans = [(y, r.x, r.right) for y in range(r.y, r.bottom)]
        for v in views:
            gv, region = v.graphics, v.content_region
            shown = main_screen_shown and v.display and region.area > 0
            if gv.canvas.geometry not in (None, (region.x, region.y, region.width, region.height)):
                gv.clear()  # the layout moved the view: its old tiles must not come back; a new frame is due
            elif gv.canvas.visible and not shown:
                gv.send(gv.canvas.hide())
            elif shown:
                gv.canvas.repainted(spans or [])
                gv.send(gv.canvas.show() if not gv.canvas.visible else gv.canvas.flush())

    def stop(self, views) -> None:
        """Take every kitty image off the screen and out of the terminal's memory."""
        for v in views:
            if v.graphics is not None:
                v.graphics.send(v.graphics.canvas.clear(free=True))
