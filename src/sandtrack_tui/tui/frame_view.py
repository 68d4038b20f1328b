"""Camera frames drawn with half-block characters.

A terminal cell holds two display pixels: "▀" with the upper pixel as foreground colour and the
lower one as background. The visible part of the frame is area-averaged down to the cell grid
(`cv2.resize(INTER_AREA)`), so fine texture becomes its mean colour rather than aliasing. Small
markers would fade to a faint tint at a 10-20x downscale, so a marker mask is computed at half
resolution (blue paint, or pixels that look like the seeded marker when it is not blue) and every
display pixel covering at least `BOOST_FRACTION` of marker pixels is painted vivid blue ("marker boost").
The boost never covers the picture: where more than `BOOST_DENSE_SHARE` of it looks like markers (a
packed bed of beads, hundreds of markers on sand), it paints only the tracked markers, and nothing where
even those would cover more than that share.

Rows become Rich segments with runs of equal colour pairs merged and `Style` objects cached by
colour pair; in 256-colour terminals the pixels are first snapped to the xterm colour cube, which
both matches what the terminal can show and makes runs longer.

Mapping between cells and source pixels (s = source px per display px):
    x = x0 + (col + 0.5) * s,  y = y0 + (2 * row + 1) * s
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from rich.color import Color as RichColor
from rich.segment import Segment
from rich.style import Style
from textual import events
from textual.geometry import Region
from textual.message import Message
from textual.strip import Strip
from textual.widget import Widget

HALF = "▀"
BOOST_FRACTION = 0.03
BOOST_RGB = (40, 110, 255)
# Past this share of a view's picture looking like markers, the boost would paint a scene rather than pick
# markers out of it (8 markers at 10-20x cover 0.1-1 %, the same zoomed in 4x a few %; a packed bed 30-60 %).
BOOST_DENSE_SHARE = 0.05
MARKER_RADIUS_PX = 5.0  # a blue marker's radius when no seeded marker tells it (5 mm at ~1 mm per px)
# OpenCV HSV (H in 0..180): blue marker paint, well away from sand (H ~ 10-30).
BLUE_LO = np.array([95, 90, 45], np.uint8)
BLUE_HI = np.array([135, 255, 255], np.uint8)

STATUS_RGB = {
    "tracked": (60, 220, 90),
    "manual": (80, 220, 255),
    "interpolated": (240, 200, 40),
    "imported": (210, 120, 255),
    "occluded": (170, 170, 170),
    "lost": (255, 60, 60),
}
SELECTED_RGB = (255, 255, 255)
CURSOR_RGB = (255, 230, 0)
EPIPOLAR_RGB = (255, 80, 200)
# Epipolar curves in a view are drawn in the colour of the camera they come from (shown in its title).
CAMERA_RGB = [EPIPOLAR_RGB, (90, 200, 255), (255, 170, 60), (150, 255, 120), (255, 255, 120), (200, 150, 255)]
SEARCH_RGB = (255, 160, 40)

_CUBE = np.array([0, 95, 135, 175, 215, 255], np.int16)
# The xterm 256-colour palette without the 16 theme-dependent colours: 6x6x6 cube + 24 greys.
# 256 colours: the scene is drawn in the palette's 30 greys (cube greys + the 24-step ramp), which
# keeps the sand's texture readable; the cube's few warm colours posterise sand into pink and green
# blotches. Marker boost and overlays stay in colour.
_GREYS = np.unique(np.concatenate([_CUBE, 8 + 10 * np.arange(24)])).astype(np.int16)
_GREY_LUT = _GREYS[np.abs(np.arange(256)[:, None] - _GREYS[None, :]).argmin(axis=1)].astype(np.uint8)
_BOOST_256 = (0, 95, 255)


# --------------------------------------------------------------------------------------------
# geometry of a view
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ViewTransform:
    """Which source region a view of `cols` x `rows` cells shows: display pixel (i, j) covers source
    [x0 + i s, x0 + (i+1) s) x [y0 + j s, y0 + (j+1) s); there are cols x 2*rows display pixels."""

    x0: float
    y0: float
    s: float
    cols: int
    rows: int

    @classmethod
    def make(cls, width: int, height: int, cols: int, rows: int, zoom: float = 1.0,
             center: tuple[float, float] | None = None) -> ViewTransform:
        cols, rows = max(int(cols), 1), max(int(rows), 1)
        s = max(width / cols, height / (2 * rows)) / max(zoom, 1e-6)
        vw, vh = cols * s, 2 * rows * s
        cx, cy = center if center is not None else (width / 2, height / 2)
        cx = width / 2 if vw >= width else min(max(cx, vw / 2), width - vw / 2)
        cy = height / 2 if vh >= height else min(max(cy, vh / 2), height - vh / 2)
        return cls(cx - vw / 2, cy - vh / 2, s, cols, rows)

    @property
    def center(self) -> tuple[float, float]:
        return self.x0 + self.cols * self.s / 2, self.y0 + self.rows * self.s

    def cell_to_source(self, col: int, row: int) -> tuple[float, float]:
        return self.x0 + (col + 0.5) * self.s, self.y0 + (2 * row + 1) * self.s

    def source_to_cell(self, x: float, y: float) -> tuple[int, int]:
        return math.floor((x - self.x0) / self.s), math.floor((y - self.y0) / self.s / 2)

    def source_to_display(self, x, y):
        """Continuous display-pixel coordinates with pixel centres at integers."""
        return (np.asarray(x) - self.x0) / self.s - 0.5, (np.asarray(y) - self.y0) / self.s - 0.5

    def contains(self, x: float, y: float) -> bool:
        return self.x0 <= x < self.x0 + self.cols * self.s and self.y0 <= y < self.y0 + 2 * self.rows * self.s


# --------------------------------------------------------------------------------------------
# pixels
# --------------------------------------------------------------------------------------------
def marker_mask(bgr: np.ndarray) -> np.ndarray:
    """uint8 mask (255 = blue marker paint) at the resolution of `bgr`."""
    return cv2.inRange(cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV), BLUE_LO, BLUE_HI)


@dataclass
class Rendered:
    """A view's display image and what its marker boost found."""

    pixels: np.ndarray  # (2*rows, cols, 3) RGB uint8
    marker_share: float = 0.0  # share of the picture that looks like markers (0 without the boost)
    limited: bool = False  # a dense scene: the boost painted the tracked markers only (or nothing)


