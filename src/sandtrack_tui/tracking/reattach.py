"""Coasting tracks re-attached: each searched for blobs of its marker's look no match of its camera explains
(reacquire.py), in its gate, a largest move per frame beyond it the first frames of a miss, or along the
other view's epipolar band when that view measures the marker; the blobs assigned (matching.BlobAssigner)
and verified (MarkerTrack.verify_at); a brightness model's marker the other view measures also by its
template or look on that view's line (line_search.py)."""

from __future__ import annotations

import numpy as np

from .crowd_passes import CrowdPasses
from .line_search import LineSearch, measurable_on_line
from .matcher import Proposal
from .matching import BlobAssigner, blob_id
from .reacquire import find_blobs, unexplained
from .tracker import LOST, SHORT_MISS
from .trackset import OnTracks, TrackSet, explained_points

JUMP_FRAMES = 2  # frames after a miss during which a track is searched a largest move per frame unseen


class Reacquisition(OnTracks):
    """The re-acquisition of one camera's coasting tracks (run), with the searches it holds."""

    def __init__(self, trackset: TrackSet, lines: LineSearch, crowd: CrowdPasses, assigner: BlobAssigner):
        super().__init__(trackset)
        self.lines = lines
        self.crowd = crowd
        self.assigner = assigner

    def run(self, cam, img, tracks, props, forced, frames) -> int:
        """Re-attach coasting tracks of `cam` to unexplained blobs; returns how many were."""
        by_key = self.trackset.tracks
        self.lines.searched[cam] = ({}, set())
        if all((t.marker, cam) in props for t in tracks):
            return 0
        explained = explained_points(cam, props, forced)
        cands: dict[tuple, list] = {}  # track key -> [(d2, blob id, blob)]
        jumpers: set = set()  # tracks searched a largest move per frame beyond their gate (a streak)
        far: set = set()  # tracks searched beyond their gate (any rival is then ambiguous)
        unanchored: set = set()  # lost tracks the other view does not pin to a line: any lost marker may be theirs
        windows: dict = {}  # track key -> (x, y, hx, hy) searched
        seen: list = []  # one blob seen through several tracks' windows is one blob
        lines: dict = {}  # track key -> the other view's point this step (its line pins the marker: LineSearch.on_line)
        assigned: dict = {}  # track key -> (x, y) of the blob it was given that its match then failed
        self.lines.searched[cam] = (windows, lines)
        for t in tracks:
            key = (t.marker, cam)
            if key in props:
                continue
            if t.model.crowd and (t.misses > SHORT_MISS or key in self.crowd.flow_refused):
                # (unseen a while among touching lookalikes: which is which is not known any more; or its match
                # this step left where the image motion took it: the blob there is that match again)
                continue
            px, py = t.kf.xy
            hx, hy = t.search_halfsize()
            band_from = None
            if self.stereo is not None and cam in self.stereo.cams:
                other = self.trackset.other_view(key)
                if other is not None and other[1] in frames:
                    band_from = self.trackset.point_at(other, frames, props, forced)
                    if band_from is not None and measurable_on_line(t.model):
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
                blobs += self.lines.band_blobs(cam, img, t.model, band_from, px, py, hx, p.max_band_search_px)
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
            cands[key] = [(float(d), blob_id(seen, b, t.model.radius), b)
                          for d, b, k in zip(d2, blobs, keep, strict=True) if k]
        n = 0
        for key, blob in self.assigner.assign(cam, int(frames[cam][0]), cands, far, windows, unanchored).items():
            m = by_key[key].verify_at(img, blob.x, blob.y, int(frames[cam][0]) if key in jumpers else None)
            if m is not None:
                props[key] = Proposal(m, reattach=True, jump=key in jumpers)
                n += 1
            else:
                assigned[key] = (blob.x, blob.y)
        for key, band_from in lines.items():
            if key not in props:
                explained_now = explained_points(cam, props, forced)
                m = None if key not in assigned else \
                    self.lines.on_line(cam, img, by_key[key], band_from, explained_now, at=assigned[key])
                m = m or self.lines.on_line(cam, img, by_key[key], band_from, explained_now)
                if m is None and key in windows and by_key[key].misses % 2 == 1:
                    # (every other frame, as the band's blobs: a marker back in sight stays in sight)
                    m = self.lines.on_band(cam, img, by_key[key], band_from, explained_now, max(windows[key][2:]))
                if m is not None and self.lines.nearer_searcher(key, m, windows, props):
                    m = None
                if m is not None:
                    props[key] = Proposal(m, reattach=True)
                    n += 1
        return n

