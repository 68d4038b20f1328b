"""All markers in all cameras, one time step at a time.

Per step: every track predicts and proposes its best gated match; two tracks of one camera
claiming the same marker keep only the better; with a calibration, the proposals of a marker in
the two cameras are checked against each other's epipolar lines (the suspect view is dropped and
flagged); coasting tracks look for unexplained blobs (along the epipolar band when the other view
is tracked; a brightness model's marker also by its template or its look on the other view's line);
a brightness model's marker still followed that nothing measured is placed by its look where it shows
whole (in both views only where they agree); then every track commits its status for the frame.
Touching lookalikes (a crowd, crowd.py) seeded in one view each are paired across the views once their
points tell who is who (_pair_crowd), and then checked and searched like one marker's two views (the run
makes each pair one marker at its end: run._merge_pairs). When most tracks of a camera leave their gates
at once and the whole view moved (globalmotion.py), every track of that camera is moved with the view and
searched again.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field

import numpy as np

from . import crowd as crowd_rules
from .appearance import BRIGHT, DARK
from .detection import detect_like
from .globalmotion import image_shift
from .matcher import Match
from .reacquire import find_blobs, search_windows, unexplained
from .stereo import StereoCheck
from .tracker import LOST, MERGED_COVERAGE, SHORT_MISS, TRACKED, MarkerTrack, Observation

FLOW_AGREE_PX = 1.5  # a crowd marker's match this far from where the image motion took it is not its own
JUMP_FRAMES = 2  # frames after a miss during which a track is searched a largest move per frame unseen
CROWD_MEMORY = 100  # frames of measured positions kept per crowd track (a hidden patch is registered from them)
REGROUP_REACH = 6.0  # radii: how far a hidden patch of the layer is looked for
REGROUP_EVERY = 3  # frames between registrations of one patch
# Two crowd tracks, one per view, are one bead when the other view's line through one never missed the
# other over PAIR_MIN_FRAMES frames measured together, while every other track of that view left it at
# PAIR_BREAKS frames or more (more than a wrong measurement or two: a bead beside the line, not on it).
PAIR_MIN_FRAMES = 10
PAIR_BREAKS = 3
ANCHOR_REACH = 4.0  # radii: the beads around a lost one whose moves carry it (as crowd.carried's reach)


def _on_explained(m: Match, model, explained: list) -> bool:
    """m lies on a marker this camera already explains."""
    return any(math.hypot(m.x - a, m.y - b) < 1.5 * model.radius + 1 for a, b in explained)


def _measurable_on_line(model) -> bool:
    """A marker Engine._on_line may measure: of a brightness model (its coverage follows the light on its
    body, its template does not), not among touching lookalikes (a crowd's line crosses several)."""
    return model.kind in (DARK, BRIGHT) and not model.crowd


@dataclass
class _Proposal:
    match: Match
    reattach: bool = False
    jump: bool = False  # re-attached beyond the gate: the marker's velocity starts from that move


@dataclass
class Engine:
    stereo: StereoCheck | None = None
    direction: int = 1  # +1 forward, -1 backward
    tracks: dict = field(default_factory=dict)  # (marker, camera) -> MarkerTrack
    start: dict = field(default_factory=dict)  # (marker, camera) -> seed frame
    stereo_flags: list = field(default_factory=list)
    ambiguous: list = field(default_factory=list)
    max_events: int = 500
    ambiguity_d2: float = 6.0
    crowd_factor: float = 1.4  # tracks closer than this x (r1 + r2) are "touching"
    crowded_min_score: float = 0.8
    crowded_max_colour: float = 1.4
    follow_view: bool = True  # estimate the view's motion when most tracks of a camera lose their gates
    view_shifts: list = field(default_factory=list)  # (camera, frame, dx, dy) applied
    _prev: dict = field(default_factory=dict)  # camera -> its frame of the previous step
    _open_ambiguity: dict = field(default_factory=dict)
    _both_cache: tuple | None = None
    _by_camera: dict | None = None  # camera -> [(key, track, start frame)], in the order of `tracks`
    _crowd_cams: set = field(default_factory=set)  # cameras with a crowd track (kept with _by_camera)
    _crowd_at: dict = field(default_factory=dict)  # crowd track key -> (x, y) measured at the last step
    _crowd_carried: dict = field(default_factory=dict)  # missed crowd track key -> (x, y) carried by the layer
    _crowd_prev: dict = field(default_factory=dict)  # camera -> its frame of the previous step (the layer's motion)
    _crowd_seen: dict = field(default_factory=dict)  # crowd track key -> {frame: (x, y)} measured lately
    # (camera, patch's markers, its frame) -> (step last tried, unexplained beads then)
    _regroup_tried: dict = field(default_factory=dict)
    # Crowd tracks seeded in one view each, paired across the views by their points (_pair_crowd):
    partners: dict = field(default_factory=dict)  # crowd track key -> the key of the same bead in the other view
    # each pair as it was made: (key in the stereo pair's first camera, key in the second, frames measured on
    # each other's lines then, frame of the first camera at which it was made)
    pairings: list = field(default_factory=list)
    # key in one camera -> {key in the other: [frames both measured, frames off each other's lines]} (both ways)
    _lines: dict = field(default_factory=dict)
    _searched: dict = field(default_factory=dict)  # camera -> (windows searched, keys measured on a line) this step

    def add(self, track: MarkerTrack, start_frame: int) -> None:
        self.tracks[(track.marker, track.camera)] = track
        self.start[(track.marker, track.camera)] = start_frame
        self._by_camera = None

    def _tracks_of(self, cam: str) -> list:
        if self._by_camera is None:
            groups: dict = {}
            for key, t in self.tracks.items():
                groups.setdefault(t.camera, []).append((key, t, self.start[key]))
            self._by_camera = groups
            self._crowd_cams = {t.camera for t in self.tracks.values() if t.model.crowd}
        return self._by_camera.get(cam, [])

    def _has_crowd(self, cam: str) -> bool:
        """Any track of `cam` among touching lookalikes (the crowd passes have nothing to do otherwise)."""
        return cam in self._crowd_cams

    def step(self, frames: dict, manual: dict | None = None) -> list[Observation]:
        """frames: camera -> (frame index, BGR image, remainder in frames of the wanted time);
        manual: (marker, camera, frame) -> (x, y) operator points to trust along the way."""
        manual = manual or {}
        obs: list[Observation] = []
        live: dict[str, list[MarkerTrack]] = {}
        props: dict[tuple, _Proposal] = {}
        forced: dict[tuple, tuple] = {}
        for cam, (j, img, _rem) in frames.items():
            live[cam] = lv = []
            for key, t, s in self._tracks_of(cam):
                if j == s and t.frame_index == s and t.counts["manual"] == 0:
                    obs.append(t.seed_observation())
                    continue
                if self.direction * (j - s) <= 0:
                    continue
                t.predict()
                if manual:
                    man = manual.get((t.marker, cam, j))
                    if man is not None:
                        forced[key] = man
                        continue
                lv.append(t)
            crowd = self._neighbours(live[cam])
            for t in live[cam]:
                m = t.pattern_return(img, j) if t.coasting and not t.awaiting_outline else t.propose(img, j)
                if m is not None and self._crowded_reject(t, m, crowd.get(id(t), ())):
                    m = None
                if m is not None:
                    props[(t.marker, cam)] = _Proposal(m)
            if self.follow_view:
                self._follow_view(cam, j, img, live[cam], props)
            self._resolve_conflicts(live[cam], props, forced)
            if self._has_crowd(cam):
                self._crowd_coherence(live[cam], props, crowd)
                self._crowd_flow_check(cam, img, live[cam], props)
        if self.stereo is not None:
            self._stereo_check(frames, props, forced, only_reattached=False)
        reattached = 0
        for cam, (_j, img, _rem) in frames.items():
            if self._reacquire(cam, img, live[cam], props, forced, frames):
                reattached += 1
                self._resolve_conflicts(live[cam], props, forced)  # (a pass leaves no clash behind)
                if self._has_crowd(cam):
                    self._crowd_coherence(live[cam], props, self._neighbours(live[cam]))
        if self.stereo is not None and reattached:
            for cam, (_j, img, _rem) in frames.items():
                if self._late_lines(cam, img, live[cam], props, forced, frames):
                    self._resolve_conflicts(live[cam], props, forced)
        for cam, (j, img, _rem) in frames.items():
            if self._has_crowd(cam):
                reattached += self._crowd_passes(cam, img, int(j), live[cam], props, forced, frames)
            self._crowd_prev[cam] = img
        if self.stereo is not None and reattached:
            self._stereo_check(frames, props, forced, only_reattached=True)
        self._looks(frames, live, props, forced)
        for cam, (j, img, _rem) in frames.items():
            for t in live[cam]:
                p = props.get((t.marker, cam))
                obs.append(t.apply(j, img, p.match if p else None, reattach=bool(p and p.reattach),
                                   jump=bool(p and p.jump)))
                if t.model.crowd:
                    self._remember_crowd((t.marker, cam), int(j), (p.match.x, p.match.y) if p else None)
        for key, (x, y) in forced.items():
            t = self.tracks[key]
            obs.append(t.set_manual(frames[t.camera][0], None, x, y))
            if t.model.crowd:
                self._remember_crowd(key, int(frames[t.camera][0]), (float(x), float(y)))
        if self.stereo is not None:
            self._pair_crowd(frames, obs)
        return obs

    # -- steps ---------------------------------------------------------------------------------
    def _crowd_passes(self, cam, img, j: int, tracks, props, forced, frames) -> int:
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

    def _other_view(self, key):
        """The key of the same marker in the stereo pair's other camera: the same marker's, or the crowd
        track paired with it (_pair_crowd); None."""
        other = (key[0], self.stereo.other(key[1]))
        return other if other in self.tracks else self.partners.get(key)

    def _pair_crowd(self, frames, obs) -> None:
        """Crowd beads seeded in one view each (touching lookalikes are not paired at the seed: an
        epipolar line crosses several of them) are paired across the views by their points over time.
        A bead's points in the two views lie on each other's epipolar lines (within the stereo
        threshold) at every frame both are measured; a track of the other view that left the line at
        PAIR_BREAKS frames or more is another bead (beside the line, or carried apart from it). Two
        tracks are paired when each is the only one of the other view that never left the other's line
        over at least PAIR_MIN_FRAMES frames measured together, every other track measured with it having
        left it PAIR_BREAKS times or more; anything less stays unpaired."""
        a, b = self.stereo.cams
        if a not in frames or b not in frames:
            return
        measured = {a: {}, b: {}}
        for o in obs:
            key = (o.marker, o.camera)
            t = self.tracks.get(key)
            if o.status == TRACKED and t is not None and t.model.crowd and key not in self.partners \
                    and (o.marker, self.stereo.other(o.camera)) not in self.tracks:
                measured[o.camera][key] = (o.x_px, o.y_px)
        if not measured[a] or not measured[b]:
            return
        ka, kb = list(measured[a]), list(measured[b])
        pa = np.repeat(np.array([measured[a][k] for k in ka], float), len(kb), axis=0)
        pb = np.tile(np.array([measured[b][k] for k in kb], float), (len(ka), 1))
        off = self.stereo.distance(a, pa, b, pb) > self.stereo.threshold_px
        for (x, y), broke in zip(((x, y) for x in ka for y in kb), off, strict=True):
            rec = self._lines.setdefault(x, {}).get(y)
            if rec is None:
                rec = self._lines[x][y] = self._lines.setdefault(y, {})[x] = [0, 0]
            rec[0] += 1
            rec[1] += int(broke)
        for x in ka:
            y = self._only_on_line(x)
            if y is not None and y in measured[b] and self._only_on_line(y) == x:
                self.partners[x], self.partners[y] = y, x
                self.pairings.append((x, y, self._lines[x][y][0], int(frames[a][0])))

    def _only_on_line(self, key):
        """The one track of the other view that never left `key`'s line over PAIR_MIN_FRAMES frames, every
        other one measured with it having left it PAIR_BREAKS times or more; None."""
        found = None
        for other, (together, broke) in self._lines.get(key, {}).items():
            if other in self.partners:
                continue
            if broke == 0 and together >= PAIR_MIN_FRAMES and found is None:
                found = other
            elif broke < PAIR_BREAKS:
                return None
        return found

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
        prev = self._crowd_prev.get(cam)
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
            self._note_ambiguous(missed[i].marker, cam, j, 2)
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
                props[(t.marker, cam)] = _Proposal(m, reattach=True)
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
                continue
            pairs, ambiguous = crowd_rules.assign(at, beads, 0.5 * r, 0.5 * r)
            for i in ambiguous:
                self._note_ambiguous(group[patch[i]].marker, cam, j, 2)
            n += self._give_back(cam, img, {group[patch[i]]: beads[b] for i, b in pairs.items()
                                            if agreed.get(i) == b}, props)
        return n

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
            self._note_ambiguous(placed[i].marker, cam, j, 2)
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
            if m is None or any(math.hypot(m.x - a, m.y - b) < r for a, b in self._explained(cam, props, forced)):
                continue
            props[(t.marker, cam)] = _Proposal(m, reattach=True)
            n += 1
        return n

    def _crowd_on_line(self, cam, img, j: int, tracks, props, forced, frames) -> int:
        """Crowd markers unseen for more than SHORT_MISS frames that the other view measures this step (the
        same marker, or its paired track: _pair_crowd): the bead no track explains lying on the other
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
            other = self._other_view(key)
            band_from = None if other is None or other[1] not in frames else \
                self._point_at(other, frames, props, forced)
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
                    self._note_ambiguous(t.marker, cam, j, int(rivals.sum()))
                continue
            bead = beads[int(np.argmax(inside))]
            n += self._give_back(cam, img, {t: bead}, props)
        return n

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
            other = self._other_view(key)
            band_from = None if other is None or other[1] not in frames else \
                self._point_at(other, frames, props, forced)
            if band_from is None:
                continue
            foot = self.stereo.onto_line(other[1], band_from, cam, carried)
            m = t.confirm_on_line(img, *foot)
            if m is None or self.stereo.distance(other[1], band_from, cam, (m.x, m.y))[0] > self.stereo.threshold_px \
                    or math.hypot(m.x - carried[0], m.y - carried[1]) > 0.5 * t.model.radius \
                    or any(math.hypot(m.x - a, m.y - b) <= 0.5 * t.model.radius
                           for a, b in self._explained(cam, props, forced)):
                continue
            props[key] = _Proposal(m, reattach=True)
            n += 1
        return n

    def _crowd_confirm(self, cam, img, missed, where, props, forced) -> int:
        """Carried crowd markers no detected bead gave back, measured where they were carried
        (MarkerTrack.confirm_carried), unless another marker of this camera is measured within a radius
        of there; returns how many came back."""
        taken = self._explained(cam, props, forced)
        n = 0
        for t, (x, y) in zip(missed, where, strict=True):
            if (t.marker, cam) in props or not t.carried:
                continue
            m = t.confirm_carried(img, float(x), float(y))
            if m is None or any(math.hypot(m.x - a, m.y - b) < t.model.radius for a, b in taken):
                continue
            props[(t.marker, cam)] = _Proposal(m, reattach=True)
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
        explained = self._explained(cam, props, forced)
        if explained:
            e = np.array(explained, float)
            d = np.hypot(beads[:, None, 0] - e[None, :, 0], beads[:, None, 1] - e[None, :, 1])
            beads = beads[d.min(axis=1) > r]
        return beads

    @staticmethod
    def _explained(cam, props, forced) -> list:
        """[(x, y)] of this step's proposals and operator's points in camera `cam`."""
        return [(p.match.x, p.match.y) for k, p in props.items() if k[1] == cam] + \
            [xy for k, xy in forced.items() if k[1] == cam]

    def _remember_crowd(self, key, frame: int, xy) -> None:
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

    def _follow_view(self, cam, j, img, tracks, props) -> None:
        """The tracks of this camera seen last frame mostly missed their gates, or found their markers
        all displaced alike: if the whole view moved since the previous frame (globalmotion.py),
        move every track with it and search the seen ones again."""
        prev, self._prev[cam] = self._prev.get(cam), img
        seen = [t for t in tracks if not t.coasting]
        if prev is None or not seen:
            return
        missed, moves = [], []
        for t in seen:
            p = props.get((t.marker, cam))
            if p is None:
                missed.append(t)
            elif not p.match.rest:  # (a marker at rest did not move)
                x, y = t.kf.xy
                moves.append((p.match.x - x, p.match.y - y))
        if len(missed) < 0.5 * len(seen) and not _alike(moves):
            return
        shift = image_shift(prev, img)
        if shift is None:
            return
        for t in tracks:
            t.kf.translate(*shift)
        crowd = self._neighbours(tracks)
        for t in seen:
            props.pop((t.marker, cam), None)
            m = t.propose(img, j)
            if m is not None and not self._crowded_reject(t, m, crowd.get(id(t), ())):
                props[(t.marker, cam)] = _Proposal(m)
        if len(self.view_shifts) < self.max_events:
            self.view_shifts.append({"camera": cam, "frame": int(j), "dx": round(shift[0], 2),
                                     "dy": round(shift[1], 2)})

    def _crowd_coherence(self, tracks, props, crowd: dict) -> None:
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

    def _crowd_flow_check(self, cam, img, tracks, props) -> None:
        """A crowd marker's new match must lie where the image motion around it since the last step
        took it (crowd.flowed, from where it was measured then), within FLOW_AGREE_PX: one that does not
        has jumped to a neighbour's outline or a gap, and coasts instead (flagged). Where the motion is
        not clear the match stands."""
        prev = self._crowd_prev.get(cam)
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

    def _neighbours(self, tracks) -> dict:
        """For each track, the other tracks whose predictions touch it: id(track) -> [(track, xy)]."""
        if len(tracks) < 2:
            return {}
        pts = [(*t.kf.xy, t.model.radius) for t in tracks]
        near: list[list[int]] = [[] for _ in tracks]  # neighbour indices, ascending
        for i, k in _touching_pairs(pts, lambda ri, rk: self.crowd_factor * (ri + rk)):
            near[i].append(k)
            near[k].append(i)
        return {id(tracks[i]): [(tracks[k], pts[k][:2]) for k in ks] for i, ks in enumerate(near) if ks}

    def _crowded_reject(self, t: MarkerTrack, m: Match, neighbours) -> bool:
        """Markers touching each other: their discs merge, the centroid and the NCC peak both lie.
        Keep a match only if it is clearly this marker's: nearer to this track's prediction than to
        the neighbour's, and either centred on its own share of the blob (the matcher split it from
        the touching markers) or of a high score and not a merged blob. Otherwise the track coasts
        (honestly)."""
        if not neighbours:
            return False
        px, py = t.kf.xy
        own = math.hypot(m.x - px, m.y - py)
        for _o, q in neighbours:
            if math.hypot(m.x - q[0], m.y - q[1]) < own:
                return True
        if t.model.crowd and m.outline:
            # (centred on its own outline: the coverage around it holds the rims of its touching neighbours)
            return m.score < self.crowded_min_score or m.colour_frac > crowd_rules.packed_coverage(
                t.model.radius, self.crowded_max_colour)
        if m.touching and m.used_centroid:
            return m.colour_frac > self.crowded_max_colour
        return m.score < self.crowded_min_score or m.colour_frac > self.crowded_max_colour

    def _resolve_conflicts(self, tracks, props, forced) -> None:
        """Two tracks on (nearly) the same spot: the better match keeps it, the other coasts."""
        keyed = [(t, props[(t.marker, t.camera)]) for t in tracks if (t.marker, t.camera) in props]
        if len(keyed) < 2:
            return
        pts = [(p.match.x, p.match.y, t.model.radius) for t, p in keyed]
        for i, k in _touching_pairs(pts, lambda ri, rk: 1.2 * max(ri, rk)):
            (ta, pa), (tb, pb) = keyed[i], keyed[k]
            ka, kb = (ta.marker, ta.camera), (tb.marker, tb.camera)
            if ka not in props or kb not in props or _two_outlines(ta, pa.match, tb, pb.match):
                continue
            better_a = (pa.match.score - 0.05 * pa.match.d2) >= (pb.match.score - 0.05 * pb.match.d2)
            del props[kb if better_a else ka]

    def _point_at(self, key, frames, props, forced):
        """Position of a marker in one camera at the step's wanted time, or None."""
        t = self.tracks.get(key)
        if t is None:
            return None
        if key in forced:
            x, y = forced[key]
            return float(x), float(y)
        p = props.get(key)
        if p is None:
            return None
        rem = frames[t.camera][2]
        if not rem:
            return p.match.x, p.match.y
        vx, vy = t.kf.vxy
        return p.match.x + vx * self.direction * rem, p.match.y + vy * self.direction * rem

    def _stereo_check(self, frames, props, forced, only_reattached: bool) -> None:
        a, b = self.stereo.cams
        if a not in frames or b not in frames:
            return
        pairs, pas, pbs = [], [], []
        for ka, kb in self._stereo_pairs(a, b):
            if only_reattached and not ((ka in props and props[ka].reattach) or (kb in props and props[kb].reattach)):
                continue
            pa, pb = self._point_at(ka, frames, props, forced), self._point_at(kb, frames, props, forced)
            if pa is None or pb is None:
                continue
            pairs.append((ka, kb))
            pas.append(pa)
            pbs.append(pb)
        if not pairs:
            return
        dist = self.stereo.distance(a, np.array(pas), b, np.array(pbs))  # one call for all markers
        for (ka, kb), d in zip(pairs, dist, strict=True):
            if d <= self.stereo.threshold_px:
                continue
            cands = [k for k in (ka, kb) if k in props and k not in forced]
            if only_reattached:
                cands = [k for k in cands if props[k].reattach] or cands
            if not cands:
                continue
            suspect = max(cands, key=lambda k: props[k].match.d2 if np.isfinite(props[k].match.d2) else 0.0)
            del props[suspect]
            if len(self.stereo_flags) < self.max_events:
                self.stereo_flags.append({"marker": suspect[0], "camera": suspect[1],
                                          "frame": int(frames[suspect[1]][0]), "epipolar_px": round(float(d), 2)})

    def _stereo_pairs(self, a, b) -> list:
        """[(key in a, key in b)] of the markers tracked in both cameras, sorted, then the crowd tracks
        paired across them (kept until the set of tracks or of pairs changes)."""
        c = self._both_cache
        if c is None or c[0] != (a, b, len(self.tracks), len(self.partners)):
            ms = sorted({m for (m, k) in self.tracks if k == a} & {m for (m, k) in self.tracks if k == b})
            crowd = sorted((ka, kb) for ka, kb in self.partners.items() if ka[1] == a)
            c = self._both_cache = ((a, b, len(self.tracks), len(self.partners)),
                                    [((m, a), (m, b)) for m in ms] + crowd)
        return c[1]

    def _reacquire(self, cam, img, tracks, props, forced, frames) -> int:
        """Re-attach coasting tracks of `cam` to unexplained blobs; returns how many were."""
        self._searched[cam] = ({}, set())
        if all((t.marker, cam) in props for t in tracks):
            return 0
        explained = self._explained(cam, props, forced)
        cands: dict[tuple, list] = {}  # track key -> [(d2, blob id, blob)]
        jumpers: set = set()  # tracks searched a largest move per frame beyond their gate (a streak)
        far: set = set()  # tracks searched beyond their gate (any rival is then ambiguous)
        unanchored: set = set()  # lost tracks the other view does not pin to a line: any lost marker may be theirs
        windows: dict = {}  # track key -> (x, y, hx, hy) searched
        seen: list = []  # one blob seen through several tracks' windows is one blob
        lines: dict = {}  # track key -> the other view's point this step, for _on_line (its line pins the marker)
        assigned: dict = {}  # track key -> (x, y) of the blob it was given that its match then failed
        self._searched[cam] = (windows, lines)
        for t in tracks:
            key = (t.marker, cam)
            if key in props:
                continue
            if t.model.crowd and t.misses > SHORT_MISS:
                continue  # (unseen a while among touching lookalikes: which is which is not known any more)
            px, py = t.kf.xy
            hx, hy = t.search_halfsize()
            band_from = None
            if self.stereo is not None and cam in self.stereo.cams:
                other = self._other_view(key)
                if other is not None and other[1] in frames:
                    band_from = self._point_at(other, frames, props, forced)
                    if band_from is not None and _measurable_on_line(t.model):
                        lines[key] = band_from
            # How far the marker may have gone since it was last seen: a frame's largest move per frame.
            # Beyond its gate (pushed hard, carried away while hidden, or the view jumped) a blob takes
            # the track only when no other candidate is in sight (any rival is ambiguous).
            p = t.params
            # (the first frames of a miss only: later the gate, widened while hidden, takes over)
            reach = p.max_jump_px * (t.misses + 1) if t.misses <= JUMP_FRAMES else 0.0
            if t.model.crowd:
                reach = 0.0  # (among touching lookalikes a blob beyond the gate is anyone's: motion alone tells)
            carried = False
            if band_from is not None:
                # The other view pins the marker to a line: search a wider window, along the band only.
                wide = max(hx, hy, 4 * t.model.radius + 10)
                hx = hy = min(wide, p.max_search_px)
                if reach > hx:
                    hx = hy = min(reach, p.max_band_search_px)
                else:
                    # Hidden a while: the sand may have carried it anywhere along the line.
                    # Every other frame: a marker back in sight stays in sight, so this costs at most a
                    # frame of delay, and the band search is most of a hidden marker's cost.
                    carried = (t.misses > JUMP_FRAMES and t.misses % 2 == 1 and t.model.has_blob
                               and not t.model.crowd and hx < p.max_band_search_px)
            elif reach > max(hx, hy):
                hx = hy = min(reach, p.max_search_px)
            jump = not carried and max(hx, hy) > max(t.search_halfsize()) and t.model.has_blob
            # Beyond the gate the marker may be a streak: its pixels count from half the threshold.
            windows[key] = (px, py, hx, hy)
            blobs = find_blobs(img, t.model, px, py, hx, hy,
                               threshold=0.5 * t.model.threshold if jump else None)
            if carried:
                blobs += self._band_blobs(cam, img, t.model, band_from, px, py, hx, p.max_band_search_px)
            blobs = unexplained(blobs, np.array(explained).reshape(-1, 2), 1.5 * t.model.radius + 1)
            if not blobs:
                continue
            xy = np.array([(b.x, b.y) for b in blobs])
            d2 = t.kf.mahalanobis2(xy)
            if band_from is not None:
                keep = self.stereo.distance(self.stereo.other(cam), band_from, cam, xy) <= self.stereo.band_px
            elif jump:
                keep = np.ones(len(blobs), bool)
            else:
                keep = d2 <= t.params.gate_d2
            if jump or carried:
                far.add(key)
            if t.status == LOST and band_from is None:
                unanchored.add(key)
            if jump:
                jumpers.add(key)
            cands[key] = [(float(d), self._blob_id(seen, b, t.model.radius), b)
                          for d, b, k in zip(d2, blobs, keep, strict=True) if k]
        n = 0
        for key, blob in self._assign(cam, int(frames[cam][0]), cands, far, windows, unanchored).items():
            m = self.tracks[key].verify_at(img, blob.x, blob.y, int(frames[cam][0]) if key in jumpers else None)
            if m is not None:
                props[key] = _Proposal(m, reattach=True, jump=key in jumpers)
                n += 1
            else:
                assigned[key] = (blob.x, blob.y)
        for key, band_from in lines.items():
            if key not in props:
                explained_now = self._explained(cam, props, forced)
                m = None if key not in assigned else \
                    self._on_line(cam, img, self.tracks[key], band_from, explained_now, at=assigned[key])
                m = m or self._on_line(cam, img, self.tracks[key], band_from, explained_now)
                if m is None and key in windows and self.tracks[key].misses % 2 == 1:
                    # (every other frame, as the band's blobs: a marker back in sight stays in sight)
                    m = self._on_band(cam, img, self.tracks[key], band_from, explained_now, max(windows[key][2:]))
                if m is not None and self._nearer_searcher(key, m, windows, props):
                    m = None
                if m is not None:
                    props[key] = _Proposal(m, reattach=True)
                    n += 1
        return n

    def _late_lines(self, cam, img, tracks, props, forced, frames) -> int:
        """_reacquire's measurement on the other view's line (_on_line, _on_band) for the coasting tracks of
        `cam` whose other view was given its point back by a re-acquisition after `cam` was searched this
        step; returns how many were measured."""
        windows, lined = self._searched.get(cam, ({}, set()))
        n = 0
        for t in tracks:
            key = (t.marker, cam)
            if key in props or key in forced or key in lined or not _measurable_on_line(t.model):
                continue
            band_from = self._point_at((t.marker, self.stereo.other(cam)), frames, props, forced)
            if band_from is None:
                continue
            explained = self._explained(cam, props, forced)
            reach = min(max(*t.search_halfsize(), 4 * t.model.radius + 10), t.params.max_search_px)
            m = self._on_line(cam, img, t, band_from, explained) or self._on_band(cam, img, t, band_from, explained,
                                                                                 reach)
            if m is not None and not self._nearer_searcher(key, m, windows, props):
                props[key] = _Proposal(m, reattach=True)
                n += 1
        return n

    def _nearer_searcher(self, key, m: Match, windows: dict, props) -> bool:
        """Another track of this camera still searching holds m in its window, its prediction nearer m
        than this track's: the marker there may be that one (which did not see it), as in _assign."""
        ox, oy = self.tracks[key].kf.xy
        own = math.hypot(m.x - ox, m.y - oy)
        return any(k != key and k not in props and abs(m.x - wx) <= hx and abs(m.y - wy) <= hy
                   and math.hypot(m.x - wx, m.y - wy) < own for k, (wx, wy, hx, hy) in windows.items())

    def _on_line(self, cam, img, t: MarkerTrack, band_from, explained: list, at=None) -> Match | None:
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
        if not _measurable_on_line(model):
            return None
        other = self.stereo.other(cam)
        x, y = self.stereo.onto_line(other, band_from, cam, t.kf.xy if at is None else at)
        half = min(max(t.search_halfsize()), 2 * model.radius + 4) if at is None else 2.0
        m = t.matcher.match(img, x, y, half, half)
        if not self._template_on_line(t, img, m, other, band_from):
            m = self._look_on_line(t, img, (x, y) if m is None else (m.x, m.y), other, band_from)
        return None if m is None else self._placed_on_line(t, img, m, other, band_from, explained)

    def _template_on_line(self, t: MarkerTrack, img, m: Match | None, other, band_from) -> bool:
        """The template's match m is as _on_line takes it: its score and PSR as a tracked marker's, not
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

    def _on_band(self, cam, img, t: MarkerTrack, band_from, explained: list, reach: float) -> Match | None:
        """_on_line for a marker unseen a while, whose prediction may lie far from it: its template
        searched in windows along the other view's epipolar line, out to `reach` px from the prediction's
        foot on it, taken only where it is found at one place along the line that this camera does not
        explain (another marker like it there, unseen too, could be either)."""
        if not _measurable_on_line(t.model):
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

    def _looks(self, frames, live: dict, props, forced) -> None:
        """Brightness-model markers still followed (not lost) that nothing measured this step: where a
        marker's look at its last whole measurement (MarkerTrack.look_place) registers near its prediction
        and the marker shows itself whole (MarkerTrack.shows_whole), it is there (a marker pushed by the
        tool, whose look changes as it moves over the sand, is found by no match; a marker partly hidden
        shows no outline all round). With a second view: not where that view measures the marker
        (its line was asked, _on_line); where that view's look places it too, only when the two places lie
        on each other's epipolar lines as closely as a marker measured in both views does
        (StereoCheck.agree_px; a look slides to the part of a marker in sight, which the two views do not
        see alike)."""
        found = {}
        for cam, (_j, img, _rem) in frames.items():
            for t in live.get(cam, ()):
                key = (t.marker, cam)
                if key not in props and key not in forced and t.status != LOST and _measurable_on_line(t.model):
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
            props[key] = _Proposal(m, reattach=True)

    def _look_alone(self, t: MarkerTrack, img, props, forced) -> Match | None:
        """_looks' match of track t in its camera's image, or None."""
        placed = t.look_place(img, *t.kf.xy)
        if placed is None:
            return None
        m = Match(*placed, t.look_fit, float("nan"), float("nan"), t.kf.d2(*placed), look=True)
        if m.d2 > t.params.gate_d2 or t.cut_by_border(img, m) or not t.shows_whole(img, m.x, m.y) \
                or _on_explained(m, t.model, self._explained(t.camera, props, forced)):
            return None
        return m

    def _look_on_line(self, t: MarkerTrack, img, start: tuple, other, band_from) -> Match | None:
        """_on_line where the template does not place the marker on the line: its look at its last whole
        measurement (MarkerTrack.look_place), registered from `start`, placing it on the line as closely
        as a marker measured in both views lies; None otherwise."""
        placed = t.look_place(img, *start)
        if placed is None or self.stereo.distance(other, band_from, t.camera, placed)[0] > self.stereo.agree_px:
            return None
        m = Match(*placed, t.look_fit, float("nan"), float("nan"), look=True)
        return None if t.cut_by_border(img, m) else m

    def _band_blobs(self, cam, img, model, band_from, px, py, inner: float, reach: float) -> list:
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

    @staticmethod
    def _blob_id(seen: list, b, radius: float) -> int:
        for i, (x, y) in enumerate(seen):
            if np.hypot(b.x - x, b.y - y) < radius:
                return i
        seen.append((b.x, b.y))
        return len(seen) - 1

    def _assign(self, cam, frame, cands: dict, far=frozenset(), windows=None, unanchored=frozenset()) -> dict:
        """Tracks to blobs, most likely pair first; a pair is taken only if neither the track nor the
        blob has a rival nearly as likely (likelihood ratio > e^3 ≈ 20): ambiguity is left alone.
        Blobs inside a track's gate go first: a blob only a track searched beyond its gate (`far`)
        could reach is left to the tracks whose gate holds it. Then a far track takes a blob outside
        its gate only when neither the track nor the blob has any rival, and the blob lies in no
        other still searching track's window (`windows`: that track may be the blob's marker even if
        it did not see the blob there). Inside the gates too, a blob in another still searching
        track's window and nearer that track's prediction than this one's may be that track's marker
        (which did not see it: half hidden still, or beside the tool), and a lost track no other view
        pins (`unanchored`) is nowhere in particular: any searching track's window holding its blob is
        a rival. Both are ambiguous."""
        gated, beyond = {}, {}
        for k, lst in cands.items():
            if k not in far:
                gated[k] = lst
                continue
            gate = self.tracks[k].params.gate_d2
            gated[k] = [c for c in lst if c[0] <= gate]
            beyond[k] = [c for c in lst if c[0] > gate]
        blocked_tracks, blocked_blobs = set(), set()
        out = self._assign_pass(cam, frame, gated, blocked_tracks, blocked_blobs, None, unanchored, windows)
        if any(beyond.values()):
            taken = set(out)
            searching = {k: w for k, w in (windows or {}).items() if k not in taken}
            beyond = {k: v for k, v in beyond.items() if k not in blocked_tracks}
            out.update(self._assign_pass(cam, frame, beyond, blocked_tracks, blocked_blobs, searching))
        return out

    def _assign_pass(self, cam, frame, cands: dict, blocked_tracks: set, blocked_blobs: set, windows,
                     unanchored=frozenset(), all_windows=None) -> dict:
        """One greedy pass of _assign; `windows` given: the candidates lie beyond their tracks' gates.
        Inside the gates, the other tracks of `all_windows` not yet given a blob whose window holds a
        track's blob are its rivals when their prediction is nearer it, or always for a track of
        `unanchored`."""
        out = {}
        cands = {k: sorted(v, key=lambda c: c[0]) for k, v in cands.items() if v}
        while True:
            best = None
            for key, lst in cands.items():
                if key in blocked_tracks:
                    continue
                for d2, bid, blob in lst:
                    if bid in blocked_blobs:
                        continue
                    if best is None or d2 < best[0]:
                        best = (d2, key, bid, blob)
                    break
            if best is None:
                return out
            d2, key, bid, blob = best
            rival_blob = [c[0] for c in cands[key] if c[1] != bid and c[1] not in blocked_blobs]
            rival_track = [c[0] for k, lst in cands.items() if k != key and k not in blocked_tracks
                           for c in lst if c[1] == bid]
            far = windows is not None
            near = [r for r in rival_blob + rival_track if r - d2 < self.ambiguity_d2 or far]
            if far:
                near += [d2 for k, (wx, wy, hx, hy) in windows.items()
                         if k != key and abs(blob.x - wx) <= hx and abs(blob.y - wy) <= hy]
            elif all_windows:
                ox, oy = all_windows[key][:2]
                own = math.hypot(blob.x - ox, blob.y - oy)
                near += [d2 for k, (wx, wy, hx, hy) in all_windows.items()
                         if k != key and k not in out and abs(blob.x - wx) <= hx and abs(blob.y - wy) <= hy
                         and (key in unanchored or math.hypot(blob.x - wx, blob.y - wy) < own)]
            blocked_tracks.add(key)
            blocked_blobs.add(bid)
            if near:
                n = 1 + len(near)
                self._note_ambiguous(key[0], cam, frame, n, shared=bool(rival_track))
                continue
            out[key] = blob

    def _note_ambiguous(self, marker, cam, frame, n, shared=False) -> None:
        """Record an ambiguity once per stretch (consecutive frames extend the same record)."""
        key = (marker, cam)
        rec = self._open_ambiguity.get(key)
        if rec is not None and abs(frame - rec["last_frame"]) <= 1:
            rec["last_frame"] = frame
            rec["candidates"] = max(rec["candidates"], n)
            return
        if len(self.ambiguous) >= self.max_events:
            return
        rec = {"marker": marker, "camera": cam, "frame": frame, "last_frame": frame, "candidates": n,
               "why": "blob wanted by two tracks" if shared else "several candidate blobs in the gate"}
        self.ambiguous.append(rec)
        self._open_ambiguity[key] = rec


def _two_outlines(ta: MarkerTrack, ma: Match, tb: MarkerTrack, mb: Match) -> bool:
    """Two crowd matches each centred on its own outline, found all round, more than half a radius apart:
    two beads, one partly over the other (a pressed layer piles up), not one bead claimed twice (one
    outline measured twice gives centres much nearer than that)."""
    return ta.model.crowd and tb.model.crowd and ma.outline and mb.outline and \
        math.hypot(ma.x - mb.x, ma.y - mb.y) > 0.5 * max(ta.model.radius, tb.model.radius)


def _alike(moves: list, min_px: float = 2.0, spread_px: float = 1.5) -> bool:
    """At least two markers' moves from their predictions, of at least `min_px`, all within
    `spread_px` of their median: the view moved, or everything was carried alike."""
    if len(moves) < 2:
        return False
    mx, my = statistics.median(m[0] for m in moves), statistics.median(m[1] for m in moves)
    if math.hypot(mx, my) < min_px:
        return False
    return all(math.hypot(m[0] - mx, m[1] - my) <= spread_px for m in moves)


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


def _touching_pairs(pts, limit) -> list[tuple[int, int]]:
    """Index pairs (i, k), i < k, in ascending order, of points (x, y, r) closer than limit(ri, rk)
    (a function growing with both radii). Swept along x: a camera's markers are mostly far apart,
    so few pairs are looked at. Plain floats: a handful of points, where numpy's per-call cost
    would dominate."""
    order = sorted((i for i, p in enumerate(pts) if math.isfinite(p[0]) and math.isfinite(p[1])),
                   key=lambda i: pts[i][0])
    if len(order) < 2:
        return []
    r_max = max(pts[i][2] for i in order)
    reach = limit(r_max, r_max)
    pairs = []
    for a, i in enumerate(order):
        xi, yi, ri = pts[i]
        for k in order[a + 1:]:
            xk, yk, rk = pts[k]
            if xk - xi >= reach:
                break
            lim = limit(ri, rk)
            if xk - xi < lim and abs(yk - yi) < lim and math.hypot(xk - xi, yk - yi) < lim:
                pairs.append((i, k) if i < k else (k, i))
    pairs.sort()
    return pairs
