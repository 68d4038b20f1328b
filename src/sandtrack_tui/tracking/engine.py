"""All markers in all cameras, one time step at a time: the step as the list of its stages.

1. predict (motion.py): every track's Kalman prediction; the seeds' and the operator's own points.
2. search (search.py), per camera: every track proposes its best gated match (MarkerTrack.propose: the
   template's peak and colour centroid, matcher.py, refined by the marker's brightness between intra frames,
   refine.py, or by a crowd bead's highlight, highlight.py); among touching markers only a match clearly
   its own stands; when most tracks of a camera leave their gates at once and the whole view moved
   (globalmotion.py), every track of that camera is moved with it and searched again (motion.ViewFollower);
   two tracks claiming one spot keep only the better (matching.py); touching lookalikes (a crowd) must move
   with their neighbours and with the image (crowd_passes.py).
3. verify (verify.py): with a calibration, a marker's proposals in the two cameras lie on each other's
   epipolar lines, or the suspect view is dropped and flagged.
4. re-acquire (reattach.py): coasting tracks look for unexplained blobs (along the epipolar band when
   the other view is tracked; a brightness model's marker also by its template or its look on the other
   view's line, line_search.py); the crowd's own passes give missed beads back (crowd_passes.py);
   whatever came back is verified across the views again; a brightness model's marker still followed
   that nothing measured is placed by its look where it shows whole (in both views only where they agree).
5. commit (commit.py): every track commits its status and its refined point for the frame
   (MarkerTrack.apply).
6. pair (pairing.py): crowd tracks seeded in one view each are paired across the views once their points
   tell who is who (the run makes each pair one marker at its end: run._merge_pairs).
Between the stages the step's findings are plain data: `live` (camera -> [MarkerTrack] stepping this
frame), `props` ((marker, camera) -> matcher.Proposal), `forced` ((marker, camera) -> (x, y), the
operator's points).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from . import motion, search, verify
from .commit import commit
from .crowd_passes import CrowdPasses
from .events import AmbiguityLog
from .line_search import LineSearch
from .matcher import Proposal
from .matching import BlobAssigner, resolve_conflicts
from .pairing import CrowdPairing
from .reattach import Reacquisition
from .stereo import StereoCheck
from .tracker import MarkerTrack, Observation
from .trackset import TrackSet


@dataclass
class Engine:
    stereo: StereoCheck | None = None
    direction: int = 1  # +1 forward, -1 backward
    stereo_flags: list = field(default_factory=list)
    max_events: int = 500
    ambiguity_d2: float = 6.0
    crowd_factor: float = 1.4  # tracks closer than this x (r1 + r2) are "touching"
    crowded_min_score: float = 0.8
    crowded_max_colour: float = 1.4
    follow_view: bool = True  # estimate the view's motion when most tracks of a camera lose their gates

    def __post_init__(self) -> None:
        self.trackset = TrackSet(self.stereo, self.direction)
        self.crowded = search.Crowded(self.crowd_factor, self.crowded_min_score, self.crowded_max_colour)
        self.log = AmbiguityLog(self.max_events)
        self.view = motion.ViewFollower(self.max_events)
        self.lines = LineSearch(self.trackset)
        self.crowd = CrowdPasses(self.trackset, self.log)
        self.pairing = CrowdPairing(self.trackset)
        self.assigner = BlobAssigner(self.trackset, self.log, self.ambiguity_d2)
        self.reacquisition = Reacquisition(self.trackset, self.lines, self.crowd, self.assigner)

    @property
    def tracks(self) -> dict:
        """(marker, camera) -> MarkerTrack."""
        return self.trackset.tracks

    @property
    def partners(self) -> dict:
        return self.trackset.partners

    @property
    def pairings(self) -> list:
        return self.pairing.pairings

    @property
    def ambiguous(self) -> list:
        return self.log.records

    @property
    def view_shifts(self) -> list:
        return self.view.shifts

    def add(self, track: MarkerTrack, start_frame: int) -> None:
        self.trackset.add(track, start_frame)

    def step(self, frames: dict, manual: dict | None = None) -> list[Observation]:
        """frames: camera -> (frame index, BGR image, remainder in frames of the wanted time);
        manual: (marker, camera, frame) -> (x, y) operator points to trust along the way."""
        obs, live, forced = motion.predict(self.trackset, frames, manual or {})
        props: dict[tuple, Proposal] = {}
        for cam, (j, img, _rem) in frames.items():
            self._search(cam, j, img, live[cam], props)
        if self.stereo is not None:
            verify.stereo_check(self.trackset, frames, props, forced, False, self.stereo_flags, self.max_events)
        self._reacquire(frames, live, props, forced)
        obs += commit(frames, live, props, forced, self.trackset, self.crowd)
        if self.stereo is not None:
            self.pairing.pair(frames, obs)
        return obs

    def _search(self, cam, j, img, tracks: list, props: dict) -> None:
        """Stage 2 in camera `cam`: the gated matches, the view's motion, one marker per spot, the crowd's checks."""
        near = search.gated(cam, j, img, tracks, props, self.crowded)
        if self.follow_view:
            self.view.follow(cam, j, img, tracks, props, self.crowded)
        resolve_conflicts(tracks, props)
        if self.trackset.has_crowd(cam):
            self.crowd.coherence(tracks, props, near)
            self.crowd.flow_check(cam, img, tracks, props)

    def _reacquire(self, frames, live: dict, props: dict, forced: dict) -> None:
        """Stage 4: what the gated search missed, given back (each pass leaves no clash behind), verified
        across the views again, then the brightness models' looks."""
        reattached = 0
        for cam, (_j, img, _rem) in frames.items():
            if self.reacquisition.run(cam, img, live[cam], props, forced, frames):
                reattached += 1
                resolve_conflicts(live[cam], props)
                if self.trackset.has_crowd(cam):
                    self.crowd.coherence(live[cam], props, self.crowded.neighbours(live[cam]))
        if self.stereo is not None and reattached:
            for cam, (_j, img, _rem) in frames.items():
                if self.lines.late_lines(cam, img, live[cam], props, forced, frames):
                    resolve_conflicts(live[cam], props)
        for cam, (j, img, _rem) in frames.items():
            if self.trackset.has_crowd(cam):
                reattached += self.crowd.passes(cam, img, int(j), live[cam], props, forced, frames)
            self.crowd.prev_frames[cam] = img
        if self.stereo is not None and reattached:
            verify.stereo_check(self.trackset, frames, props, forced, True, self.stereo_flags, self.max_events)
        self.lines.looks(frames, live, props, forced)
