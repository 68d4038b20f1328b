"""The engine's searches along the other view's epipolar line, and by a marker's look.

A collaborator of Engine (engine.py), on its TrackSet. When the other view of a marker is measured,
its point there draws a line in this view on which the marker must lie: a coasting track is searched
on that line (its template, its placed look, the blobs of its band) after re-acquisition gave back
others (late_lines).
A brightness model's marker that nothing measured is placed by its look (the luma pattern at its last
whole measurement) where it shows whole, in both views only where they agree (looks).
"""

from __future__ import annotations

import math

import numpy as np

from .appearance import BRIGHT, DARK
from .matcher import Match, Proposal
from .reacquire import find_blobs, search_windows
from .tracker import LOST, MERGED_COVERAGE, MarkerTrack
from .trackset import OnTracks, TrackSet, explained_points


def _on_explained(m: Match, model, explained: list) -> bool:
    """m lies on a marker this camera already explains."""
    return any(math.hypot(m.x - a, m.y - b) < 1.5 * model.radius + 1 for a, b in explained)


def measurable_on_line(model) -> bool:
    """A marker LineSearch.on_line may measure: of a brightness model (its coverage follows the light on its
    body, its template does not), not among touching lookalikes (a crowd's line crosses several)."""
    return model.kind in (DARK, BRIGHT) and not model.crowd


