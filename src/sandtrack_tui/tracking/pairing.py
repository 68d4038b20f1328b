"""Crowd beads seeded in one view each, paired across the views by their points over time (touching
lookalikes are not paired at the seed: an epipolar line crosses several of them). The engine's last stage
each step; the run makes each pair one marker at its end (run._merge_pairs)."""

from __future__ import annotations

import numpy as np

from .tracker import TRACKED
from .trackset import OnTracks, TrackSet

# Two crowd tracks, one per view, are one bead when the other view's line through one never missed the
# other over PAIR_MIN_FRAMES frames measured together, while every other track of that view left it at
# PAIR_BREAKS frames or more (more than a wrong measurement or two: a bead beside the line, not on it).
PAIR_MIN_FRAMES = 10
PAIR_BREAKS = 3


class CrowdPairing(OnTracks):
    """Pairs crowd tracks of the two views (pair) into TrackSet.partners; each pair as made in `pairings`."""

    def __init__(self, trackset: TrackSet):
        super().__init__(trackset)
        # each pair as it was made: (key in the stereo pair's first camera, key in the second, frames measured on
        # each other's lines then, frame of the first camera at which it was made)
        self.pairings: list = []
        # key in one camera -> {key in the other: [frames both measured, frames off each other's lines]} (both ways)
        self._lines: dict = {}

    def pair(self, frames, obs) -> None:
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