def render_pixels(frame_bgr: np.ndarray, tf: ViewTransform, boost: bool = True, look=None,
                  markers: np.ndarray | None = None) -> np.ndarray:
    """The display image (2*rows, cols, 3) RGB uint8 of the region `tf` shows; black outside the frame
    (see `render`)."""
    return render(frame_bgr, tf, boost, look, markers).pixels


def render(frame_bgr: np.ndarray, tf: ViewTransform, boost: bool = True, look=None,
           markers: np.ndarray | None = None) -> Rendered:
    """The display image of the region `tf` shows, with the marker boost. `look`: the appearance model
    (tracking.appearance) of the project's markers when they are not blue; the boost then paints the
    pixels that look like them. `markers`: (N, 2) source px of the tracked markers, the only ones the
    boost paints in a dense scene."""
    h, w = frame_bgr.shape[:2]
    out = np.zeros((2 * tf.rows, tf.cols, 3), np.uint8)
    ix0, iy0 = max(0, math.floor(tf.x0)), max(0, math.floor(tf.y0))
    ix1 = min(w, math.ceil(tf.x0 + tf.cols * tf.s))
    iy1 = min(h, math.ceil(tf.y0 + 2 * tf.rows * tf.s))
    if ix1 <= ix0 or iy1 <= iy0:
        return Rendered(out)
    dc0 = min(max(round((ix0 - tf.x0) / tf.s), 0), tf.cols)
    dc1 = min(max(round((ix1 - tf.x0) / tf.s), 0), tf.cols)
    dr0 = min(max(round((iy0 - tf.y0) / tf.s), 0), 2 * tf.rows)
    dr1 = min(max(round((iy1 - tf.y0) / tf.s), 0), 2 * tf.rows)
    if dc1 <= dc0 or dr1 <= dr0:
        return Rendered(out)
    share, limited = 0.0, False
    crop = frame_bgr[iy0:iy1, ix0:ix1]
    size = (dc1 - dc0, dr1 - dr0)
    if tf.s <= 1.0:
        small = cv2.resize(crop, size, interpolation=cv2.INTER_NEAREST)
    elif tf.s < 2.0:
        # INTER_AREA by a fractional factor costs ~18 ms for a 1080p frame: from 1.5x halve exactly
        # (area), then interpolate the small rest; below 1.5x interpolate (1-2 ms either way)
        work = _shrink(crop, 2) if tf.s >= 1.5 else crop
        small = cv2.resize(work, size, interpolation=cv2.INTER_LINEAR)
    else:
        # INTER_AREA is fast for whole-number factors and slow otherwise, so shrink by whole
        # factors first (2x, then k x) and do the fractional rest on the small image.
        work, frac = crop, None
        if tf.s >= 2.0:
            work = _shrink(work, 2)
            if boost:
                frac = marker_mask(work) if look is None else _look_mask(look, work, tf.s)
            k = int(tf.s / 2.0)
            if k >= 2:
                work = _shrink(work, k)
                frac = None if frac is None else _shrink(frac, k)
        small = cv2.resize(work, size, interpolation=cv2.INTER_AREA)
        if frac is not None:
            frac = cv2.resize(frac, size, interpolation=cv2.INTER_AREA)
            # a marker split over several display pixels may cover < 3 % of each: keep its peak too
            peak = (frac >= 2) & (frac == cv2.dilate(frac, np.ones((3, 3), np.uint8)))
            hit = (frac >= int(255 * BOOST_FRACTION)) | peak
            share = float(np.count_nonzero(hit)) / hit.size
            if share > BOOST_DENSE_SHARE:
                hit &= _near_markers(markers, tf, getattr(look, "radius", MARKER_RADIUS_PX), dc0, dr0, hit.shape)
                limited = True
                if np.count_nonzero(hit) > BOOST_DENSE_SHARE * hit.size:
                    hit[:] = False
            small[hit] = BOOST_RGB[::-1]
    out[dr0:dr1, dc0:dc1] = small[:, :, ::-1]
    return Rendered(out, share, limited)


