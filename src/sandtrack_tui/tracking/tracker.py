"""One marker in one camera: a Kalman filter, a template matcher, a colour model and its status.

Status per frame (the store's STATUSES):
- ``tracked``: a match passed the gate, the NCC score, the peak-to-sidelobe ratio and the colour check;
  or a brightness model's marker whose colour check failed was found whole by its look at its last whole
  measurement (its disc's brightness pattern: look_match; the engine's measurements on the other view's
  line and across both views);
- ``occluded``: no acceptable match; the position written is the Kalman prediction (coasting);
- ``lost``: more than ``lost_after`` frames without a match; no position is claimed;
- ``manual``: the operator's point (a seed or a correction), used as a measurement as is.
A marker among touching lookalikes whose template is found but not its own outline is *held*:
followed by its template's peak (a loose measurement) but flagged ``occluded``, as its centre
is not measured.
A track never invents a match: when in doubt it coasts and says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..errors import SandtrackError
from . import crowd as crowd_rules
from .appearance import BRIGHT, DARK, AppearanceModel
from .highlight import CARRIED_AGREE_PX, Highlight
from .kalman import GATE_D2, ConstantVelocityKF
from .learning import learn
from .luma import LumaPattern, edge_circle, rim_step
from .matcher import Match, TemplateMatcher
from .refine import LOST_PLACE_PX, PLACE_MIN_FIT, LumaCarry
from .rest import RestReference

TRACKED, OCCLUDED, LOST, MANUAL, INTERPOLATED = "tracked", "occluded", "lost", "manual", "interpolated"
DEFAULT_BOX_PX = 16
# A marker touching others matches its seed template (the marker in a ring of sand) less well, and
# its neighbours' peaks crowd the NCC surface: its score and PSR limits are relaxed this much. (Who is
# who is the crowd rules' business: search.Crowded.)
TOUCHING_RELAX = 0.85
MERGED_COVERAGE = 1.4  # marker coverage (in seed discs) above which a blob is two markers merged
HELD_MEAS_PX = 1.0  # measurement noise of a held marker's template peak (no outline), px
SHORT_MISS = 3  # frames unseen up to which a returning marker's match is judged leniently (verify_at)
# A whole marker shows an outline of at least its radius less this share (a bead moving in depth changes its
# image size by about that over a box's depth; a larger circle is its contact shadow's rim, not a part hidden).
OUTLINE_RADIUS_TOL = 0.15
# ... and its outline steps by at least this share of its contrast with the sand all round (the median over
# rays, luma.rim_step): on the glass twin, whole beads 1.05 median (1 % under 0.37), a pale bead's faint rim
# 0.28 at the least; circles found in sand's texture 0.05 median, 99 % under 0.21.
RIM_SHARE = 0.25


@dataclass
class TrackParams:
    min_score: float = 0.7  # NCC peak to accept a match
    min_psr: float = 4.0  # peak-to-sidelobe ratio to accept a match
    min_colour: float = 0.55  # marker coverage (fraction of the seed disc) to accept a match
    confident_score: float = 0.85  # the updated template learns only from matches this good ...
    confident_colour: float = 0.85  # ... and this complete
    template_alpha: float = 0.15
    level_alpha: float = 0.3  # share of a dark marker's change in brightness its model follows per frame
    template_every: int = 2  # frames between template updates (slow drift; half the cost)
    lost_after: int = 25  # frames of coasting before a track is declared lost
    accel_px: float = 2.0  # Kalman process noise: white acceleration, px/frame²
    meas_px: float = 0.3  # measurement noise, px
    max_search_px: float = 80.0  # cap of the half search window while hidden
    max_jump_px: float = 30.0  # a marker's largest move per frame: searched this far (per frame unseen)
    max_band_search_px: float = 240.0  # ... and at most this far along the other view's epipolar band
    # Between intra-coded frames, report the luma edge centre + the colour-minus-luma offset of the
    # last intra frame (luma.py), while the marker stays within this distance of where it was then; a
    # marker with no dark silhouette (white on beige sand) is followed by its disc's brightness pattern,
    # cut again once it has moved this far.
    luma_carry: bool = True
    luma_carry_max_px: float = 12.0
    # A marker whose brightness window has shifted by at most rest_shift_px, and changed otherwise
    # by at most max(rest_residual, rest_residual_frac x its contrast) rms, since its last full
    # measurement is that measurement moved by the shift (rest.py); intra frames are always measured.
    rest_check: bool = True
    rest_shift_px: float = 0.2
    rest_residual: float = 3.0
    rest_residual_frac: float = 0.03
    # Re-interpolate 4:2:0 chroma at this sample position (x, y) within its 2 x 2 block (chroma.py);
    # None = use the decoder's replicated chroma. The position depends on the camera/encoder chain.
    chroma_siting: tuple | None = None
    gate_d2: float = GATE_D2


class Observation(NamedTuple):
    """One marker in one camera frame, in the store's point columns (a tuple: made per track and frame)."""

    frame: int
    camera: str
    marker: int
    x_px: float
    y_px: float
    status: str
    score: float = float("nan")
    psr: float = float("nan")
    colour_frac: float = float("nan")

    def row(self) -> tuple:
        return tuple(self)


