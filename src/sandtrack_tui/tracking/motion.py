"""Where each marker is expected: the step's prediction (each track's Kalman filter, or the seed's and the
operator's own points), and the view's own motion (a shaken or panned camera) carried into the predictions
when most tracks of a camera lose their gates at once (globalmotion.py)."""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field

from .globalmotion import image_shift
from .matcher import Proposal
from .search import Crowded
from .tracker import Observation
from .trackset import TrackSet


def predict(trackset: TrackSet, frames: dict, manual: dict) -> tuple[list[Observation], dict, dict]:
    """(obs, live, forced): the seeds' own observations at their seed frames; camera -> [tracks] stepping
    this frame, each predicted; (marker, camera) -> (x, y) the operator's points (`manual`: (marker, camera,
    frame) -> (x, y)) that stand for a track's measurement this frame."""
    obs: list[Observation] = []
    live: dict = {}
    forced: dict = {}
    for cam, (j, _img, _rem) in frames.items():
        live[cam] = lv = []
        for key, t, s in trackset.of_camera(cam):
            if j == s and t.frame_index == s and t.counts["manual"] == 0:
                obs.append(t.seed_observation())
                continue
            if trackset.direction * (j - s) <= 0:
                continue
            t.predict()
            if manual:
                man = manual.get((t.marker, cam, j))
                if man is not None:
                    forced[key] = man
                    continue
            lv.append(t)
    return obs, live, forced


@dataclass
class ViewFollower:
    """The view's own motion carried into a camera's predictions (follow), and the shifts applied."""

    max_events: int = 500
    shifts: list = field(default_factory=list)  # {camera, frame, dx, dy} applied
    _prev: dict = field(default_factory=dict)  # camera -> its frame of the previous step

    def follow(self, cam, j, img, tracks, props, crowded: Crowded) -> None:
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
        crowd = crowded.neighbours(tracks)
        for t in seen:
            props.pop((t.marker, cam), None)
            m = t.propose(img, j)
            if m is not None and not crowded.reject(t, m, crowd.get(id(t), ())):
                props[(t.marker, cam)] = Proposal(m)
        if len(self.shifts) < self.max_events:
            self.shifts.append({"camera": cam, "frame": int(j), "dx": round(shift[0], 2),
                                     "dy": round(shift[1], 2)})



def _alike(moves: list, min_px: float = 2.0, spread_px: float = 1.5) -> bool:
    """At least two markers' moves from their predictions, of at least `min_px`, all within
    `spread_px` of their median: the view moved, or everything was carried alike."""
    if len(moves) < 2:
        return False
    mx, my = statistics.median(m[0] for m in moves), statistics.median(m[1] for m in moves)
    if math.hypot(mx, my) < min_px:
        return False
    return all(math.hypot(m[0] - mx, m[1] - my) <= spread_px for m in moves)


