"""The engine's passes for touching lookalikes (a crowd: a dense layer of identical beads).

A collaborator of Engine (engine.py), on its TrackSet, holding what it remembers of the crowd: per step,
after every track proposed its match, the passes here give missed crowd markers back (carried by the
layer's motion and assigned, measured on the other view's epipolar line, a hidden patch registered from
its neighbours, carried by the beads around it), check that the crowd's matches move together with the
image (coherence, flow), keep each crowd track's recent points (crowd tracks seeded in one view each are
paired across the views by pairing.py). The rules of one bead against its neighbours are in crowd.py.
"""

from __future__ import annotations

import math
import statistics

import numpy as np

from . import crowd as crowd_rules
from .detection import detect_like
from .events import AmbiguityLog
from .matcher import Proposal
from .tracker import SHORT_MISS
from .trackset import OnTracks, TrackSet, explained_points

FLOW_AGREE_PX = 1.5  # a crowd marker's match this far from where the image motion took it is not its own
CROWD_MEMORY = 100  # frames of measured positions kept per crowd track (a hidden patch is registered from them)
REGROUP_REACH = 6.0  # radii: how far a hidden patch of the layer is looked for
REGROUP_EVERY = 3  # frames between registrations of one patch
ANCHOR_REACH = 4.0  # radii: the beads around a lost one whose moves carry it (as crowd.carried's reach)


