"""A colour marker's centre refined between the video's intra frames (luma.py: a 4:2:0 video's chroma is
decoded at half resolution and, between key frames, trails a moving marker): at an intra frame the colour
centre's offset from the marker's full-resolution brightness centre is measured (its edge circle, or, when its
brightness does not set it apart from the sand, its disc's brightness pattern, luma.LumaPattern), and that
brightness carries the centre through the frames after it (LumaCarry.refine). The chain of patterns is kept
through a short miss, and after a long one, to find the marker again by its look (resume, whole_by_pattern)."""

from __future__ import annotations

import math

import numpy as np

from .appearance import COLOUR, AppearanceModel
from .kalman import ConstantVelocityKF
from .luma import LumaPattern, edge_centre
from .matcher import Match
from .streak import STREAK_MIN_SPEED

# A fast marker's colour match this far behind its brightness pattern is stale chroma: half the pitch of
# 4:2:0 chroma samples (2 px), under which the colour's centre cannot tell where the marker is anyway.
STALE_BEHIND_PX = 1.0
# A colour match covering less than a whole disc lying farther than this from where the marker's brightness
# pattern registers is the uncovered part of a marker partly hidden: the pitch of 4:2:0 chroma samples, within
# which a whole marker's colour and pattern agree.
PARTIAL_ASTRAY_PX = 2.0
# The luma carry fits the silhouette's circle once, from the colour centre less the last intra frame's offset:
# that start lies within a fraction of the radius of the silhouette's centre (the sample: 0.31 px median, 1.4 px
# at most), where the rays still cross the outline nearly square and the circle through their edge points is the
# silhouette's. Fitted again from its own centre, it moved by 0.06 px (median), no nearer the truth: the sample's
# centres 0.198 / 0.500 px (mean / p95) with one fit, 0.201 / 0.519 px with up to three.
CARRY_EDGE_ROUNDS = 1
LOST_PLACE_PX = 0.5  # a lost marker's pattern found from around its place must come back this near it
PLACE_MIN_FIT = 0.5  # a pattern fitting worse (a quarter of its disc's brightness variance explained) has no place


