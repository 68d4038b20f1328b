"""The tracks one engine steps (a MarkerTrack per marker and camera), grouped by camera, and how each
marker's two views pair across the stereo cameras: the same marker's, or a crowd track paired with one
of the other view by their points (crowd_passes.py). What a step found so far is plain data beside it:
`props` ((marker, camera) -> matcher.Proposal) and `forced` ((marker, camera) -> (x, y), the operator's).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .stereo import StereoCheck
from .tracker import MarkerTrack


@dataclass
class TrackSet:
    """One engine's tracks, by camera, and each marker's other view."""

    stereo: StereoCheck | None = None
    direction: int = 1  # +1 forward, -1 backward
    tracks: dict = field(default_factory=dict)  # (marker, camera) -> MarkerTrack
    start: dict = field(default_factory=dict)  # (marker, camera) -> seed frame
    # Crowd tracks seeded in one view each, paired across the views by their points (crowd_passes.py):
    partners: dict = field(default_factory=dict)  # crowd track key -> the key of the same bead in the other view
    _by_camera: dict | None = None  # camera -> [(key, track, start frame)], in the order of `tracks`
    _crowd_cams: set = field(default_factory=set)  # cameras with a crowd track (kept with _by_camera)
    _both_cache: tuple | None = None

    def add(self, track: MarkerTrack, start_frame: int) -> None:
        self.tracks[(track.marker, track.camera)] = track
        self.start[(track.marker, track.camera)] = start_frame
        self._by_camera = None

    def of_camera(self, cam: str) -> list:
        """[(key, track, start frame)] of camera `cam`, in the order the tracks were added."""
        if self._by_camera is None:
            groups: dict = {}
            for key, t in self.tracks.items():
                groups.setdefault(t.camera, []).append((key, t, self.start[key]))
            self._by_camera = groups
            self._crowd_cams = {t.camera for t in self.tracks.values() if t.model.crowd}
        return self._by_camera.get(cam, [])

    def has_crowd(self, cam: str) -> bool:
        """Any track of `cam` among touching lookalikes (the crowd passes have nothing to do otherwise)."""
        return cam in self._crowd_cams

    def other_view(self, key):
        """The key of the same marker in the stereo pair's other camera: the same marker's, or the crowd
        track paired with it; None."""
        other = (key[0], self.stereo.other(key[1]))
        return other if other in self.tracks else self.partners.get(key)

    def point_at(self, key, frames, props, forced):
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

    def stereo_pairs(self, a, b) -> list:
        """[(key in a, key in b)] of the markers tracked in both cameras, sorted, then the crowd tracks
        paired across them (kept until the set of tracks or of pairs changes)."""
        c = self._both_cache
        if c is None or c[0] != (a, b, len(self.tracks), len(self.partners)):
            ms = sorted({m for (m, k) in self.tracks if k == a} & {m for (m, k) in self.tracks if k == b})
            crowd = sorted((ka, kb) for ka, kb in self.partners.items() if ka[1] == a)
            c = self._both_cache = ((a, b, len(self.tracks), len(self.partners)),
                                    [((m, a), (m, b)) for m in ms] + crowd)
        return c[1]


def explained_points(cam, props, forced) -> list:
    """[(x, y)] of this step's proposals and operator's points in camera `cam`."""
    return [(p.match.x, p.match.y) for k, p in props.items() if k[1] == cam] + \
        [xy for k, xy in forced.items() if k[1] == cam]


class OnTracks:
    """What a stage of the engine's step reads of its TrackSet by name: the tracks, their pairs across the
    views, the stereo check and the direction (the stage holds the TrackSet, never a copy)."""

    def __init__(self, trackset: TrackSet):
        self.trackset = trackset

    @property
    def stereo(self):
        return self.trackset.stereo

    @property
    def tracks(self) -> dict:
        return self.trackset.tracks

    @property
    def partners(self) -> dict:
        return self.trackset.partners

    @property
    def direction(self) -> int:
        return self.trackset.direction
