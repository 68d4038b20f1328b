"""All markers in all cameras, one time step at a time.

Per step: every track predicts and proposes its best gated match; two tracks of one camera
claiming the same marker keep only the better; with a calibration, the proposals of a marker in
the two cameras are checked against each other's epipolar lines (the suspect view is dropped and
flagged); coasting tracks look for unexplained blobs (along the epipolar band when the other view
is tracked; a brightness model's marker also by its template or its look on the other view's line);
a brightness model's marker still followed that nothing measured is placed by its look where it shows
whole (in both views only where they agree); then every track commits its status for the frame.
The searches along the other view's line and by a marker's look are in line_search.py. Touching
lookalikes (a crowd, crowd.py) have passes of their own (crowd_passes.py): those seeded in one view
each are paired across the views once their points tell who is who (_pair_crowd), and then checked
and searched like one marker's two views (the run makes each pair one marker at its end:
run._merge_pairs). When most tracks of a camera leave their gates at once and the whole view moved
(globalmotion.py), every track of that camera is moved with the view and searched again.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field

import numpy as np

from . import crowd as crowd_rules
from .crowd_passes import CrowdPasses
from .globalmotion import image_shift
from .line_search import LineSearch, _measurable_on_line
from .matcher import Match, Proposal
from .reacquire import find_blobs, unexplained
from .stereo import StereoCheck
from .tracker import LOST, SHORT_MISS, MarkerTrack, Observation

JUMP_FRAMES = 2  # frames after a miss during which a track is searched a largest move per frame unseen


@dataclass
class Engine(CrowdPasses, LineSearch):
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
    _flow_refused: set = field(default_factory=set)  # crowd track keys whose match the flow check refused this step

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
        props: dict[tuple, Proposal] = {}
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
                    props[(t.marker, cam)] = Proposal(m)
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

    def _other_view(self, key):
        """The key of the same marker in the stereo pair's other camera: the same marker's, or the crowd
        track paired with it (_pair_crowd); None."""
        other = (key[0], self.stereo.other(key[1]))
        return other if other in self.tracks else self.partners.get(key)

    @staticmethod
    def _explained(cam, props, forced) -> list:
        """[(x, y)] of this step's proposals and operator's points in camera `cam`."""
        return [(p.match.x, p.match.y) for k, p in props.items() if k[1] == cam] + \
            [xy for k, xy in forced.items() if k[1] == cam]

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
                props[(t.marker, cam)] = Proposal(m)
        if len(self.view_shifts) < self.max_events:
            self.view_shifts.append({"camera": cam, "frame": int(j), "dx": round(shift[0], 2),
                                     "dy": round(shift[1], 2)})

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
            if t.model.crowd and (t.misses > SHORT_MISS or key in self._flow_refused):
                # (unseen a while among touching lookalikes: which is which is not known any more; or its match
                # this step left where the image motion took it: the blob there is that match again)
                continue
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
                props[key] = Proposal(m, reattach=True, jump=key in jumpers)
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
                    props[key] = Proposal(m, reattach=True)
                    n += 1
        return n

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