class LineSearch(OnTracks):
    """The engine's searches on the other view's line and by a marker's look, over its tracks."""

    def __init__(self, trackset: TrackSet):
        super().__init__(trackset)
        # camera -> (windows re-acquisition searched this step: track key -> (x, y, hx, hy), keys it measured on
        # the other view's line)
        self.searched: dict = {}

    def late_lines(self, cam, img, tracks, props, forced, frames) -> int:
        """Reacquisition.run's measurement on the other view's line (on_line, on_band) for the coasting tracks of
        `cam` whose other view was given its point back by a re-acquisition after `cam` was searched this
        step; returns how many were measured."""
        windows, lined = self.searched.get(cam, ({}, set()))
        n = 0
        for t in tracks:
            key = (t.marker, cam)
            if key in props or key in forced or key in lined or not measurable_on_line(t.model):
                continue
            band_from = self.trackset.point_at((t.marker, self.stereo.other(cam)), frames, props, forced)
            if band_from is None:
                continue
            explained = explained_points(cam, props, forced)
            reach = min(max(*t.search_halfsize(), 4 * t.model.radius + 10), t.params.max_search_px)
            m = self.on_line(cam, img, t, band_from, explained) or self.on_band(cam, img, t, band_from, explained,
                                                                                 reach)
            if m is not None and not self.nearer_searcher(key, m, windows, props):
                props[key] = Proposal(m, reattach=True)
                n += 1
        return n

    def nearer_searcher(self, key, m: Match, windows: dict, props) -> bool:
        """Another track of this camera still searching holds m in its window, its prediction nearer m
        than this track's: the marker there may be that one (which did not see it), as in BlobAssigner.assign."""
        ox, oy = self.trackset.tracks[key].kf.xy
        own = math.hypot(m.x - ox, m.y - oy)
        return any(k != key and k not in props and abs(m.x - wx) <= hx and abs(m.y - wy) <= hy
                   and math.hypot(m.x - wx, m.y - wy) < own for k, (wx, wy, hx, hy) in windows.items())

    def on_line(self, cam, img, t: MarkerTrack, band_from, explained: list, at=None) -> Match | None:
        """A coasting marker of a brightness model that the other view measures this step: its template
        found near its prediction, on the other view's epipolar line as closely as a marker measured in
        both views lies (StereoCheck.agree_px), is the marker there, moved onto the line (the line
        pins it across, the template along). Its coverage is not asked: a brightness model's coverage
        follows the light on the marker's body (a glass bead's body turns pale where the lamp's light is
        focused through it) while its template still finds it. Where the template does not place it on
        the line, its look at its last whole measurement may (_look_on_line). None otherwise, or when
        the match lies on a marker this camera already explains. `at`: the blob re-acquisition gave the
        track (its match failed there), searched instead of the prediction."""
        model = t.model
        if not measurable_on_line(model):
            return None
        other = self.stereo.other(cam)
        x, y = self.stereo.onto_line(other, band_from, cam, t.kf.xy if at is None else at)
        half = min(max(t.search_halfsize()), 2 * model.radius + 4) if at is None else 2.0
        m = t.matcher.match(img, x, y, half, half)
        if not self._template_on_line(t, img, m, other, band_from):
            m = self._look_on_line(t, img, (x, y) if m is None else (m.x, m.y), other, band_from)
        return None if m is None else self._placed_on_line(t, img, m, other, band_from, explained)

    def _template_on_line(self, t: MarkerTrack, img, m: Match | None, other, band_from) -> bool:
        """The template's match m is as on_line takes it: its score and PSR as a tracked marker's, not
        merged with another dark thing, on the other view's line."""
        p = t.params
        # (more than MERGED_COVERAGE discs of the marker's brightness there: merged with another dark thing)
        return not (m is None or m.score < p.min_score or not m.psr >= p.min_psr or m.colour_frac > MERGED_COVERAGE
                    or t.cut_by_border(img, m)
                    or self.stereo.distance(other, band_from, t.camera, (m.x, m.y))[0] > self.stereo.agree_px)

    def _placed_on_line(self, t: MarkerTrack, img, m: Match, other, band_from, explained: list) -> Match | None:
        """m, a whole marker (MarkerTrack.shows_whole) this camera does not explain yet, moved onto the other view's
        line; else None."""
        if not t.shows_whole(img, m.x, m.y) or _on_explained(m, t.model, explained):
            return None
        m.x, m.y = self.stereo.onto_line(other, band_from, t.camera, (m.x, m.y))
        m.used_centroid = False  # (along the line its place is the template's peak: a looser measurement)
        m.line = not m.look
        m.d2 = t.kf.d2(m.x, m.y)
        return m

    def on_band(self, cam, img, t: MarkerTrack, band_from, explained: list, reach: float) -> Match | None:
        """on_line for a marker unseen a while, whose prediction may lie far from it: its template
        searched in windows along the other view's epipolar line, out to `reach` px from the prediction's
        foot on it, taken only where it is found at one place along the line that this camera does not
        explain (another marker like it there, unseen too, could be either)."""
        if not measurable_on_line(t.model):
            return None
        other = self.stereo.other(cam)
        half = 2 * t.model.radius + 4
        x0, y0, dx, dy = self.stereo.along_line(other, band_from, cam, t.kf.xy)
        found: list = []
        n = int(reach // (2 * half))
        for step in 2 * half * np.arange(-n, n + 1):
            m = t.matcher.match(img, x0 + step * dx, y0 + step * dy, half, half)
            if self._template_on_line(t, img, m, other, band_from) and not _on_explained(m, t.model, explained) \
                    and not any(math.hypot(m.x - o.x, m.y - o.y) < t.model.radius for o in found):
                found.append(m)
        if len(found) != 1:
            return None
        return self._placed_on_line(t, img, found[0], other, band_from, explained)

    def looks(self, frames, live: dict, props, forced) -> None:
        """Brightness-model markers still followed (not lost) that nothing measured this step: where a
        marker's look at its last whole measurement (MarkerTrack.look_place) registers near its prediction
        and the marker shows itself whole (MarkerTrack.shows_whole), it is there (a marker pushed by the
        tool, whose look changes as it moves over the sand, is found by no match; a marker partly hidden
        shows no outline all round). With a second view: not where that view measures the marker
        (its line was asked, on_line); where that view's look places it too, only when the two places lie
        on each other's epipolar lines as closely as a marker measured in both views does
        (StereoCheck.agree_px; a look slides to the part of a marker in sight, which the two views do not
        see alike)."""
        found = {}
        for cam, (_j, img, _rem) in frames.items():
            for t in live.get(cam, ()):
                key = (t.marker, cam)
                if key not in props and key not in forced and t.status != LOST and measurable_on_line(t.model):
                    m = self._look_alone(t, img, props, forced)
                    if m is not None:
                        found[key] = m
        taken = []
        for (mk, cam), m in found.items():
            if self.stereo is not None and cam in self.stereo.cams:
                other = (mk, self.stereo.other(cam))
                if other in props or other in forced:
                    continue
                o = found.get(other)
                if o is not None and self.stereo.distance(cam, (m.x, m.y), other[1], (o.x, o.y))[0] \
                        > self.stereo.agree_px:
                    continue
            taken.append(((mk, cam), m))
        for key, m in taken:
            props[key] = Proposal(m, reattach=True)

    def _look_alone(self, t: MarkerTrack, img, props, forced) -> Match | None:
        """looks' match of track t in its camera's image, or None."""
        placed = t.look_place(img, *t.kf.xy)
        if placed is None:
            return None
        m = Match(*placed, t.look_fit, float("nan"), float("nan"), t.kf.d2(*placed), look=True)
        if m.d2 > t.params.gate_d2 or t.cut_by_border(img, m) or not t.shows_whole(img, m.x, m.y) \
                or _on_explained(m, t.model, explained_points(t.camera, props, forced)):
            return None
        return m

    def _look_on_line(self, t: MarkerTrack, img, start: tuple, other, band_from) -> Match | None:
        """on_line where the template does not place the marker on the line: its look at its last whole
        measurement (MarkerTrack.look_place), registered from `start`, placing it on the line as closely
        as a marker measured in both views lies; None otherwise."""
        placed = t.look_place(img, *start)
        if placed is None or self.stereo.distance(other, band_from, t.camera, placed)[0] > self.stereo.agree_px:
            return None
        m = Match(*placed, t.look_fit, float("nan"), float("nan"), look=True)
        return None if t.cut_by_border(img, m) else m

    def band_blobs(self, cam, img, model, band_from, px, py, inner: float, reach: float) -> list:
        """Blobs along the other view's epipolar band through `band_from`, out to `reach` px from
        (px, py), outside the window of half-size `inner` searched already: small tiles along the
        line (a brightness model reads its sand level per tile, as in any search window)."""
        h = 2 * model.radius + 8
        n = int(math.ceil(reach / (2 * h)))
        offs = np.arange(-n, n + 1) * 2 * h
        cx, cy = np.meshgrid(px + offs, py + offs)
        cx, cy = cx.ravel(), cy.ravel()
        outside = (np.abs(cx - px) + h > inner) | (np.abs(cy - py) + h > inner)
        H, W = img.shape[:2]
        inside = (cx + h >= 0) & (cy + h >= 0) & (cx - h < W) & (cy - h < H)
        cx, cy = cx[outside & inside], cy[outside & inside]
        if not len(cx):
            return []
        d = self.stereo.distance(self.stereo.other(cam), band_from, cam, np.c_[cx, cy])
        near = d <= h * math.sqrt(2) + self.stereo.band_px
        cx, cy = cx[near], cy[near]
        # Most tiles hold nothing of the marker's colour: told in one call, only the others are searched.
        out = []
        for i in np.flatnonzero(model.any_in(img, search_windows(img.shape, model, cx, cy, h, h))).tolist():
            out += [b for b in find_blobs(img, model, float(cx[i]), float(cy[i]), h, h)
                    if abs(b.x - px) > inner or abs(b.y - py) > inner]
        return out