def _near_markers(markers: np.ndarray | None, tf: ViewTransform, radius: float, dc0: int, dr0: int,
                  shape: tuple[int, int]) -> np.ndarray:
    """Display pixels (of the picture starting at column dc0, row dr0) within a marker's radius of a
    tracked marker."""
    near = np.zeros(shape, np.uint8)
    if markers is not None and len(markers):
        u, v = tf.source_to_display(markers[:, 0], markers[:, 1])
        r = max(int(round(radius / tf.s)), 1)
        for a, b in zip(u - dc0, v - dr0, strict=True):
            if -r <= a < shape[1] + r and -r <= b < shape[0] + r:
                cv2.circle(near, (int(round(a)), int(round(b))), r, 1, -1)
    return near.astype(bool)


def _look_mask(look, half: np.ndarray, s: float) -> np.ndarray | None:
    """Pixels of a half-resolution image that look like the markers of `look` (an appearance
    model); found at quarter resolution when a display pixel spans 8 source px or more (a 9 px
    marker still fills a few pixels there, at a quarter of the cost)."""
    if s < 8.0:
        return look.display_mask(half, 2.0)
    mask = look.display_mask(_shrink(half, 2), 4.0)
    if mask is None:
        return None
    return cv2.resize(mask, (half.shape[1], half.shape[0]), interpolation=cv2.INTER_NEAREST)