class CrowdPasses(OnTracks):
    """The engine's passes for touching lookalikes, and what they remember between steps."""

    def __init__(self, trackset: TrackSet, log: AmbiguityLog):
        super().__init__(trackset)
        self.log = log
        self._crowd_at: dict = {}  # crowd track key -> (x, y) measured at the last step
        self._crowd_carried: dict = {}  # missed crowd track key -> (x, y) carried by the layer
        self.prev_frames: dict = {}  # camera -> its frame of the previous step (the layer's motion)
        self._crowd_seen: dict = {}  # crowd track key -> {frame: (x, y)} measured lately
        # (camera, patch's markers, its frame) -> (step last tried, unexplained beads then)
        self._regroup_tried: dict = {}
        self.flow_refused: set = set()  # crowd track keys whose match the flow check refused this step

    def passes(self, cam, img, j: int, tracks, props, forced, frames) -> int:
        """The passes that give missed crowd markers back (carried and assigned, measured on the other view's
        line, a hidden patch registered, carried by their neighbours); returns how many of them gave any
        back. (Those the other view pins come first: measured again, they pin a registration as anchors.)"""
        n = int(self._crowd_return(cam, img, j, tracks, props, forced) > 0)
        if self.stereo is not None:
            n += int(self._crowd_outline_on_line(cam, img, tracks, props, forced, frames) > 0)
            n += int(self._crowd_on_line(cam, img, j, tracks, props, forced, frames) > 0)
        n += int(self._crowd_regroup(cam, img, j, tracks, props, forced) > 0)
        n += int(self._crowd_rejoin(cam, img, j, tracks, props, forced) > 0)
        return n

    def _crowd_return(self, cam, img, j: int, tracks, props, forced) -> int:
        """Missed markers among touching lookalikes, carried by the layer's motion (crowd.py: the image
        motion around each, else the median move of its measured neighbours), assigned at once to the
        beads no track explains; returns how many came back. A carried marker stays flagged, at its
        carried position."""
        members = [t for t in tracks if t.model.crowd]
        missed = [t for t in members if (t.marker, cam) not in props and (t.marker, cam) not in forced]
        for t in members:
            t.carried = False
        if not missed:
            return 0
        src, dst = [], []
        for t in members:
            key = (t.marker, cam)
            p, last = props.get(key), self._crowd_at.get(key)
            if p is not None and last is not None and not p.reattach:
                src.append(last)
                dst.append((p.match.x, p.match.y))
        r = max(t.model.radius for t in missed)
        start = np.array([self._crowd_carried.get((t.marker, cam)) or self._crowd_at.get((t.marker, cam)) or t.kf.xy
                          for t in missed], float)
        where = np.full_like(start, np.nan)
        prev = self.prev_frames.get(cam)
        if prev is not None:
            where = crowd_rules.flowed(prev, img, start, r)
        lacking = ~np.isfinite(where[:, 0])
        if lacking.any():
            where[lacking] = crowd_rules.carried(start[lacking], src, dst, 4.0 * r)
        for t, xy in zip(missed, where, strict=True):
            # (NaN: where the layer took it is not known; it is not carried again, from a prediction that may
            # lie on another bead by now, until something measures it: the start above stays NaN)
            self._crowd_carried[(t.marker, cam)] = (float(xy[0]), float(xy[1]))
            if np.isfinite(xy[0]):
                kx, ky = t.kf.xy
                t.kf.translate(xy[0] - kx, xy[1] - ky)
                t.carried = True
        known = np.isfinite(where[:, 0])
        if not known.any():
            return 0
        missed = [t for t, k in zip(missed, known, strict=True) if k]
        where = where[known]
        beads = self._unexplained_beads(cam, img, missed[0].model, where, props, forced)
        pairs, ambiguous = crowd_rules.assign(where, beads, 0.5 * r, 0.5 * r) if len(beads) else ({}, [])
        for i in ambiguous:
            self.log.note(missed[i].marker, cam, j, 2)
        n = self._give_back(cam, img, {missed[i]: beads[b] for i, b in pairs.items()}, props)
        return n + self._crowd_confirm(cam, img, missed, where, props, forced)

    @staticmethod
    def _give_back(cam, img, found: dict, props) -> int:
        """Crowd tracks given back at the beads assigned to them ({track: (x, y)}), each measured there
        (verify_at, else by its outline alone: verify_assigned) within half a radius of its bead; returns
        how many."""
        n = 0
        for t, (x, y) in found.items():
            m = t.verify_at(img, float(x), float(y)) or t.verify_assigned(img, float(x), float(y))
            if m is not None and math.hypot(m.x - x, m.y - y) <= 0.5 * t.model.radius:
                m.assigned = True  # (who it is comes from where it went: its template is cut again there)
                props[(t.marker, cam)] = Proposal(m, reattach=True)
                n += 1
        return n

    def _crowd_regroup(self, cam, img, j: int, tracks, props, forced) -> int:
        """Crowd markers unseen for more than SHORT_MISS frames (a patch of the layer hidden under the
        tool and carried on meanwhile, where nothing measured its motion), found again together: their
        positions at the latest frame that measured most of them, split into patches of touching beads,
        each registered onto the beads no track explains (crowd.register: one affine map, accepted only
        with a clear margin over any other pairing, the beads measured around the patch fitted with it,
        and only when it puts each of those within a radius of where it is; each bead then placed by the
        map of the pairs and anchors nearest it), then assigned one by one with the margins of
        crowd.assign; returns how many came back."""
        strays = [t for t in tracks if t.model.crowd and t.misses > SHORT_MISS
                  and (t.marker, cam) not in props and (t.marker, cam) not in forced]
        if len(strays) < crowd_rules.MIN_GROUP:
            return 0
        counts: dict = {}
        for t in strays:
            for f in self._crowd_seen.get((t.marker, cam), ()):
                counts[f] = counts.get(f, 0) + 1
        if not counts:
            return 0
        most = max(counts.values())
        if most < crowd_rules.MIN_GROUP:
            return 0
        f0 = max(f for f, c in counts.items() if c == most) if self.direction > 0 else \
            min(f for f, c in counts.items() if c == most)
        group = [t for t in strays if f0 in self._crowd_seen.get((t.marker, cam), ())]
        old = np.array([self._crowd_seen[(t.marker, cam)][f0] for t in group], float)
        r = max(t.model.radius for t in group)
        reach = REGROUP_REACH * r
        # (a missed marker carried by the layer still explains the bead where it was carried)
        carried = [(t.marker, cam) for t in tracks if t.model.crowd and t.carried and t not in group]
        explained = {**forced, **{k: self._crowd_carried[k] for k in carried if k in self._crowd_carried}}
        n = 0
        for patch in _patches(old, 1.5 * 2.0 * r):
            if len(patch) < crowd_rules.MIN_GROUP:
                continue
            # (a patch registered in vain is tried again once more of it shows, or every REGROUP_EVERY frames)
            who = (cam, tuple(group[i].marker for i in patch), f0)
            last, shown = self._regroup_tried.get(who, (j - REGROUP_EVERY, 0))
            beads = self._unexplained_beads(cam, img, group[patch[0]].model, old[patch], props, explained,
                                            pad=reach + r)
            if not len(beads) or (len(beads) <= shown and abs(j - last) < REGROUP_EVERY):
                continue
            self._regroup_tried[who] = (j, len(beads))
            # (the beads measured around the patch were carried with it: a map that misplaces one of them by
            # more than a radius, half the pitch of the packing, is nearer the patch shifted by a bead, onto
            # lookalikes no track follows, than the patch where it is)
            anchors = self._anchors_at(cam, f0, old[patch], ANCHOR_REACH * r, props, forced)
            at, agreed = crowd_rules.register(old[patch], beads, r, reach, anchors=anchors)
            if at is None:
                at, agreed = self._register_pinned(cam, [group[i] for i in patch], beads, len(anchors[0]), props,
                                                   forced)
            if at is None:
                continue
            pairs, ambiguous = crowd_rules.assign(at, beads, 0.5 * r, 0.5 * r)
            for i in ambiguous:
                self.log.note(group[patch[i]].marker, cam, j, 2)
            n += self._give_back(cam, img, {group[patch[i]]: beads[b] for i, b in pairs.items()
                                            if agreed.get(i) == b}, props)
        return n

    def _register_pinned(self, cam, patch: list, beads: np.ndarray, pinned_by: int, props, forced) -> tuple:
        """A hidden patch's registration (crowd.register) from the frame that measured, with all of the patch,
        the most beads around it still measured now (anchors: a map shifted by a bead misplaces each of them),
        when that is more than the `pinned_by` anchors of the frame tried first; (None, {}) otherwise."""
        seen = [self._crowd_seen.get((t.marker, cam), {}) for t in patch]
        frames = sorted(set(seen[0]).intersection(*seen[1:]), reverse=self.direction > 0)
        r = max(t.model.radius for t in patch)
        best = None
        for f in frames:
            old = np.array([s[f] for s in seen], float)
            anchors = self._anchors_at(cam, f, old, ANCHOR_REACH * r, props, forced)
            if len(anchors[0]) > pinned_by and (best is None or len(anchors[0]) > len(best[1][0])):
                best = (old, anchors)
        if best is None:
            return None, {}
        return crowd_rules.register(best[0], beads, r, REGROUP_REACH * r, anchors=best[1])

    def _crowd_rejoin(self, cam, img, j: int, tracks, props, forced) -> int:
        """Crowd markers unseen for more than SHORT_MISS frames, or missed and carried by no motion (where
        the layer took them is not known), whose neighbours are measured again (given back by a
        registration, or never lost): each is carried from the last frame it was measured
        together with at least crowd.MIN_ANCHORS of the beads around it (within ANCHOR_REACH radii) by
        the affine map of those beads' moves since (crowd.moved_with), then all are assigned at once to
        the beads no track explains, with crowd.assign's margins; returns how many came back."""
        strays = [t for t in tracks if t.model.crowd and (t.misses > SHORT_MISS or (t.misses and not t.carried))
                  and (t.marker, cam) not in props and (t.marker, cam) not in forced]
        if not strays:
            return 0
        now = {k: (p.match.x, p.match.y) for k, p in props.items() if k[1] == cam}
        now.update({k: xy for k, xy in forced.items() if k[1] == cam})
        anchors = [(self._crowd_seen[k], xy) for k, xy in now.items()
                   if self.tracks[k].model.crowd and k in self._crowd_seen]
        placed, where = [], []
        for t in strays:
            xy = self._carried_by_neighbours(self._crowd_seen.get((t.marker, cam), {}), anchors, t.model.radius)
            if xy is not None:
                placed.append(t)
                where.append(xy)
        if not placed:
            return 0
        where = np.array(where, float)
        r = max(t.model.radius for t in placed)
        carried = [(t.marker, cam) for t in tracks if t.model.crowd and t.carried and t not in strays]
        explained = {**forced, **{k: self._crowd_carried[k] for k in carried if k in self._crowd_carried}}
        beads = self._unexplained_beads(cam, img, placed[0].model, where, props, explained)
        pairs, ambiguous = crowd_rules.assign(where, beads, 0.5 * r, 0.5 * r) if len(beads) else ({}, [])
        for i in ambiguous:
            self.log.note(placed[i].marker, cam, j, 2)
        n = self._give_back(cam, img, {placed[i]: beads[b] for i, b in pairs.items()}, props)
        return n + self._confirm_placed(cam, img, placed, where, beads, set(ambiguous), props, forced)

    def _confirm_placed(self, cam, img, placed, where, beads, ambiguous: set, props, forced) -> int:
        """Lost crowd markers placed by their neighbours' map (_crowd_rejoin) that no detected bead gave
        back (in a pressed layer a bead's outline is not seen all round, so it is not detected), measured
        where they were placed by their highlight (MarkerTrack.confirm_carried), unless another bead could
        be the one there: an unexplained detected bead, another placed marker or a marker measured this
        step within a radius of the place."""
        n = 0
        for i, t in enumerate(placed):
            if (t.marker, cam) in props or i in ambiguous:
                continue
            x, y = where[i]
            r = t.model.radius
            others = np.delete(where, i, axis=0)
            if (len(beads) and np.hypot(beads[:, 0] - x, beads[:, 1] - y).min() <= r) or \
                    (len(others) and np.hypot(others[:, 0] - x, others[:, 1] - y).min() <= r):
                continue
            m = t.confirm_carried(img, float(x), float(y))
            if m is None or any(math.hypot(m.x - a, m.y - b) < r for a, b in explained_points(cam, props, forced)):
                continue
            props[(t.marker, cam)] = Proposal(m, reattach=True)
            n += 1
        return n

    def _crowd_on_line(self, cam, img, j: int, tracks, props, forced, frames) -> int:
        """Crowd markers unseen for more than SHORT_MISS frames that the other view measures this step (the
        same marker, or its paired track: pairing.py): the bead no track explains lying on the other
        view's epipolar band within `reach` of where the marker was last (its radius, plus how far the
        other view saw it move since both last measured it, in this view's scale, but never more than its
        radius), with no other such bead within a bead's width more along the band, is given back. (A bead
        farther along the band than a radius leaves room for another nearer, half hidden or pressed among
        its neighbours so that it is not detected, which may be the marker: on the dense twin every bead
        given back from farther, 11-15 px, was another.) Returns how many came back."""
        n = 0
        for t in tracks:
            key = (t.marker, cam)
            if not t.model.crowd or t.misses <= SHORT_MISS or key in props or key in forced:
                continue
            other, band_from = self._line_from_other_view(key, frames, props, forced)
            if band_from is None:
                continue
            reach = self._line_reach(key, other, band_from)
            if reach is None:
                continue
            r = t.model.radius
            reach = min(reach, r)
            px, py = self.stereo.onto_line(other[1], band_from, cam, t.kf.xy)
            beads = self._unexplained_beads(cam, img, t.model, np.array([[px, py]]), props, forced,
                                            pad=reach + 2 * r + 4)
            if not len(beads):
                continue
            on = self.stereo.distance(other[1], band_from, cam, beads) <= self.stereo.band_px
            d = np.hypot(beads[:, 0] - px, beads[:, 1] - py)
            inside = on & (d <= reach)
            rivals = on & (d <= reach + 2 * r)
            if inside.sum() != 1 or rivals.sum() != 1:
                if rivals.sum() > 1 and inside.any():
                    self.log.note(t.marker, cam, j, int(rivals.sum()))
                continue
            bead = beads[int(np.argmax(inside))]
            n += self._give_back(cam, img, {t: bead}, props)
        return n

    def _line_from_other_view(self, key, frames, props, forced) -> tuple:
        """(the other view's key, its point this step) for a crowd track whose bead the other view sees
        (the same marker's, or its paired track's point: the epipolar line's source); (None, None)."""
        other = self.trackset.other_view(key)
        if other is None or other[1] not in frames:
            return None, None
        return other, self.trackset.point_at(other, frames, props, forced)

    def _line_reach(self, key, other, other_now) -> float | None:
        """How far (px) a crowd marker unseen a while may be from where it was last measured: its radius,
        plus how far the other view's track moved since the last frame both were measured, scaled by
        the ratio of the two views' radii; None when no frame measured both."""
        seen, seen_other = self._crowd_seen.get(key, {}), self._crowd_seen.get(other, {})
        both = [f for f in seen if f in seen_other]
        if not both:
            return None
        f = max(both) if self.direction > 0 else min(both)
        ox, oy = seen_other[f]
        r, r_other = self.tracks[key].model.radius, self.tracks[other].model.radius
        return r + math.hypot(other_now[0] - ox, other_now[1] - oy) * r / r_other

    def _anchors_at(self, cam, f0: int, near: np.ndarray, reach: float, props, forced) -> tuple:
        """The crowd tracks of `cam` measured this step that were measured at frame f0 within `reach` px
        of one of the points `near` (their positions then): (positions then (k, 2), positions now)."""
        then, now = [], []
        for key, xy in [(k, (p.match.x, p.match.y)) for k, p in props.items() if k[1] == cam] + \
                [(k, xy) for k, xy in forced.items() if k[1] == cam]:
            seen = self._crowd_seen.get(key, {}).get(f0)
            if seen is None or not self.tracks[key].model.crowd:
                continue
            if np.hypot(near[:, 0] - seen[0], near[:, 1] - seen[1]).min() <= reach:
                then.append(seen)
                now.append(xy)
        return np.array(then, float).reshape(-1, 2), np.array(now, float).reshape(-1, 2)

    def _carried_by_neighbours(self, seen: dict, anchors: list, radius: float) -> tuple | None:
        """Where a lost crowd bead is now (crowd.moved_with), from the latest frame of `seen` ({frame:
        (x, y)} it was measured) at which at least crowd.MIN_ANCHORS of `anchors` ([(their seen, their
        position now)]) not all on a line were measured within ANCHOR_REACH radii of it; None when the
        beads around it did not move as one (an anchor farther from where the map puts it than the
        assignment's gate, half a radius)."""
        frames = sorted(seen, reverse=self.direction > 0)
        for f in frames:
            x, y = seen[f]
            near = [(a_seen[f], a_now) for a_seen, a_now in anchors if f in a_seen
                    and math.hypot(a_seen[f][0] - x, a_seen[f][1] - y) <= ANCHOR_REACH * radius]
            if len(near) < crowd_rules.MIN_ANCHORS:
                continue
            out = crowd_rules.moved_with((x, y), [a for a, _ in near], [b for _, b in near], 0.5 * radius)
            if out is None:
                continue  # (those anchors do not fix the map: on a line)
            if out[1] > 0.5 * radius:
                return None
            return float(out[0][0]), float(out[0][1])
        return None

    def _crowd_outline_on_line(self, cam, img, tracks, props, forced, frames) -> int:
        """Crowd markers carried by the layer's motion this step (_crowd_return) that nothing gave back and
        that the other view measures (the same marker, or its paired track): the other view's epipolar line
        pins the marker across it, the carried place along it. Where the marker's own outline, of its radius,
        is found all round it within half a radius of the foot of its carried place on that line
        (MarkerTrack.confirm_on_line; a bead half hidden behind its neighbours in a slanted view shows
        neither its template nor its highlight, but its outline against the sand), lying on that line as
        closely as the stereo check asks, and no other marker of this camera measured on that outline (within
        half a radius: in a slanted view a bead half behind another lies nearer than a radius to it), it is
        measured there. Returns how many came back."""
        n = 0
        for t in tracks:
            key = (t.marker, cam)
            carried = self._crowd_carried.get(key)
            if not t.model.crowd or not t.carried or key in props or key in forced or carried is None:
                continue
            other, band_from = self._line_from_other_view(key, frames, props, forced)
            if band_from is None:
                continue
            foot = self.stereo.onto_line(other[1], band_from, cam, carried)
            m = t.confirm_on_line(img, *foot)
            if m is None or self.stereo.distance(other[1], band_from, cam, (m.x, m.y))[0] > self.stereo.threshold_px \
                    or math.hypot(m.x - carried[0], m.y - carried[1]) > 0.5 * t.model.radius \
                    or any(math.hypot(m.x - a, m.y - b) <= 0.5 * t.model.radius
                           for a, b in explained_points(cam, props, forced)):
                continue
            props[key] = Proposal(m, reattach=True)
            n += 1
        return n

    def _crowd_confirm(self, cam, img, missed, where, props, forced) -> int:
        """Carried crowd markers no detected bead gave back, measured where they were carried
        (MarkerTrack.confirm_carried), unless another marker of this camera is measured within a radius
        of there; returns how many came back."""
        taken = explained_points(cam, props, forced)
        n = 0
        for t, (x, y) in zip(missed, where, strict=True):
            if (t.marker, cam) in props or not t.carried:
                continue
            m = t.confirm_carried(img, float(x), float(y))
            if m is None or any(math.hypot(m.x - a, m.y - b) <= 0.5 * t.model.radius for a, b in taken):
                continue
            props[(t.marker, cam)] = Proposal(m, reattach=True)
            taken.append((m.x, m.y))
            n += 1
        return n

    def _unexplained_beads(self, cam, img, model, near: np.ndarray, props, forced, pad: float | None = None
                           ) -> np.ndarray:
        """Beads like `model` (detection.py) within about `pad` px (default 3 radii) of the points `near`
        that no match of this camera explains: (n, 2) px."""
        r = model.radius
        H, W = img.shape[:2]
        pad = 3.0 * r + 4 if pad is None else pad
        x0, y0 = max(int(near[:, 0].min() - pad), 0), max(int(near[:, 1].min() - pad), 0)
        x1, y1 = min(int(near[:, 0].max() + pad) + 1, W), min(int(near[:, 1].max() + pad) + 1, H)
        if x1 - x0 < 3 or y1 - y0 < 3:
            return np.empty((0, 2))
        det = detect_like(np.ascontiguousarray(img[y0:y1, x0:x1]), model)
        if det.empty:
            return np.empty((0, 2))
        beads = det[["x_px", "y_px"]].to_numpy(float) + (x0, y0)
        explained = explained_points(cam, props, forced)
        if explained:
            e = np.array(explained, float)
            d = np.hypot(beads[:, None, 0] - e[None, :, 0], beads[:, None, 1] - e[None, :, 1])
            beads = beads[d.min(axis=1) > r]
        return beads

    def remember(self, key, frame: int, xy) -> None:
        """A crowd track's position this step, measured or placed (its neighbours' next moves start
        here, and a hidden patch of the layer is registered from where its beads were together); None:
        missed."""
        if xy is not None:
            self._crowd_at[key] = xy
            self._crowd_carried.pop(key, None)
            seen = self._crowd_seen.setdefault(key, {})
            seen[frame] = xy
            if len(seen) > CROWD_MEMORY:
                del seen[next(iter(seen))]
        else:
            self._crowd_at.pop(key, None)

    def coherence(self, tracks, props, crowd: dict) -> None:
        """Markers among touching lookalikes (a dense layer) are carried by the sand together: a
        marker's match must have moved from its prediction as its touching neighbours' matches did
        (within half a radius of their median); one that did not has taken a neighbour or a gap,
        and coasts instead (flagged). With fewer than two neighbours matched, it may have moved half a
        radius from its prediction at most."""
        drop = []
        for t in tracks:
            p = props.get((t.marker, t.camera))
            if p is None or not t.model.crowd:
                continue
            moves = []
            for o, q in crowd.get(id(t), ()):
                po = props.get((o.marker, o.camera))
                if po is not None:
                    moves.append((po.match.x - q[0], po.match.y - q[1]))
            px, py = t.kf.xy
            if len(moves) < 2:  # (no neighbours to vouch for a move: at most half a bead off its prediction)
                if math.hypot(p.match.x - px, p.match.y - py) > 0.5 * t.model.radius:
                    drop.append((t.marker, t.camera))
                continue
            mx, my = statistics.median(m[0] for m in moves), statistics.median(m[1] for m in moves)
            if math.hypot(p.match.x - px - mx, p.match.y - py - my) > 0.5 * t.model.radius:
                drop.append((t.marker, t.camera))
        for key in drop:
            del props[key]

    def flow_check(self, cam, img, tracks, props) -> None:
        """A crowd marker's new match must lie where the image motion around it since the last step
        took it (crowd.flowed, from where it was measured then), within FLOW_AGREE_PX: one that does not
        has jumped to a neighbour's outline or a gap, and coasts instead (flagged). Where the motion is
        not clear the match stands."""
        prev = self.prev_frames.get(cam)
        self.flow_refused = {k for k in self.flow_refused if k[1] != cam}
        if prev is None:
            return
        keys, start, found = [], [], []
        for t in tracks:
            key = (t.marker, cam)
            p, last = props.get(key), self._crowd_at.get(key)
            if p is None or last is None or not t.model.crowd or p.match.rest:
                continue
            keys.append(key)
            start.append(last)
            found.append((p.match.x, p.match.y))
        if not keys:
            return
        r = max(self.tracks[k].model.radius for k in keys)
        where = crowd_rules.flowed(prev, img, np.array(start), r)
        off = np.hypot(*(where - np.array(found)).T)
        for key, d in zip(keys, off, strict=True):
            if d > FLOW_AGREE_PX:  # (NaN: the motion is not clear, the match stands)
                del props[key]
                self.flow_refused.add(key)


def _patches(points: np.ndarray, link: float) -> list[list[int]]:
    """Indices of `points` (n, 2) in groups linked by distances of at most `link` (single linkage)."""
    n = len(points)
    d = np.hypot(points[:, None, 0] - points[None, :, 0], points[:, None, 1] - points[None, :, 1])
    label = list(range(n))
    for i in range(n):
        for k in np.nonzero(d[i] <= link)[0]:
            a, b = label[i], label[int(k)]
            if a != b:
                label = [a if x == b else x for x in label]
    groups: dict = {}
    for i, g in enumerate(label):
        groups.setdefault(g, []).append(i)
    return list(groups.values())
