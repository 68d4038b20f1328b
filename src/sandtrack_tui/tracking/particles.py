"""Every particle that looks like one seeded particle, tracked by detection in every frame and one
global assignment per frame (`sandtrack track PROJECT --auto-seed --all`).

The step, per camera and frame: detect (detect.py) -> predict (predict.py) -> assign (assign.py) ->
the detector's sub-pixel centre is the point. A track that is not seen coasts on its prediction
(`occluded`) for up to `memory` frames, then is `lost` and ends; a detection no track explains starts
a new particle with a new id when asked (`new_particles`: beads entering the view). A detection that
is two merged particles (detect.py) is neither's centre: a track on it is reported `occluded` (flagged)
and stays in doubt until a clear detection of its own; none starts a new particle. A merged blob the
detector resolved into its two particles gives two ordinary detections (`split`): seeds and tracks take
them, a new particle does not start on one (its identity is the fit's, not yet the motion's). Each camera is
tracked on its own; at the end of the run, pieces of one particle's track are joined across short gaps and
the tracks of two calibrated cameras are paired across the views (particle_joins.py), in the same edit.

`ParticleTracker` works on arrays and returns rows; `track_every_particle(project, ...)` seeds from the
project's seeded marker and writes every point in one undoable edit.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..corrections import MARKER_CAMERA_SETTINGS
from ..errors import SandtrackError
from . import predict as kf
from .assign import assign
from .detect import ParticleModel, detect, learn_particle
from .gaps import MAX_GAP_FRAMES
from .particle_joins import join_tracks
from .seeding import marker_box

TRACKED, OCCLUDED, LOST, MANUAL = "tracked", "occluded", "lost", "manual"
BOX_MARGIN_PX = 5.0  # marker_box: the marker and ~2.5 px of background each side
NEW_CLEAR_DIAMETERS = 0.5  # a new particle starts no nearer than this to a track's prediction
CONFIRM_FRAMES = 3  # a new particle's track is unsure (its velocity unknown) until seen this many frames
# A track in doubt (last seen on two merged particles) takes a detection only this many diameters nearer
# than any other: when the pair parts, the track on their common centre is as near to either.
LEAD_DIAMETERS = 0.5
# A track at rest (seeded or seen twice, slower than REST_DIAMETERS per frame) whose detection lies within
# REST_DIAMETERS of its prediction, every other detection and every other track's prediction three times
# that farther (assign.REST_CLEAR), keeps it whatever its gate: a marker at rest in a crowd whose track
# is back from a miss has a wide gate, and the margin rule finds rivals in it for nearly every such
# track; a neighbour most of a diameter away is none. (A track seen once has no measured velocity: a
# bead in flight seen once may have left its spot to the next one of a stream.)
REST_DIAMETERS = 0.25
# A track back from a miss or in doubt takes a detection no farther from its prediction than its own
# speed carried it over the frames since it was seen, or COAST_REACH diameters: its Kalman gate grows
# with every frame missed, and in a crowd a neighbour's detection then lies inside it.
COAST_REACH = 0.75
# A track at rest (its velocity measured: a seed's is not) takes no detection farther from its prediction
# than its speed and STILL_REACH diameters: after a miss its gate stays wide for some frames, and an
# overlapping neighbour's detection (0.5-0.75 diameter away) lies in it.
STILL_REACH = 0.4


@dataclass(frozen=True)
class ParticleParams:
    motion: kf.Motion = field(default_factory=kf.Motion)
    memory: int = 3  # frames a track coasts unseen before it is lost
    new_particles: bool = False


class ParticleTracker:
    """Tracks of one camera. `start(frame, image, seeds_xy, ids)` then `step(frame, image)` per frame;
    both return point rows (frame, marker, x_px, y_px, status, confidence)."""

    def __init__(self, model: ParticleModel, params: ParticleParams, next_id: int):
        self.model, self.params, self.next_id = model, params, next_id
        self.X = np.zeros((0, 4))
        self.P = np.zeros((0, 4, 4))
        self.ids = np.zeros(0, int)
        self.missed = np.zeros(0, int)
        self.seen_n = np.zeros(0, int)  # frames each track was seen since it started
        self.measured = np.zeros(0, bool)  # seen again since it started: its velocity is measured
        self.doubt = np.zeros(0, bool)  # last seen on a merged detection
        self.counts = {"seeded": 0, TRACKED: 0, OCCLUDED: 0, LOST: 0, "new": 0, "ambiguous": 0, "merged": 0}
        self.cpu_s = 0.0
        self.particle_frames = 0

    def detect(self, image) -> pd.DataFrame:
        return detect(image, self.model)

    def start(self, frame: int, image, seeds_xy: np.ndarray | None = None, ids=None, merged=None) -> list[tuple]:
        """Seeds: the given positions (`merged`: those that are detections of merged particles), or
        every detection of this frame."""
        c0 = time.process_time()
        if seeds_xy is None:
            det = self.detect(image)
            seeds_xy = det[["x_px", "y_px"]].to_numpy()
            conf = det.confidence.to_numpy()
            merged = det.merged.to_numpy()
        else:
            conf = np.full(len(seeds_xy), np.nan)
        if merged is None:
            merged = np.zeros(len(seeds_xy), bool)
        if ids is None:
            ids = np.arange(self.next_id, self.next_id + len(seeds_xy))
        ids = np.asarray(ids, int)
        self.next_id = max(self.next_id, int(ids.max()) + 1 if len(ids) else self.next_id)
        self._add(np.asarray(seeds_xy, float), ids)
        self.doubt[len(self.doubt) - len(ids):] = merged
        self.counts["seeded"] += len(ids)
        self.cpu_s += time.process_time() - c0
        self.particle_frames += len(ids)
        return [(frame, int(m), float(x), float(y), OCCLUDED if g else MANUAL, float(c))
                for m, (x, y), c, g in zip(ids, seeds_xy, conf, merged, strict=True)]

    def _add(self, xy: np.ndarray, ids: np.ndarray, seen_n: int = CONFIRM_FRAMES) -> None:
        X, P = kf.start(xy, self.params.motion)
        self.X = np.concatenate([self.X, X])
        self.P = np.concatenate([self.P, P])
        self.ids = np.concatenate([self.ids, ids])
        self.missed = np.concatenate([self.missed, np.zeros(len(ids), int)])
        self.seen_n = np.concatenate([self.seen_n, np.full(len(ids), seen_n)])
        self.measured = np.concatenate([self.measured, np.zeros(len(ids), bool)])
        self.doubt = np.concatenate([self.doubt, np.zeros(len(ids), bool)])

    def step(self, frame: int, image) -> list[tuple]:
        c0 = time.process_time()
        det = self.detect(image)
        dxy = det[["x_px", "y_px"]].to_numpy()
        conf = det.confidence.to_numpy()
        merged = det.merged.to_numpy()
        motion = self.params.motion
        X, P = kf.predict(self.X, self.P, motion)
        S, reach = kf.gate(P, motion)
        d = self.model.diameter_px
        speed = np.hypot(X[:, 2], X[:, 3])
        lapsed = ((self.missed > 0) | self.doubt) & (self.seen_n >= CONFIRM_FRAMES)
        reach = np.where(lapsed, np.minimum(reach, np.maximum(speed * (self.missed + 1), COAST_REACH * d)), reach)
        unsure = (self.missed > 0) | (self.seen_n < CONFIRM_FRAMES) | self.doubt
        still = (self.seen_n >= 2) & (speed <= REST_DIAMETERS * d)
        reach = np.where(still & self.measured, np.minimum(reach, speed + STILL_REACH * d), reach)
        taken, _cost, ambiguous = assign(S, X, reach, dxy, motion, unsure, self.doubt, LEAD_DIAMETERS * d,
                                         REST_DIAMETERS * d, still)
        seen = np.flatnonzero(taken >= 0)
        X, P = kf.update(X, P, seen, dxy[taken[seen]], motion)
        rows = []
        for k in seen:
            j = taken[k]
            rows.append((frame, int(self.ids[k]), float(dxy[j, 0]), float(dxy[j, 1]),
                         OCCLUDED if merged[j] else TRACKED, float(conf[j])))
        self.missed[seen] = 0
        self.seen_n[seen] += 1
        self.measured[seen] = True
        self.doubt[seen] = merged[taken[seen]]
        n_merged = int(merged[taken[seen]].sum())
        unseen = np.flatnonzero(taken < 0)
        self.missed[unseen] += 1
        self.counts["ambiguous"] += int(ambiguous.sum())
        ends = unseen[self.missed[unseen] > self.params.memory]
        coast = unseen[self.missed[unseen] <= self.params.memory]
        H, W = np.asarray(image).shape[:2]
        for k in coast:
            x, y = X[k, 0], X[k, 1]
            inside = 0 <= x < W and 0 <= y < H
            rows.append((frame, int(self.ids[k]), float(x) if inside else np.nan, float(y) if inside else np.nan,
                         OCCLUDED, np.nan))
        for k in ends:
            rows.append((frame, int(self.ids[k]), np.nan, np.nan, LOST, np.nan))
        self.counts[TRACKED] += len(seen) - n_merged
        self.counts["merged"] += n_merged
        self.counts[OCCLUDED] += len(coast) + n_merged
        self.counts[LOST] += len(ends)
        keep = np.ones(len(X), bool)
        keep[ends] = False
        self.X, self.P, self.ids = X[keep], P[keep], self.ids[keep]
        self.missed, self.seen_n, self.doubt = self.missed[keep], self.seen_n[keep], self.doubt[keep]
        self.measured = self.measured[keep]
        if self.params.new_particles:
            free = ~merged & ~det.split.to_numpy(bool)
            free[taken[taken >= 0]] = False
            rows += self._new(frame, dxy, conf, free)
        self.cpu_s += time.process_time() - c0
        self.particle_frames += len(seen)
        return rows

    def _new(self, frame: int, dxy: np.ndarray, conf: np.ndarray, free: np.ndarray) -> list[tuple]:
        """New tracks on the `free` detections (no track took them; not merged)."""
        if not free.any():
            return []
        cand = np.flatnonzero(free)
        if len(self.X):
            from scipy.spatial import cKDTree

            d, _ = cKDTree(self.X[:, :2]).query(dxy[cand])
            cand = cand[d > NEW_CLEAR_DIAMETERS * self.model.diameter_px]
        if len(cand) == 0:
            return []
        ids = np.arange(self.next_id, self.next_id + len(cand))
        self.next_id += len(cand)
        self._add(dxy[cand], ids, seen_n=1)
        self.counts["new"] += len(cand)
        return [(frame, int(m), float(dxy[j, 0]), float(dxy[j, 1]), TRACKED, float(conf[j]))
                for m, j in zip(ids, cand, strict=True)]


# -- the project -------------------------------------------------------------------------------
def seed_look(project, sources: dict, cams: list[str], like: int | None = None) -> dict:
    """Camera -> (ParticleModel, seed frame, seed x, y, marker) learnt from marker `like`'s first manual
    point in that camera (default: the lowest marker with one); a camera without one borrows another's
    model (its seed frame then is the other camera's frame number)."""
    pts = project.points()
    man = pts[(pts.status == MANUAL) & pts.x_px.notna()].sort_values(["marker", "frame"])
    if like is not None:
        man = man[man.marker == int(like)]
    if man.empty:
        raise SandtrackError("seed one particle first (a click in the TUI, or --seeds): every particle like it "
                             "is then found" if like is None else f"marker {like} has no manual point")
    marker = int(man.marker.iloc[0])
    man = man[man.marker == marker]
    boxes = project.get(MARKER_CAMERA_SETTINGS[0], {}) or {}
    out = {}
    for c in cams:
        rows = man[man.camera == c]
        if rows.empty:
            continue
        r = rows.iloc[0]
        img = sources[c].frame(int(r.frame))
        box = boxes.get(f"{marker}/{c}") or marker_box(img, float(r.x_px), float(r.y_px))
        if not box:
            raise SandtrackError(f"marker {marker} ({c}, frame {int(r.frame)}): no particle at its seed")
        diameter = max(min(box) - BOX_MARGIN_PX, 3.0)
        out[c] = (learn_particle(img, float(r.x_px), float(r.y_px), diameter), int(r.frame), float(r.x_px),
                  float(r.y_px), marker)
    first = next(iter(out.values()))
    for c in cams:
        if c not in out:
            out[c] = (first[0], first[1], np.nan, np.nan, None)
    return out


def track_every_particle(project, like: int | None = None, start: int | None = None, stop: int | None = None,
                         new_particles: bool = False, progress=None, params: ParticleParams | None = None,
                         sources: dict | None = None, should_stop=None, gap_closing: bool = True,
                         pairing: bool = True, max_gap: int = MAX_GAP_FRAMES) -> dict:
    """Seed every particle like the seeded marker `like` in frame `start` (each camera's own index;
    default: the seed's frame) and track them forward to `stop` (default: the end), per camera, into
    one undoable edit; then join pieces across gaps of up to `max_gap` frames and pair the tracks across
    two calibrated views (particle_joins.join_tracks). `should_stop()` true ends the run after the frame in
    hand: what was written stays, as the same one edit, without the joins. Returns the summary (per camera:
    seeded, tracked, new, flagged, timing; gaps closed; pairs)."""
    params = params or ParticleParams(new_particles=new_particles)
    if new_particles and not params.new_particles:
        params = ParticleParams(params.motion, params.memory, True)
    own = sources is None
    sources = sources or project.open_sources()
    try:
        cams = [c for c in project.cameras() if c in sources] or list(sources)
        looks = seed_look(project, sources, cams, like)
        existing = project.markers()
        pts = project.points()
        next_id = max([int(existing["id"].max()) if len(existing) else 0,
                       int(pts.marker.max()) if len(pts) else 0]) + 1
        summary = {"mode": "every particle", "cameras": {}, "new_particles": params.new_particles,
                   "rows_written": 0, "stopped": False}
        runs, run_ids = {}, set()
        total = {c: len(sources[c]) for c in cams}
        with project.edit("track every particle", sync_each_write=False) as ed:
            for c in cams:
                if summary["stopped"]:
                    break
                model, f_seed, sx, sy, marker = looks[c]
                f0 = f_seed if start is None else int(start)
                last = total[c] - 1 if stop is None else min(int(stop), total[c] - 1)
                if not 0 <= f0 <= last:
                    raise SandtrackError(f"{c}: start frame {f0} outside 0..{last}")
                t = ParticleTracker(model, params, next_id)
                img = sources[c].frame(f0)
                det = t.detect(img)
                xy = det[["x_px", "y_px"]].to_numpy()
                ids = np.arange(next_id, next_id + len(xy))
                if marker is not None and f0 == f_seed and len(xy):
                    # the seeded particle keeps its marker id
                    d = np.hypot(xy[:, 0] - sx, xy[:, 1] - sy)
                    k = int(np.argmin(d))
                    if d[k] <= model.diameter_px / 2:
                        ids[k] = marker
                rows = t.start(f0, img, xy, ids, det.merged.to_numpy())
                buf = [_point(c, r) for r in rows if not (r[1] == marker and r[0] == f_seed)]
                for i in range(f0 + 1, last + 1):
                    if should_stop is not None and should_stop():
                        summary["stopped"] = True
                        last = i - 1
                        break
                    buf += [_point(c, r) for r in t.step(i, sources[c].frame(i))]
                    if len(buf) > 20000:
                        run_ids |= {p[2] for p in buf}
                        ed.add_markers({p[2] for p in buf})
                        summary["rows_written"] += ed.write(buf)
                        buf = []
                    if progress is not None:
                        progress(i - f0, last - f0)
                run_ids |= {p[2] for p in buf}
                ed.add_markers({p[2] for p in buf})
                summary["rows_written"] += ed.write(buf)
                next_id = t.next_id
                runs[c] = (f0, last, model.diameter_px)
                n_frames = last - f0 + 1
                summary["cameras"][c] = {
                    "first_frame": f0, "last_frame": last, "frames": n_frames, **t.counts,
                    "particles": int(t.counts["seeded"] + t.counts["new"]),
                    "flagged": int(t.counts[OCCLUDED] + t.counts[LOST]),
                    "cpu_ms_per_particle_frame": round(1000 * t.cpu_s / max(t.particle_frames, 1), 4),
                    "look": model.describe()}
            if not summary["stopped"] and (gap_closing or pairing):
                summary["joins"] = join_tracks(project, ed, runs, run_ids, gap_closing, pairing, max_gap)
        summary["frames"] = max((v["frames"] for v in summary["cameras"].values()), default=0)
        return summary
    finally:
        if own:
            for s in sources.values():
                close = getattr(s, "close", None)
                if close:
                    close()


def _point(camera: str, r: tuple) -> tuple:
    frame, marker, x, y, status, conf = r
    return (int(frame), camera, int(marker), None if not np.isfinite(x) else x, None if not np.isfinite(y) else y,
            status, None if not np.isfinite(conf) else conf, None, None)
