"""Which track gets which match or blob: two tracks of one camera on one spot keep only the better match
(resolve_conflicts); coasting tracks get the blobs their searches found, most likely pair first, only where
no rival is nearly as likely (BlobAssigner): ambiguity is left alone, and recorded."""

from __future__ import annotations

import math

import numpy as np

from .events import AmbiguityLog
from .matcher import Match
from .search import touching_pairs
from .tracker import MarkerTrack
from .trackset import TrackSet


def resolve_conflicts(tracks, props) -> None:
    """Two tracks on (nearly) the same spot: the better match keeps it, the other coasts."""
    keyed = [(t, props[(t.marker, t.camera)]) for t in tracks if (t.marker, t.camera) in props]
    if len(keyed) < 2:
        return
    pts = [(p.match.x, p.match.y, t.model.radius) for t, p in keyed]
    for i, k in touching_pairs(pts, lambda ri, rk: 1.2 * max(ri, rk)):
        (ta, pa), (tb, pb) = keyed[i], keyed[k]
        ka, kb = (ta.marker, ta.camera), (tb.marker, tb.camera)
        if ka not in props or kb not in props or _two_outlines(ta, pa.match, tb, pb.match):
            continue
        better_a = (pa.match.score - 0.05 * pa.match.d2) >= (pb.match.score - 0.05 * pb.match.d2)
        del props[kb if better_a else ka]



def _two_outlines(ta: MarkerTrack, ma: Match, tb: MarkerTrack, mb: Match) -> bool:
    """Two crowd matches each centred on its own outline, found all round, more than half a radius apart:
    two beads, one partly over the other (a pressed layer piles up), not one bead claimed twice (one
    outline measured twice gives centres much nearer than that)."""
    return ta.model.crowd and tb.model.crowd and ma.outline and mb.outline and \
        math.hypot(ma.x - mb.x, ma.y - mb.y) > 0.5 * max(ta.model.radius, tb.model.radius)




def blob_id(seen: list, b, radius: float) -> int:
    """The index in `seen` ([(x, y)] of the blobs seen so far this step) of blob b: one blob seen through
    several tracks' windows is one blob."""
    for i, (x, y) in enumerate(seen):
        if np.hypot(b.x - x, b.y - y) < radius:
            return i
    seen.append((b.x, b.y))
    return len(seen) - 1


class BlobAssigner:
    """Coasting tracks to the blobs their searches found (assign); ambiguities go to the log."""

    def __init__(self, trackset: TrackSet, log: AmbiguityLog, ambiguity_d2: float = 6.0):
        self.trackset = trackset
        self.log = log
        self.ambiguity_d2 = ambiguity_d2

    def assign(self, cam, frame, cands: dict, far=frozenset(), windows=None, unanchored=frozenset()) -> dict:
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
            gate = self.trackset.tracks[k].params.gate_d2
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
        """One greedy pass of assign; `windows` given: the candidates lie beyond their tracks' gates.
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
                self.log.note(key[0], cam, frame, n, shared=bool(rival_track))
                continue
            out[key] = blob