def _shrink(img: np.ndarray, k: int) -> np.ndarray:
    """Area-average by a whole factor k (the last rows/columns that do not fill a block are dropped)."""
    h, w = img.shape[:2]
    h2, w2 = max(h // k, 1), max(w // k, 1)
    return cv2.resize(img[: h2 * k, : w2 * k], (w2, h2), interpolation=cv2.INTER_AREA)


def quantize(rgb: np.ndarray, colors: str) -> np.ndarray:
    """Snap colours to what the terminal shows: 5 bits per channel in truecolor (invisible at this
    scale, and it lets neighbouring cells share a style); in 256 colours, the palette's greys (the
    boosted markers stay blue)."""
    if colors == "truecolor":
        return rgb & 0xF8
    luma = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    out = np.repeat(_GREY_LUT[luma][..., None], 3, axis=2)
    out[np.all(rgb == BOOST_RGB, axis=2)] = _BOOST_256
    return out


# --------------------------------------------------------------------------------------------
# overlays (drawn into the display image; labels go into cells)
# --------------------------------------------------------------------------------------------
@dataclass
class MarkerMark:
    marker: int
    label: str
    x: float
    y: float
    status: str
    selected: bool = False
    half_size_px: float = 10.0


@dataclass
class Overlays:
    marks: list[MarkerMark] = field(default_factory=list)
    cursor: tuple[float, float] | None = None
    search: tuple[float, float, float, float] | None = None  # x, y, half_w, half_h (source px)
    # the selected marker's epipolar curves from the other views: (N, 2) source px each, with a colour
    epipolar: list[tuple[np.ndarray, tuple[int, int, int]]] = field(default_factory=list)


@dataclass
class LabelRequest:
    """A marker id to place: `anchor` is the marker's cell, `box` the cells around the bead (the spots
    beside it are just outside), `first` the spot tried first."""

    text: str
    style: Style
    anchor: tuple[int, int]  # (row, col)
    box: tuple[int, int, int, int]  # rows r0..r1, cols c0..c1 (inclusive)
    first: tuple[int, int] | None = None
    colour: tuple[int, int, int] = SELECTED_RGB


# Spots tried around a marker, nearest first: beside, above, below, then diagonals; further out after.
_RING1 = ((0, 1), (0, -1), (-1, 0), (1, 0), (-1, 1), (1, 1), (-1, -1), (1, -1))


def place_labels(requests: list[LabelRequest], rows: int, cols: int,
                 blocked: np.ndarray | None = None) -> list[tuple[LabelRequest, int, int, bool]]:
    """Place every label inside the view where it covers no marker (`blocked` cells; by default the
    requests' boxes) and no other label, with a free cell between it and any other label on its row, so
    that two ids never read as one. A label sits beside its marker only where no other marker is
    nearer; otherwise it goes further out, to the nearest free spot (`far`: the caller draws a leader
    line to it). Returns (request, row, col, far) per placed label, in the order given; a label is
    left out only when no free spot lies within FAR_ROWS rows and FAR_COLS columns of its marker."""
    if blocked is None:
        blocked = np.zeros((rows, cols), bool)
        for q in requests:
            r0, r1, c0, c1 = q.box
            blocked[max(r0, 0):max(min(r1 + 1, rows), 0), max(c0, 0):max(min(c1 + 1, cols), 0)] = True
    anchors = np.array([q.anchor for q in requests], float).reshape(-1, 2)
    labelled = np.zeros((rows, cols), bool)
    placed = []
    for k, q in enumerate(requests):
        n = len(q.text)
        if n > cols:
            continue
        # free[r, c]: a label of n cells can start at (r, c): nothing blocked under it, no label under it
        # or right beside it
        near_label = labelled.copy()
        near_label[:, 1:] |= labelled[:, :-1]
        near_label[:, :-1] |= labelled[:, 1:]
        bad = np.zeros((rows, cols + 1), np.int32)
        np.cumsum(blocked | near_label, axis=1, out=bad[:, 1:])
        free = (bad[:, n:] - bad[:, :-n]) == 0
        spot = _near_spot(q, n, k, free, anchors)
        far = spot is None
        if far:
            spot = _far_spot(q, n, free)
        if spot is None:
            continue
        r, c = spot
        labelled[r, c:c + n] = True
        placed.append((q, r, c, far))
    return placed


def _near_spot(q: LabelRequest, n: int, k: int, free: np.ndarray, anchors: np.ndarray):
    """The first free spot beside the marker (`first`, then just outside its box on each side) where
    no other marker is nearer to the label than its own."""
    r0, r1, c0, c1 = q.box
    ar, ac = q.anchor
    spots = [q.first] if q.first is not None else []
    for dr, dc in _RING1:
        spots.append((r0 - 1 if dr < 0 else r1 + 1 if dr > 0 else ar,
                      c1 + 1 if dc > 0 else c0 - n if dc < 0 else ac - n // 2))
    for r, c in spots:
        if not (0 <= r < free.shape[0] and 0 <= c < free.shape[1]) or not free[r, c]:
            continue
        if len(anchors) > 1:
            # a row is about as tall as two columns are wide
            d = np.hypot(2.0 * (anchors[:, 0] - r), anchors[:, 1] - (c + (n - 1) / 2))
            if d.min() < d[k]:
                continue  # it would read as another marker's id
        return r, c
    return None


_OFFSETS: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}
FAR_ROWS, FAR_COLS = 30, 60  # how far an id may move from its marker


def _far_spot(q: LabelRequest, n: int, free: np.ndarray):
    """The free spot whose label centre is nearest to the marker (rows count twice), within FAR_ROWS
    rows and FAR_COLS columns of it."""
    rows, width = free.shape
    key = (min(rows, FAR_ROWS), min(width, FAR_COLS), n)
    if key not in _OFFSETS:
        h, w = key[0], key[1]
        dr, dc = np.mgrid[-h:h + 1, -w - n:w + n + 1]
        order = np.argsort(np.hypot(2.0 * dr, dc + (n - 1) / 2).ravel(), kind="stable")
        _OFFSETS[key] = dr.ravel()[order], dc.ravel()[order]
        if len(_OFFSETS) > 64:
            _OFFSETS.pop(next(iter(_OFFSETS)))
    dr, dc = _OFFSETS[key]
    r, c = q.anchor[0] + dr, q.anchor[1] + dc
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < width)
    r, c = r[inside], c[inside]
    hit = np.flatnonzero(free[r, c])
    return (int(r[hit[0]]), int(c[hit[0]])) if len(hit) else None


def bead_cells(tf: ViewTransform, x: float, y: float, radius: float, out: np.ndarray) -> tuple[int, int, int, int]:
    """Mark in `out` the cells a bead of `radius` source px at (x, y) covers (cells are s wide and 2s
    tall); returns their bounding box (r0, r1, c0, c1), which may reach outside the view."""
    c0, r0 = tf.source_to_cell(x - radius, y - radius)
    c1, r1 = tf.source_to_cell(x + radius, y + radius)
    rows, cols = out.shape
    ra, rb, ca, cb = max(r0, 0), min(r1, rows - 1), max(c0, 0), min(c1, cols - 1)
    if ra <= rb and ca <= cb:
        rr, cc = np.mgrid[ra:rb + 1, ca:cb + 1]
        # distance from the bead's centre to each cell's rectangle
        dx = np.maximum(np.abs(tf.x0 + (cc + 0.5) * tf.s - x) - 0.5 * tf.s, 0.0)
        dy = np.maximum(np.abs(tf.y0 + (2 * rr + 1) * tf.s - y) - tf.s, 0.0)
        out[rr, cc] |= np.hypot(dx, dy) <= radius
    return r0, r1, c0, c1


def draw_overlays(rgb: np.ndarray, tf: ViewTransform, ov: Overlays, place_ids: bool = True,
                  cells: ViewTransform | None = None) -> dict[tuple[int, int], tuple[str, Style]]:
    """Draw boxes, crosshair, search window and epipolar curves into `rgb` (in place); return the
    text labels as {(row, col): (char, style)}: every marker's id, none over another id or a marker,
    with a leader line where an id had to move away from its marker. place_ids=False: no ids (and
    no leader lines). `cells`: the view's cells when `rgb` is drawn at a finer scale (`tf`, same
    region: the terminal's own pixels); the ids are placed in those cells, leader lines drawn in `rgb`."""
    labels: dict[tuple[int, int], tuple[str, Style]] = {}
    ct = cells or tf  # where ids go
    scale = ct.s / tf.s  # rgb pixels per half-block pixel
    for curve, colour in ov.epipolar:
        if curve is None or len(curve) < 2:
            continue
        u, v = tf.source_to_display(curve[:, 0], curve[:, 1])
        ok = np.isfinite(u) & np.isfinite(v) & (np.abs(u) < 1e5) & (np.abs(v) < 1e5)
        pts = np.round(np.stack([u[ok], v[ok]], axis=1)).astype(np.int32)
        if len(pts) >= 2:
            cv2.polylines(rgb, [pts.reshape(-1, 1, 2)], False, colour, 1, cv2.LINE_8)
    if ov.search is not None:
        x, y, hw, hh = ov.search
        _rect(rgb, tf, x - hw, y - hh, x + hw, y + hh, SEARCH_RGB)
    requests = []
    blocked = np.zeros((ct.rows, ct.cols), bool)
    for m in ov.marks:
        if not (np.isfinite(m.x) and np.isfinite(m.y)):
            continue
        colour = STATUS_RGB.get(m.status, (255, 255, 255))
        style = Style(color=RichColor.from_triplet(_t(colour)), bgcolor=RichColor.from_rgb(0, 0, 0),
                      bold=m.selected, reverse=m.selected)
        hs = max(m.half_size_px, 1.5 * tf.s)
        mc, mr = ct.source_to_cell(m.x, m.y)
        # the cells of the bead itself (about half its box), which no id may cover
        br0, br1, bc0, bc1 = bead_cells(ct, m.x, m.y, 0.5 * m.half_size_px, blocked)
        labelled = ct.contains(m.x, m.y)  # a marker outside the view gets no id
        if hs / tf.s < 2.5 and not m.selected:
            # zoomed out, boxes of neighbouring markers would merge: a status bar under the marker
            u, v = tf.source_to_display(m.x, m.y)
            u, v = int(round(float(u))), int(round(float(v)))
            for du in (-1, 0, 1):
                _put(rgb, u + du, v + 2, colour)
            if labelled:
                requests.append((1, LabelRequest(m.label, style, (mr, mc), (br0, br1, bc0, bc1), colour=colour)))
            continue
        _rect(rgb, tf, m.x - hs, m.y - hs, m.x + hs, m.y + hs, SELECTED_RGB if m.selected else colour)
        if m.selected:
            _rect(rgb, tf, m.x - hs - tf.s, m.y - hs - tf.s, m.x + hs + tf.s, m.y + hs + tf.s, colour)
        if labelled:
            col1, row0 = ct.source_to_cell(m.x + hs, m.y - hs)
            first = (row0 - 1 if row0 > 0 else row0, col1 + 1)  # the box's top right corner
            requests.append((0, LabelRequest(m.label, style, (mr, mc), (br0, br1, bc0, bc1), first, colour)))
    # boxed (and selected) markers first: their ids sit at the box's corner as far as possible
    ordered = [q for _prio, q in sorted(requests, key=lambda r: (r[0], r[1].anchor))] if place_ids else []
    for q, row, col, far in place_labels(ordered, ct.rows, ct.cols, blocked):
        if far:
            _leader(rgb, q, row, col, scale)
        for k, ch in enumerate(q.text):
            labels[(row, col + k)] = (ch, q.style)
    if ov.cursor is not None:
        u, v = tf.source_to_display(*ov.cursor)
        u, v = int(round(float(u))), int(round(float(v)))
        for d in (2, 3, 4):
            for du, dv in ((d, 0), (-d, 0), (0, d), (0, -d)):
                _put(rgb, u + du, v + dv, CURSOR_RGB)
    return labels


def _leader(rgb: np.ndarray, q: LabelRequest, row: int, col: int, scale: float = 1.0) -> None:
    """A thin line from a marker to its id placed away from it (display pixels: `scale` per column,
    2 * `scale` per row); the part under the id's cells is hidden by the id."""
    ar, ac = q.anchor

    def at(c: int, r: int) -> tuple[int, int]:  # the middle of cell (r, c)
        return int((c + 0.5) * scale - 0.5), int((2 * r + 1) * scale)

    end = at(int(np.clip(ac, col, col + len(q.text) - 1)), row)
    cv2.line(rgb, at(ac, ar), end, tuple(int(v * 0.7) for v in q.colour), 1, cv2.LINE_8)


def _t(rgb) -> tuple[int, int, int]:
    from rich.color_triplet import ColorTriplet

    return ColorTriplet(*rgb)


def _put(rgb: np.ndarray, u: int, v: int, colour) -> None:
    if 0 <= v < rgb.shape[0] and 0 <= u < rgb.shape[1]:
        rgb[v, u] = colour


def _rect(rgb, tf: ViewTransform, xa, ya, xb, yb, colour) -> None:
    (ua, ub), (va, vb) = tf.source_to_display(np.array([xa, xb]), np.array([ya, yb]))
    pa = (int(np.floor(ua)), int(np.floor(va)))
    pb = (int(np.ceil(ub)), int(np.ceil(vb)))
    if max(abs(pa[0]), abs(pa[1]), abs(pb[0]), abs(pb[1])) > 100_000:
        return
    cv2.rectangle(rgb, pa, pb, colour, 1, cv2.LINE_8)


# --------------------------------------------------------------------------------------------
# segments
# --------------------------------------------------------------------------------------------
class StripBuilder:
    """Turns a display image into one `Strip` per cell row, caching a `Style` per colour pair."""

    MAX_STYLES = 60_000

    def __init__(self) -> None:
        self._styles: dict[int, Style] = {}
        self._runs: dict[int, str] = {}
        self.keys: np.ndarray | None = None  # colour-pair key per cell of the last build (labels < 0)

    def _style(self, key: int) -> Style:
        style = self._styles.get(key)
        if style is None:
            if len(self._styles) > self.MAX_STYLES:
                self._styles.clear()
            top, bot = key >> 24, key & 0xFFFFFF
            style = Style(color=RichColor.from_rgb(top >> 16, (top >> 8) & 255, top & 255),
                          bgcolor=RichColor.from_rgb(bot >> 16, (bot >> 8) & 255, bot & 255))
            self._styles[key] = style
        return style

    def _text(self, n: int) -> str:
        text = self._runs.get(n)
        if text is None:
            text = self._runs[n] = HALF * n
        return text

    def build(self, rgb: np.ndarray, labels: dict[tuple[int, int], tuple[str, Style]] | None = None) -> list[Strip]:
        h2, cols = rgb.shape[:2]
        rows = h2 // 2
        px = rgb.astype(np.int64)
        packed = (px[..., 0] << 16) | (px[..., 1] << 8) | px[..., 2]
        keys = (packed[0:2 * rows:2] << 24) | packed[1:2 * rows:2]
        label_rows: dict[int, dict[int, tuple[str, Style]]] = {}
        for (r, c), v in (labels or {}).items():
            if 0 <= r < rows and 0 <= c < cols:
                label_rows.setdefault(r, {})[c] = v
                keys[r, c] = -1 - c  # unique in the row, so labels always break runs
        self.keys = keys
        strips = []
        styles, runs = self._styles, self._runs
        style_of, text_of = self._style, self._text
        # run boundaries for all rows at once; the Python loop only visits runs
        change = np.zeros((rows, cols + 1), bool)
        change[:, 0] = change[:, cols] = True
        change[:, 1:cols] = keys[:, 1:] != keys[:, :-1]
        for r in range(rows):
            bounds = np.flatnonzero(change[r]).tolist()
            run_keys = keys[r, bounds[:-1]].tolist()
            row_labels = label_rows.get(r)
            segs = []
            append = segs.append
            for i, k in enumerate(run_keys):
                if k < 0:
                    ch, style = row_labels[bounds[i]]
                    append(Segment(ch, style))
                    continue
                n = bounds[i + 1] - bounds[i]
                text = runs.get(n) or text_of(n)
                style = styles.get(k) or style_of(k)
                append(Segment(text, style))
            strips.append(Strip(segs, cols))
        return strips


# --------------------------------------------------------------------------------------------
# widget
# --------------------------------------------------------------------------------------------
class FrameView(Widget):
    """One camera's frame. The app hands it display images (`set_pixels`) computed off the UI thread,
    plus overlays; the widget only composes and draws lines."""

    DEFAULT_CSS = """
    FrameView { width: 1fr; height: 1fr; border: round $panel; }
    FrameView.-active { border: round $accent; }
    """

    class Clicked(Message):
        """A click in the view, mapped to source pixels of this view's camera."""

        def __init__(self, view: FrameView, x: float, y: float, button: int) -> None:
            super().__init__()
            self.view, self.x, self.y, self.button = view, x, y, button

    class Resized(Message):
        pass

    class Pan(Message):
        """A drag: move the view by (dx, dy) source px."""

        def __init__(self, view: FrameView, dx: float, dy: float) -> None:
            super().__init__()
            self.view, self.dx, self.dy = view, dx, dy

    class Zoom(Message):
        def __init__(self, view: FrameView, factor: float, x: float, y: float) -> None:
            super().__init__()
            self.view, self.factor, self.x, self.y = view, factor, x, y

    def __init__(self, camera: str, *, name: str | None = None, id: str | None = None,
                 classes: str | None = None) -> None:
        super().__init__(name=name, id=id, classes=classes)
        self.camera = camera
        self.tf: ViewTransform | None = None
        self.pixels: np.ndarray | None = None  # display image for `tf`, no overlays
        self.pixels_key = None  # what the pixels show: (frame index, tf)
        self.overlays = Overlays()
        self.color_mode = "truecolor"
        self.message_text = ""
        self._builder = StripBuilder()
        self._strips: list[Strip] = []
        self._labels: dict = {}
        self._partial_ok = False  # True once the terminal shows our last strips in full
        self._drag_from: tuple[int, int] | None = None
        self._dragged = False
        self.last_compose_ms = 0.0
        self.graphics = None  # a tiles.GraphicsView when the terminal shows real pixels (kitty, sixel)

    # -- data in -----------------------------------------------------------------------------
    def set_pixels(self, pixels: np.ndarray, key, tf: ViewTransform) -> None:
        self.pixels, self.pixels_key, self.tf = pixels, key, tf
        self.recompose()

    def set_overlays(self, overlays: Overlays) -> None:
        self.overlays = overlays
        self.recompose()

    def show_message(self, text: str) -> None:
        self.message_text = text
        self.recompose()

    def recompose(self) -> None:
        import time

        t0 = time.perf_counter()
        if self.graphics is not None and self.pixels is not None and self.tf is not None:
            region = self.content_region
            if (self.tf.cols, self.tf.rows) == (region.width, region.height):  # else a frame for the new size is due
                self.graphics.draw(self.pixels, self.tf, self.overlays, self.message_text, (region.x, region.y))
            self.last_compose_ms = (time.perf_counter() - t0) * 1000
            if self._strips:  # text shown before (a message): blank those cells
                self._strips = []
                self.refresh()
            return
        if self.graphics is not None:
            self.graphics.clear()
        rows = self.content_size.height
        cols = self.content_size.width
        regions = None
        if self.pixels is None or self.tf is None:
            self._strips = []
        else:
            rgb = quantize(self.pixels, self.color_mode)
            labels = draw_overlays(rgb, self.tf, self.overlays)
            if self.message_text:
                style = Style(color="black", bgcolor="yellow", bold=True)
                for k, ch in enumerate(self.message_text[: self.tf.cols]):
                    labels[(0, k)] = (ch, style)
            prev_keys, prev_labels = self._builder.keys, self._labels
            self._strips = self._builder.build(rgb, labels)
            self._labels = labels
            if prev_keys is not None and prev_keys.shape == self._builder.keys.shape and self._partial_ok:
                regions = self._changed_regions(prev_keys, self._builder.keys, prev_labels, labels)
        if not self._strips and self.message_text and rows:
            self._strips = [Strip([Segment(self.message_text[:cols].ljust(cols), Style(color="yellow"))], cols)]
        self.last_compose_ms = (time.perf_counter() - t0) * 1000
        self._partial_ok = bool(self._strips)
        if regions is None:
            self.refresh()
        elif regions:
            self.refresh(*regions)

    @staticmethod
    def _changed_regions(old: np.ndarray, new: np.ndarray, old_labels: dict, new_labels: dict) -> list[Region]:
        """Only the cells that changed are sent to the terminal: between two frames most of the scene
        (walls, undisturbed sand) stays the same after averaging, so a step sends a fraction of the view."""
        diff = old != new
        for cell in set(old_labels) | set(new_labels):
            if old_labels.get(cell) != new_labels.get(cell) and cell[0] < diff.shape[0] and cell[1] < diff.shape[1]:
                diff[cell] = True
        regions = []
        for r in np.flatnonzero(diff.any(axis=1)).tolist():
            idx = np.flatnonzero(diff[r])
            regions.append(Region(int(idx[0]), r, int(idx[-1] - idx[0] + 1), 1))
        return regions

    # -- drawing -----------------------------------------------------------------------------
    def render_line(self, y: int) -> Strip:
        width = self.content_size.width
        if y < len(self._strips):
            strip = self._strips[y]
            if strip.cell_length != width:
                strip = strip.crop_extend(0, width, Style())
            return strip
        return Strip.blank(width)

    def on_resize(self, event: events.Resize) -> None:
        self._partial_ok = False
        self.post_message(self.Resized())

    # -- mouse -------------------------------------------------------------------------------
    def on_mouse_down(self, event: events.MouseDown) -> None:
        if event.button == 1 and self.tf is not None and event.get_content_offset(self) is not None:
            self._drag_from = (event.screen_x, event.screen_y)
            self._dragged = False
            self.capture_mouse()

    def on_mouse_move(self, event: events.MouseMove) -> None:
        if self._drag_from is None or not event.button or self.tf is None:
            return
        dx, dy = event.screen_x - self._drag_from[0], event.screen_y - self._drag_from[1]
        if dx or dy:
            self._dragged = True
            self._drag_from = (event.screen_x, event.screen_y)
            # the picture follows the pointer: the view's centre moves the other way
            self.post_message(self.Pan(self, -dx * self.tf.s, -2 * dy * self.tf.s))

    def on_mouse_up(self, event: events.MouseUp) -> None:
        if self._drag_from is not None:
            self._drag_from = None
            self.release_mouse()

    def on_click(self, event: events.Click) -> None:
        if self._dragged:  # the end of a drag is not a click
            self._dragged = False
            event.stop()
            return
        off = event.get_content_offset(self)
        if off is None or self.tf is None:
            return
        x, y = self.tf.cell_to_source(off.x, off.y)
        event.stop()
        self.post_message(self.Clicked(self, x, y, event.button))

    def _zoom_event(self, event: events.MouseEvent, factor: float) -> None:
        off = event.get_content_offset(self)
        if off is None or self.tf is None:
            return
        event.stop()
        x, y = self.tf.cell_to_source(off.x, off.y)
        self.post_message(self.Zoom(self, factor, x, y))

    def on_mouse_scroll_up(self, event: events.MouseScrollUp) -> None:
        self._zoom_event(event, 1.5)

    def on_mouse_scroll_down(self, event: events.MouseScrollDown) -> None:
        self._zoom_event(event, 1 / 1.5)