class LumaCarry:
    """One track's chain from its last intra frame (the track's model, parameters and Kalman filter shared)."""

    def __init__(self, model: AppearanceModel, params, kf: ConstantVelocityKF):
        self.model, self.params, self.kf = model, params, kf
        self.intra = None  # per frame of this camera: intra-coded (set by the caller)
        self.offset: tuple | None = None  # colour centre - luma centre at the last intra frame
        self.anchor_luma: tuple | None = None
        self.pattern: LumaPattern | None = None  # the marker's brightness at the last intra frame (no silhouette)
        self.kept: tuple | None = None  # (pattern, offset, anchor) of a chain broken by a long miss

    def reset(self) -> None:
        """An operator's point: no chain goes on through it."""
        self.offset = self.anchor_luma = self.pattern = self.kept = None

    def resume(self, frame_bgr, chain: tuple, x: float, y: float) -> tuple | None:
        """(x, y, pattern's place, fit) of the marker where the brightness pattern of `chain` ((pattern, its
        centre's offset from the marker's, anchor luma)) registers from around (x, y), when it fits
        (LumaPattern.MIN_NCC) within the marker's radius of there and at one place, not one of several (found
        again alike from half a radius either side): the chain goes on from there (it becomes the live one).
        Else None, the chain left as it was."""
        pattern, offset, anchor = chain
        r = self.model.radius
        found = pattern.find(frame_bgr, x - offset[0], y - offset[1])
        if found is None or math.hypot(found[0] + offset[0] - x, found[1] + offset[1] - y) > r:
            return None
        fit = pattern.fit
        for dx, dy in ((r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)):
            other = pattern.find(frame_bgr, found[0] + 0.5 * dx, found[1] + 0.5 * dy)
            if other is not None and math.hypot(other[0] - found[0], other[1] - found[1]) > LOST_PLACE_PX:
                return None
        self.pattern, self.offset, self.anchor_luma, self.kept = pattern, offset, anchor, None
        return found[0] + offset[0], found[1] + offset[1], found, fit

    def whole_by_pattern(self, frame_bgr, m: Match, relax: float) -> Match | None:
        """A marker with no dark silhouette, found again where a blob of its colour was (re-acquisition), whose
        colour's peak stands out there (PSR) but covers less of its seed disc than min_colour, or fits its
        template less than min_score. Its colour alone cannot tell a part of it from the whole of it: a white
        marker back in sight in a furrow of disturbed sand shows about half its seed disc's chroma contrast
        while its brightness is unchanged (the white twin: coverage 0.41-0.68 and template NCC 0.59-0.80 on
        markers seen whole, the colour's centre 0.5-1.9 px off them); the template is a colour template, and
        fits less for the same reason. Its brightness pattern, the live chain's or the one kept from before it
        was lost, says which: a whole marker fits it (LumaPattern.MIN_NCC, closer than any template's
        min_score), a part does not (what hides it is in its disc). Found so, within its radius of the colour's
        centre and at one place, the marker is there, placed as its pattern puts it (0.1-0.4 px off on those
        frames); its chain goes on from there. None otherwise."""
        p = self.params
        if self.model.luma_follows or not self.model.has_blob or (math.isfinite(m.psr) and m.psr < p.min_psr * relax):
            return None
        chain = self.kept or (self.pattern, self.offset, self.anchor_luma)
        if chain[0] is None or chain[1] is None:
            return None
        placed = self.resume(frame_bgr, chain, m.x, m.y)
        if placed is None:
            return None
        x, y, found, _fit = placed
        return Match(x, y, m.score, m.psr, m.colour_frac, self.kf.d2(x, y), True, found)

    def pattern_match(self, frame_bgr, frame_index: int | None) -> Match | None:
        """A marker with no dark silhouette whose colour match failed (between intra frames its colour is
        stale: a moving marker's is left behind, and weakens; at an intra frame a smear or a partial
        cover may fail it) is measured by its brightness pattern (see _carry_pattern) when that is
        found inside the gate; else None. At an intra frame the pattern is cut again where it was found
        (the chain goes on from there with the offset it had: no fresh colour measured it)."""
        if self.model.luma_follows or self.pattern is None or self.offset is None:
            return None
        found = self.pattern.find(frame_bgr, *self.kf.xy, velocity=self.kf.vxy)
        if found is None:
            return None
        x, y = found[0] + self.offset[0], found[1] + self.offset[1]
        d2 = self.kf.d2(x, y)
        if d2 > self.params.gate_d2:
            return None
        fit = self.pattern.fit
        if self.is_intra(frame_index):
            self.pattern = LumaPattern(frame_bgr, *found, self.model.radius)
        return Match(x, y, fit, float("nan"), float("nan"), d2, True, found)

    @property
    def intra(self) -> np.ndarray | None:
        return self._intra
    @intra.setter
    def intra(self, mask) -> None:
        self._intra = mask
        self._intra_set = None if mask is None else frozenset(np.flatnonzero(mask).tolist())

    def is_intra(self, frame_index: int | None) -> bool:
        s = self._intra_set
        return s is not None and frame_index in s

    def refine(self, frame_bgr, m: Match, frame_index: int | None) -> bool:
        """Measure the luma centre of a whole, clearly seen marker; between intra frames, move the
        match to luma centre + the last intra frame's offset (see luma.py). False: the match is the
        marker's stale colour, not the marker (see _carry_pattern)."""
        if self.intra is None or not self.params.luma_carry or self.model.kind != COLOUR:
            return True  # (a brightness model measures the full-resolution luma itself: nothing trails)
        intra = self.is_intra(frame_index)
        if not m.used_centroid and (intra or self.model.luma_follows):
            return True  # (a pattern is cut, and an edge measured, on a whole, clearly seen marker only)
        if not intra and self.offset is None:
            return True  # nothing to carry until the next intra frame
        if not self.model.luma_follows:
            return self._carry_pattern(frame_bgr, m, intra)
        sx, sy = m.x, m.y
        if self.offset is not None:  # start from where the edge centre is expected
            sx, sy = sx - self.offset[0], sy - self.offset[1]
        m.luma = edge_centre(frame_bgr, sx, sy, self.model.radius, iterations=CARRY_EDGE_ROUNDS, outward=True)
        if m.luma is None or intra:
            return True
        lx, ly = m.luma
        ax, ay = self.anchor_luma
        dx, dy = lx - ax, ly - ay
        dist = math.hypot(dx, dy)
        if 1e-3 < dist <= self.params.luma_carry_max_px:
            # Stale colour can only hold the centre back towards where the marker was at the intra
            # frame: move it forward along that motion, by at most the distance moved since.
            ux, uy = dx / dist, dy / dist
            along = (lx + self.offset[0] - m.x) * ux + (ly + self.offset[1] - m.y) * uy
            along = min(max(along, 0.0), dist)
            m.x, m.y = m.x + along * ux, m.y + along * uy
        return True

    def _carry_pattern(self, frame_bgr, m: Match, intra: bool) -> bool:
        """refine for a marker with no dark silhouette (its brightness does not set it apart from the
        sand: a white marker on beige sand): its disc's brightness pattern at the intra frame
        (luma.LumaPattern), found again in the frames after it, moved as far as the marker, which
        is then there: the pattern is the marker's own (not an edge that shading or a shadow may
        shift), so the stale colour is not trusted in any direction.
        When the pattern fits too poorly to tell where the marker is, the colour match stands, unless
        the marker moves fast (STREAK_MIN_SPEED or more) and the colour lies behind where the pattern
        registers, along the motion, by more than STALE_BEHIND_PX: that colour is the chroma left
        behind by the moving marker (stale between intra frames); or unless the colour covers less than
        a whole disc and lies more than PARTIAL_ASTRAY_PX from where the pattern registers (fitting at
        least PLACE_MIN_FIT): that is the part of a marker not yet hidden. Then the marker is not
        measured (False)."""
        if intra:
            self.pattern = LumaPattern(frame_bgr, m.x, m.y, self.model.radius)
            m.luma = (m.x, m.y) if self.pattern.ok else None
            return True
        m.luma = None if self.pattern is None else self.pattern.find(frame_bgr, m.x, m.y, velocity=self.kf.vxy)
        if m.luma is None:
            return self.pattern is None or not (self._colour_left_behind(m) or self._partial_colour_astray(m))
        m.x, m.y = m.luma[0] + self.offset[0], m.luma[1] + self.offset[1]
        return True

    def _colour_left_behind(self, m: Match) -> bool:
        """The fast marker's colour match m lies behind its pattern's last registration along the motion."""
        place, (vx, vy) = self.pattern.place, self.kf.vxy
        speed = math.hypot(vx, vy)
        if place is None or speed < STREAK_MIN_SPEED:
            return False
        px, py = place[0] + self.offset[0], place[1] + self.offset[1]
        return ((m.x - px) * vx + (m.y - py) * vy) / speed < -STALE_BEHIND_PX

    def _partial_colour_astray(self, m: Match) -> bool:
        """Colour match m covers less than a whole disc and lies away from its pattern's last registration."""
        place = self.pattern.place
        if m.colour_frac >= self.params.confident_colour or place is None or self.pattern.fit < PLACE_MIN_FIT:
            return False
        return math.hypot(m.x - place[0] - self.offset[0], m.y - place[1] - self.offset[1]) > PARTIAL_ASTRAY_PX

    def update(self, frame_index: int, m: Match | None, reattach: bool, frame_bgr=None,
               long_miss: bool = False) -> None:
        """The chain after this frame's outcome (m, None: missed): the offset measured again at an intra
        frame, followed between them, or broken. `long_miss`: unseen SHORT_MISS frames or more."""
        intra = self.is_intra(frame_index)
        if m is not None and m.luma is not None and intra:
            self.offset = (m.x - m.luma[0], m.y - m.luma[1])
            self.anchor_luma = m.luma
            return
        if not self.model.luma_follows and not intra:
            self._follow_pattern_chain(frame_bgr, m, reattach, long_miss)
            return
        if m is None or m.luma is None or reattach or self.anchor_luma is None or \
                math.hypot(m.luma[0] - self.anchor_luma[0], m.luma[1] - self.anchor_luma[1]) \
                > self.params.luma_carry_max_px:
            self.offset = self.anchor_luma = self.pattern = None  # the chain from the intra frame is broken

    def _follow_pattern_chain(self, frame_bgr, m: Match | None, reattach: bool, long_miss: bool = False) -> None:
        """update between intra frames for a marker with no dark silhouette, followed by its
        brightness pattern (see _carry_pattern)."""
        if m is None:
            if self.pattern is not None and long_miss:
                self.kept = (self.pattern, self.offset, self.anchor_luma)  # (to find it again when lost)
            if self.pattern is None or long_miss:
                self.offset = self.anchor_luma = self.pattern = None  # the chain is broken
            # (else unseen a frame or two: the chain is kept, to find the marker by its pattern:
            # MarkerTrack.pattern_return)
            return
        if reattach and m.luma is not None and self.pattern is not None:
            return  # (found again by its chain's pattern: whole_by_pattern; the chain goes on)
        if reattach:
            self.offset = self.anchor_luma = self.pattern = None
            if m.colour_frac >= self.params.confident_colour:
                self._restart_pattern(frame_bgr, m)  # (the chain restarts where the marker was found again)
            return
        if self.pattern is None:
            self._restart_pattern(frame_bgr, m)
        elif m.luma is not None and math.hypot(m.luma[0] - self.anchor_luma[0], m.luma[1] - self.anchor_luma[1]) \
                > self.params.luma_carry_max_px:
            # (far from where it was cut: the sand, the light differ; no fit this one frame: the marker is
            # still where the chain says)
            self._new_pattern(frame_bgr, m.x, m.y)

    def _restart_pattern(self, frame_bgr, m: Match) -> None:
        """A chain broken between intra frames starts again from a colour match centred on the marker's
        coverage: its brightness pattern there, followed until the next intra frame (the colour's place
        at this frame may be stale, but without the chain it only grows staler)."""
        if frame_bgr is None or self.intra is None or not self.params.luma_carry or not m.used_centroid \
                or not m.colour_frac >= self.params.min_colour:
            return
        self._new_pattern(frame_bgr, m.x, m.y)

    def _new_pattern(self, frame_bgr, x: float, y: float) -> None:
        """Follow the brightness pattern of the marker at (x, y) in this frame from now on (no chain when
        there is none to follow)."""
        pattern = None if frame_bgr is None else LumaPattern(frame_bgr, x, y, self.model.radius)
        if pattern is not None and pattern.ok:
            self.pattern, self.offset, self.anchor_luma = pattern, (0.0, 0.0), (x, y)
        else:
            self.pattern = self.offset = self.anchor_luma = None

    def denies(self, frame_bgr, m: Match, frame_index: int | None) -> bool:
        """A marker with no dark silhouette, unseen a frame or two, whose colour covers less than a whole
        disc where it would be found again: when its brightness pattern (kept from before the miss) is
        not there, part of it is still hidden (a whole one fits its pattern to NCC >= 0.97 at 99 % of
        frames) and its colour's centre is not its own. A whole disc of colour is refused only as stale
        chroma left behind by a fast marker (see _carry_pattern)."""
        if self.model.luma_follows or self.pattern is None or self.offset is None or self.is_intra(frame_index):
            return False
        if m.colour_frac >= self.params.confident_colour:
            if math.hypot(*self.kf.vxy) < STREAK_MIN_SPEED:
                return False
            found = self.pattern.find(frame_bgr, m.x - self.offset[0], m.y - self.offset[1], velocity=self.kf.vxy)
            return found is None and self._colour_left_behind(m)
        return self.pattern.find(frame_bgr, m.x - self.offset[0], m.y - self.offset[1]) is None