class MarkerTrack:
    def __init__(self, marker: int, camera: str, frame_bgr: np.ndarray, frame_index: int, x: float, y: float,
                 w: float | None = None, h: float | None = None, params: TrackParams | None = None,
                 refine_seed: bool = True, kind: str | None = None, like: AppearanceModel | None = None):
        self.marker, self.camera = int(marker), camera
        self.params = params or TrackParams()
        H, W = frame_bgr.shape[:2]
        if not (np.isfinite(x) and np.isfinite(y)) or not (0 <= x < W and 0 <= y < H):
            raise SandtrackError(f"marker {marker} ({camera}, frame {frame_index}): seed ({x:.1f}, {y:.1f}) "
                                 f"lies outside the {W}x{H} image")
        w = float(w) if w is not None and np.isfinite(w) and w > 0 else DEFAULT_BOX_PX
        h = float(h) if h is not None and np.isfinite(h) and h > 0 else DEFAULT_BOX_PX
        try:
            self.model: AppearanceModel = learn(frame_bgr, x, y, w, h, kind=kind, like=like)
        except SandtrackError as exc:
            raise SandtrackError(f"marker {marker} ({camera}, frame {frame_index}): {exc}") from None
        self.matcher = TemplateMatcher(self.model, frame_bgr, x, y)
        if refine_seed:
            rx, ry, frac = self.matcher.refine_at(frame_bgr, x, y)
            if frac >= 0.5 and np.hypot(rx - x, ry - y) <= max(w, h):
                x, y = rx, ry
                self.matcher = TemplateMatcher(self.model, frame_bgr, x, y)
        p = self.params
        self.matcher.confident_score = p.confident_score
        self.kf = ConstantVelocityKF(x, y, accel_px=p.accel_px, meas_px=p.meas_px)
        self.status = MANUAL
        self.misses = 0
        self.frame_index = frame_index
        self.seed_xy = (x, y)
        self.reacquisitions = 0
        self._since_update = 0
        self.counts = {TRACKED: 0, OCCLUDED: 0, LOST: 0, MANUAL: 0}
        self.carry = LumaCarry(self.model, self.params, self.kf)  # its colour centre carried by its brightness
        self._rest: RestReference | None = None
        # A brightness model's marker at its last full measurement: (window, x0, y0, x, y) of its
        # LumaPattern, cut when first wanted (look_match), then the pattern itself.
        self._look: tuple | LumaPattern | None = None
        self.rest_frames = 0
        self.held = False
        self.highlight = Highlight(self.model)  # a crowd bead's highlight: where it sits, how far it stands out
        self.carried = False  # missed among touching lookalikes, moved with the layer (crowd_passes.py): not lost
        self._last_measured: tuple | None = (frame_index, x, y)  # (frame, x, y) of the last match or point

    @property
    def intra(self) -> np.ndarray | None:
        """Per frame of this camera: intra-coded (set by the caller; the luma carry reads it)."""
        return self.carry.intra

    @intra.setter
    def intra(self, mask) -> None:
        self.carry.intra = mask

    # -- per frame -----------------------------------------------------------------------------
    @property
    def coasting(self) -> bool:
        """Not followed: unseen (a held track is followed, though flagged)."""
        return self.status in (OCCLUDED, LOST) and not self.held

    @property
    def awaiting_outline(self) -> bool:
        """A seed among touching lookalikes that no frame has confirmed yet (its outline was not found
        all round it), missed for at most SHORT_MISS frames: still searched where it was seeded, as its
        match is taken only with its outline. (Where the bead was seen a few frames ago it most likely
        still is; later it may have been carried anywhere.)"""
        return self.model.crowd and self.status == OCCLUDED and self.counts[TRACKED] == 0 \
            and self.misses <= SHORT_MISS

    def predict(self) -> None:
        self.kf.advance()

    def search_halfsize(self) -> tuple[float, float]:
        hx, hy = self.kf.gate_halfsize(self.params.gate_d2)
        cap = self.params.max_search_px
        return min(hx, cap), min(hy, cap)

    def propose(self, frame_bgr: np.ndarray, frame_index: int | None = None) -> Match | None:
        """Best acceptable match inside the gate (after predict), or None."""
        r, p = self._rest, self.params
        if r is not None and self.status == TRACKED and not self.carry.is_intra(frame_index):
            d = r.shift(frame_bgr, p.rest_shift_px, r.residual_limit)
            if d is not None:
                o = r.match
                x, y = o.x + d[0], o.y + d[1]
                return Match(x, y, o.score, o.psr, o.colour_frac, self.kf.d2(x, y),
                             o.used_centroid, None if o.luma is None else (o.luma[0] + d[0], o.luma[1] + d[1]),
                             rest=True, look=o.look)
        px, py = self.kf.xy
        hx, hy = self.search_halfsize()
        m = self.matcher.match(frame_bgr, px, py, hx, hy, self.kf.innovation_inv(), self.params.gate_d2,
                               self.kf.vxy)
        if m is None:
            return self.carry.pattern_match(frame_bgr, frame_index) or self.look_match(frame_bgr)
        if not m.outline and self.counts[TRACKED] == 0:
            return None  # (held only once measured since its seed: a seed nothing confirmed is not followed)
        m.d2 = self.kf.d2(m.x, m.y)
        if not self.acceptable(m, TOUCHING_RELAX if m.touching else 1.0) or self.cut_by_border(frame_bgr, m) \
                or not self.carry.refine(frame_bgr, m, frame_index):
            return self.carry.pattern_match(frame_bgr, frame_index) or self.look_match(frame_bgr, (m.x, m.y))
        self._centre_by_highlight(frame_bgr, m)
        return m

    def _centre_by_highlight(self, frame_bgr, m: Match) -> None:
        """A crowd match centred by its highlight where its outline does not measure it (Highlight.centre)."""
        if self.highlight.centre(frame_bgr, m):
            m.d2 = self.kf.d2(m.x, m.y)

    def look_match(self, frame_bgr, near: tuple | None = None) -> Match | None:
        """A marker of a brightness model whose match failed, found again by its look at its last full
        measurement: the brightness pattern of its disc there (luma.LumaPattern: its body, rim and
        highlight), registered inside the gate and fitting as closely as a marker seen whole fits its
        pattern of the frame before (MIN_NCC). A marker's look may change while its match fails: a glass
        bead's body shows the sand beneath it and turns pale where the lamp's light is focused through it,
        which its model reads as too little coverage; its pattern still fits. A marker partly hidden (by
        the tool, by sand) does not: what hides it is in its disc. The pattern is registered from the
        prediction and from `near` (the failed match's place, or None): where both fit, they must agree
        (LOST_PLACE_PX), or the place is not clear. None otherwise."""
        pattern = self._look_pattern()
        if pattern is None:
            return None
        found = None
        for x, y in (self.kf.xy,) if near is None else (self.kf.xy, near):
            got = pattern.find(frame_bgr, x, y)
            if got is None:
                continue
            if found is not None and math.hypot(got[0] - found[0][0], got[1] - found[0][1]) > LOST_PLACE_PX:
                return None
            if found is None or pattern.fit > found[1]:
                found = (got, pattern.fit)
        if found is None:
            return None
        (x, y), fit = found
        m = Match(x, y, fit, float("nan"), float("nan"), self.kf.d2(x, y), look=True)
        if m.d2 > self.params.gate_d2 or self.cut_by_border(frame_bgr, m) or not self.shows_whole(frame_bgr, x, y):
            return None
        return m

    def look_place(self, frame_bgr, x: float, y: float) -> tuple[float, float] | None:
        """Where the marker's look at its last full measurement registers from (x, y) when it fits at
        least PLACE_MIN_FIT, else None (a place only: the caller knows otherwise that the marker is there)."""
        pattern = self._look_pattern()
        if pattern is None:
            return None
        pattern.find(frame_bgr, x, y)
        return pattern.place if pattern.place is not None and pattern.fit >= PLACE_MIN_FIT else None

    @property
    def look_fit(self) -> float:
        """How closely the marker's look fitted where it was last registered."""
        return self._look.fit if isinstance(self._look, LumaPattern) else float("nan")

    def _look_return(self, frame_bgr) -> Match | None:
        """look_match for a coasting marker, also from its template's best place inside the gate."""
        if self._look is None:
            return None
        px, py = self.kf.xy
        hx, hy = self.search_halfsize()
        m = self.matcher.match(frame_bgr, px, py, hx, hy, self.kf.innovation_inv(), self.params.gate_d2)
        return self.look_match(frame_bgr, None if m is None else (m.x, m.y))

    def _look_pattern(self) -> LumaPattern | None:
        look = self._look
        if isinstance(look, tuple):
            win, x0, y0, x, y = look
            look = LumaPattern.from_window((win, x0, y0), x, y, self.model.radius)
            self._look = look = look if look.ok else None
        return look

    def _keep_look(self, frame_bgr, m: Match) -> None:
        """Keep the marker's look at a full measurement (a window of it: its pattern is cut when wanted)."""
        if frame_bgr is None or self.model.kind not in (DARK, BRIGHT) or self.model.crowd:
            return
        cut = LumaPattern.window(frame_bgr, m.x, m.y, self.model.radius)
        self._look = None if cut is None else (*cut, m.x, m.y)

    def pattern_return(self, frame_bgr, frame_index: int | None = None) -> Match | None:
        """A coasting marker with no dark silhouette, unseen a few frames at most, whose brightness
        pattern is found again near its prediction (as closely as a followed marker's: see LumaPattern)
        is back in sight: its colour, stale between intra frames, may not say so yet; so is a brightness
        model's marker found whole by its look (look_match, from its prediction and from its template's
        best place in the gate). So is a lost one
        whose pattern, kept from before it was hidden (the light, not the marker, sets a matte marker's
        shading), is found within its radius of its prediction, from there and from around it alike."""
        if not self.coasting:
            return None
        if self.misses <= SHORT_MISS:
            return self.carry.pattern_match(frame_bgr, frame_index) or self._look_return(frame_bgr)
        if self.status != LOST or self.carry.kept is None or self.model.luma_follows:
            return None
        placed = self.carry.resume(frame_bgr, self.carry.kept, *self.kf.xy)
        if placed is None:
            return None
        x, y, found, fit = placed
        return Match(x, y, fit, float("nan"), float("nan"), self.kf.d2(x, y), True, found)

    def shows_whole(self, frame_bgr, x: float, y: float) -> bool:
        """The marker of a brightness model at (x, y) shows its outline all round, of its own size, stepping
        from its rim to the sand by a good part of its contrast. A marker partly hidden (behind the tool, or
        sinking) shows part of its disc: a template or a look slides to the part in sight, and the outline
        found round it is a smaller circle, or not found all round; sand's texture shows circles of edges
        too, but of a few levels."""
        model = self.model
        polarity = 1.0 if model.kind == DARK else -1.0
        e = edge_circle(frame_bgr, x, y, model.radius, polarity=polarity, outward=model.kind == DARK)
        if e is None or e[3] < 4 or e[2] < (1.0 - OUTLINE_RADIUS_TOL) * model.radius:
            return False
        level_d, level_s = model.levels
        return rim_step(frame_bgr, e[0], e[1], e[2], polarity) >= RIM_SHARE * abs(level_d - level_s)

    def cut_by_border(self, frame_bgr, m: Match) -> bool:
        """The marker's disc reaches the image's edge: part of it is outside the picture, and the
        centre of what is left is not the marker's."""
        if not self.model.has_blob:
            return False
        H, W = frame_bgr.shape[:2]
        r = self.model.radius + 1.0
        return m.x < r or m.y < r or m.x > W - 1 - r or m.y > H - 1 - r

    def acceptable(self, m: Match, relax: float = 1.0) -> bool:
        p = self.params
        # (among touching markers like it every neighbour is a peak of the NCC surface: the PSR says
        # nothing there; who is who is the gate's and the crowd rules' business)
        psr_ok = not math.isfinite(m.psr) or m.psr >= p.min_psr * relax or self.model.crowd
        colour_ok = not self.model.has_blob or m.colour_frac >= p.min_colour
        return m.score >= p.min_score * relax and colour_ok and psr_ok

    def verify_at(self, frame_bgr: np.ndarray, x: float, y: float, frame_index: int | None = None) -> Match | None:
        """Match in a small window around a candidate point (re-acquisition); None if it fails. With
        the candidate's `frame_index`, a move since the last measurement may have smeared it (a streak)."""
        velocity = None
        last = self._last_measured
        if frame_index is not None and last is not None and frame_index != last[0]:
            steps = abs(frame_index - last[0])
            velocity = ((x - last[1]) / steps, (y - last[2]) / steps)
        m = self.matcher.match(frame_bgr, x, y, 2.0, 2.0, velocity=velocity)
        if m is None:
            return None
        # Back after a frame or two (half hidden still), a marker may match its template less well;
        # after a longer absence a blob must look as much like it as a tracked marker does: by then
        # where it is says little, and a lookalike nearby may be taken for it.
        relax = 0.9 if self.misses <= SHORT_MISS else 1.0
        if not self.acceptable(m, relax):
            m = self.carry.whole_by_pattern(frame_bgr, m, relax)
            if m is None:
                return None
        if self.model.has_blob and m.colour_frac > MERGED_COVERAGE:
            return None  # the candidate is this marker merged with another: who is who is not clear
        if self.cut_by_border(frame_bgr, m) or self.carry.denies(frame_bgr, m, frame_index):
            return None
        m.d2 = self.kf.d2(m.x, m.y)
        self._centre_by_highlight(frame_bgr, m)
        return m

    def verify_assigned(self, frame_bgr: np.ndarray, x: float, y: float) -> Match | None:
        """A crowd marker given a detected bead by assignment (crowd_passes.py: who it is comes from where the
        layer carried it, not from how it looks), measured there by its own outline, found all round it
        and of its own radius (as any crowd match), whatever its template's score: the template was cut
        among the bead's old neighbours, and once the layer has deformed it fits the bead among its new
        ones poorly (NCC 0.0-0.66 where the pairing was right). Its updated template is cut again there
        (apply). None without that outline, or on a blob of two beads merged, or cut by the border."""
        m = self.matcher.match(frame_bgr, x, y, 2.0, 2.0)
        if m is None or not m.outline or m.colour_frac > self._merged_coverage() or self.cut_by_border(frame_bgr, m):
            return None
        m.assigned = True
        m.d2 = self.kf.d2(m.x, m.y)
        return m

    def confirm_carried(self, frame_bgr: np.ndarray, x: float, y: float) -> Match | None:
        """A crowd marker carried by the layer's motion (or placed by its neighbours' moves) to (x, y)
        (crowd_passes.py), measured again: its template found there, and its highlight (crowd.highlight) found
        where this bead's own highlight sits from its centre (learned while its outline was seen all round
        it), giving a centre near (x, y): two independent estimates of where the bead is agree. Near: as
        far as keeps the highlight's search on the bead's body (Highlight.agree_px); or, within half a
        radius (an assignment's gate), where the bead's own outline of its radius is found all round that
        centre too, or where the search lay on the body of a bead centred there (Highlight.own). The
        highlight must stand out of that body as the bead's own does (Highlight.stands_out). Else None (it stays
        flagged)."""
        off = self.highlight.offset
        if off is None:
            return None
        m = self.matcher.match(frame_bgr, x, y, 2.0, 2.0)
        if m is None or self.cut_by_border(frame_bgr, m):
            return None
        h = crowd_rules.highlight(frame_bgr, x + off[0], y + off[1], self.highlight.reach())
        if h is None:
            return None
        cx, cy = h[0] - off[0], h[1] - off[1]
        d = math.hypot(cx - x, cy - y)
        if d > self.highlight.agree_px():
            # (farther, within the gate of an assignment: its own outline, of its radius, found all round that
            # centre confirms it; the sand between beads gives no such outline. Or, where its outline is pressed
            # against its neighbours' or half under the tool, its highlight itself: found on the body of a bead
            # centred there and standing out of that body as this bead's own highlight does)
            if d > 0.5 * self.model.radius:
                return None
            e = self.matcher.silhouette(frame_bgr, cx, cy, strict=True)
            if e is not None and math.hypot(e[0] - cx, e[1] - cy) <= CARRIED_AGREE_PX:
                cx, cy = e
            elif not self.highlight.own(frame_bgr, h, (x + off[0], y + off[1]), (cx, cy)):
                return None
        elif not self.highlight.stands_out(frame_bgr, h, (cx, cy)):
            return None
        m.x, m.y, m.outline, m.used_centroid = cx, cy, True, True
        m.d2 = self.kf.d2(m.x, m.y)
        return m

    def confirm_on_line(self, frame_bgr: np.ndarray, x: float, y: float) -> Match | None:
        """A crowd marker carried by the layer's motion, placed at (x, y) on the other view's epipolar line
        (crowd_passes.py), measured by its own outline: a circle of its radius found all round it within half a
        radius of there (TemplateMatcher.silhouette, strict), whatever its template scores (a bead half hidden
        behind its neighbours shows only part of its shading). None without that outline, on a blob of two
        beads merged, or cut by the border."""
        m = self.matcher.match(frame_bgr, x, y, 2.0, 2.0)
        if m is None or m.colour_frac > self._merged_coverage():
            return None
        e = self.matcher.silhouette(frame_bgr, x, y, strict=True)
        if e is None:
            return None
        m.x, m.y = e
        m.outline, m.used_centroid, m.lit = True, True, False
        if self.cut_by_border(frame_bgr, m):
            return None
        m.d2 = self.kf.d2(m.x, m.y)
        return m

    def _merged_coverage(self) -> float:
        """Marker coverage (in discs) above which a crowd match centred on its outline is two beads merged:
        more than a bead shows with six like it touching it all round (crowd.packed_coverage; a small bead's
        window holds relatively more of its neighbours' rims), and never under MERGED_COVERAGE."""
        return crowd_rules.packed_coverage(self.model.radius, MERGED_COVERAGE)

    def apply(self, frame_index: int, frame_bgr: np.ndarray | None, m: Match | None,
              reattach: bool = False, jump: bool = False) -> Observation:
        """Commit this frame's outcome and return its observation. `jump`: re-attached beyond the
        gate; the velocity restarts from the move since the last measurement."""
        self.frame_index = frame_index
        p = self.params
        if m is not None:
            self.carry.kept = None
        self.carry.update(frame_index, m, reattach, frame_bgr, self.misses >= SHORT_MISS)
        self.held = m is not None and not m.outline
        if self.held:
            self._rest = None
            self.kf.update((m.x, m.y), HELD_MEAS_PX)
            self.status = OCCLUDED
            obs = Observation(frame_index, self.camera, self.marker, m.x, m.y, OCCLUDED, m.score, m.psr, m.colour_frac)
        elif m is not None:
            last = self._last_measured
            steps = abs(frame_index - last[0]) if last is not None else 0
            if jump and 0 < steps <= 3:
                self.kf.reset(m.x, m.y, velocity=((m.x - last[1]) / steps, (m.y - last[2]) / steps))
                self.reacquisitions += 1
            elif reattach and self.misses > 2:
                self.kf.reset(m.x, m.y)
                self.reacquisitions += 1
            else:
                self.kf.update((m.x, m.y), None if m.used_centroid else 1.0)
            # A dark marker's level follows its body (appearance.follow_level), also at rest (a glass bead
            # shows the sand beneath it): the marker's look, not its coverage by the model, says the
            # match is good, since a marker whose body lightens loses coverage first.
            if frame_bgr is not None and self.model.kind == DARK and not self.model.crowd and not m.look \
                    and m.score >= p.confident_score and m.used_centroid:
                self.model.follow_level(self.matcher.middle_score(frame_bgr, m.x, m.y), p.level_alpha)
            # (at rest the centre is the last measurement moved by the brightness shift: it is learned from
            # there only while no offset is known, e.g. a bead at rest since its seed)
            if self.model.crowd and frame_bgr is not None and not reattach and not m.lit \
                    and (not m.rest or self.highlight.offset is None):
                self.highlight.learn(frame_bgr, m)
            if m.assigned and frame_bgr is not None:  # (its template no longer fits it: cut again where it is)
                self.matcher.update_template(frame_bgr, m.x, m.y, 1.0)
            if m.rest:
                self.rest_frames += 1
            else:
                self._since_update += 1
                # (a crowd bead centred on its own outline is whole and clearly seen however its template
                # scores: among moving neighbours the template cut among the old ones fits it less and less)
                sure = m.score >= p.confident_score or (self.model.crowd and m.outline and not m.lit)
                clean = sure and (
                    not self.model.has_blob or (m.colour_frac >= p.confident_colour and m.used_centroid))
                if clean or m.line:
                    self._keep_look(frame_bgr, m)
                if frame_bgr is not None and self._since_update >= p.template_every and clean:
                    self.matcher.update_template(frame_bgr, m.x, m.y, p.template_alpha)
                    self._since_update = 0
                self._rest = RestReference(frame_bgr, m.x, m.y, self.model.radius, m, p.rest_residual,
                                           p.rest_residual_frac) \
                    if (p.rest_check and self.model.luma_follows and frame_bgr is not None and not reattach) else None
            self.status, self.misses = TRACKED, 0
            self._last_measured = (frame_index, m.x, m.y)
            obs = Observation(frame_index, self.camera, self.marker, m.x, m.y, TRACKED, m.score, m.psr, m.colour_frac)
        else:
            self._rest = None
            self.kf.coast()
            self.misses += 1
            if self.misses > p.lost_after and not self.carried:
                self.status = LOST
                obs = Observation(frame_index, self.camera, self.marker, float("nan"), float("nan"), LOST)
            else:
                self.status = OCCLUDED
                x, y = self.kf.xy
                obs = Observation(frame_index, self.camera, self.marker, x, y, OCCLUDED)
        self.counts[obs.status] += 1
        return obs

    def set_manual(self, frame_index: int, frame_bgr: np.ndarray | None, x: float, y: float) -> Observation:
        """An operator's point met along the way: trust it, keep tracking from it."""
        self.carry.reset()
        self._rest = None
        self.held = False
        if self.misses > 2:
            self.kf.reset(x, y)
        else:
            self.kf.update((x, y), 0.2)
        self.status, self.misses, self.frame_index = TRACKED, 0, frame_index
        self._last_measured = (frame_index, x, y)
        self.counts[MANUAL] += 1
        return Observation(frame_index, self.camera, self.marker, x, y, MANUAL)

    def seed_observation(self) -> Observation:
        x, y = self.kf.position
        self.counts[MANUAL] += 1
        return Observation(self.frame_index, self.camera, self.marker, float(x), float(y), MANUAL, 1.0, float("nan"),
                           1.0)
