"""The step's last stage: every track stepping this frame commits its status and point (MarkerTrack.apply:
the proposal's match refined and checked, or coasting), the operator's points are taken as they are, and
the crowd's tracks remember where they were (crowd_passes.py)."""

from __future__ import annotations

from .crowd_passes import CrowdPasses
from .tracker import Observation
from .trackset import TrackSet


def commit(frames, live: dict, props: dict, forced: dict, trackset: TrackSet, crowd: CrowdPasses) -> list[Observation]:
    obs: list[Observation] = []
    for cam, (j, img, _rem) in frames.items():
        for t in live[cam]:
            p = props.get((t.marker, cam))
            obs.append(t.apply(j, img, p.match if p else None, reattach=bool(p and p.reattach),
                               jump=bool(p and p.jump)))
            if t.model.crowd:
                crowd.remember((t.marker, cam), int(j), (p.match.x, p.match.y) if p else None)
    for key, (x, y) in forced.items():
        t = trackset.tracks[key]
        obs.append(t.set_manual(frames[t.camera][0], None, x, y))
        if t.model.crowd:
            crowd.remember(key, int(frames[t.camera][0]), (float(x), float(y)))
    return obs
