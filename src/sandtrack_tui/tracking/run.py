"""Project-level tracking API used by the CLI, the TUI and the demo.

- `auto_seed(project, frame)`: propose every marker of a frame that looks like the seeded one (or
  every blue marker), paired across cameras.
- `accept_seeds(project, seeds)`: write the accepted proposal as markers and "manual" points.
- `seed_marker(project, marker, camera, frame, x, y, w, h)`: one operator seed (a click).
- `track_project(project, ...)`: track forward or backward from the seeds (or from any frame:
  re-tracking after a correction is tracking from that frame), writing results to the store
  as they are made, in chunks, inside one undoable edit; touching lookalikes seeded in one view
  each that the run tells to be one bead (CrowdPairing.pair) become one marker in that edit.

Frame indices are each camera's own. The cameras are stepped together on the first camera's
clock ("side"): side frame i pairs with the front frame nearest to side time t - sync_offset_s
(the front started offset_s later), and the front point is shifted by its velocity times the
sub-frame remainder before the epipolar check.
"""

from __future__ import annotations

import sys
import time

import numpy as np
import pandas as pd

from ..corrections import MARKER_CAMERA_SETTINGS, merge_in_edit
from ..errors import SandtrackError
from ..video import camera_offsets as video_offsets
from . import identity
from .appearance import KINDS
from .chroma import Chroma420Frame, block_replicated
from .decoding import prefetch
from .engine import Engine
from .learning import learn
from .luma import intra_frames
from .seeding import detect_markers, marker_box, marker_look, pair_by_epipolar, snap_to_marker
from .stereo import StereoCheck
from .tracker import DEFAULT_BOX_PX, LOST, MANUAL, OCCLUDED, TRACKED, MarkerTrack, TrackParams

__all__ = ["auto_seed", "accept_seeds", "seed_marker", "track_project", "snap_to_marker", "marker_look", "SEED_COLUMNS"]

SEED_COLUMNS = ["marker", "camera", "frame", "x_px", "y_px", "w", "h", "epipolar_px"]
# auto-seed matches blobs to markers known this many frames before or after the seeded frame
MATCH_WINDOW_FRAMES = 500
BOXES_KEY, KINDS_KEY = MARKER_CAMERA_SETTINGS  # {"MARKER/CAMERA": box [w, h] px}, {...: appearance model kind}
_USABLE = (MANUAL, TRACKED, "interpolated", "imported")
# Frame cache per camera when track_project opens the videos itself: tracking reads each frame
# once, in either direction (decoding.py reads backward group by group), so the cache only spares
# re-decoding the seed frames.
TRACKING_CACHE_MB = 48
BATCH_STEPS = 4  # steps tracked in one run once their frames are decoded (decoding.py)


# -- clocks and pairing -----------------------------------------------------------------------
def camera_offsets(project, cameras: list[str]) -> dict[str, float]:
    """Offset (s) of each camera's clock behind the first camera's: event at t is at t - offset."""
    return video_offsets(cameras, project.sync_offset_s)


def paired_frame(sources: dict, offsets: dict, ref: str, ref_index: int, cam: str):
    """(frame index, remainder in frames) of `cam` at the time of ref frame `ref_index`, or None."""
    src = sources[cam]
    t = float(sources[ref].times_s[ref_index]) - offsets[cam]
    j = src.index_at(t)
    fps = float(getattr(src, "fps", 50.0))
    rem = (t - float(src.times_s[j])) * fps
    if abs(rem) > 0.5 + 1e-6:
        return None
    return j, rem


def _ref_index_of(sources, offsets, ref, cam, frame) -> int:
    t = float(sources[cam].times_s[frame]) + offsets[cam]
    return sources[ref].index_at(t)


def _stereo_for(project, cameras, params_px=(2.0, 3.0)) -> StereoCheck | None:
    if len(cameras) < 2:
        return None
    cal = project.calibration()
    if cal is None or not all(c in cal.cameras for c in cameras[:2]):
        return None
    return StereoCheck(cal, cameras[0], cameras[1], *params_px)


# -- seeding ----------------------------------------------------------------------------------
def first_common_frame(sources: dict, offsets: dict, ref: str) -> int:
    """First frame of the first camera that every other camera also recorded (0 if none does)."""
    for i in range(len(sources[ref])):
        if all(paired_frame(sources, offsets, ref, i, c) is not None for c in sources if c != ref):
            return i
    return 0


def auto_seed(project, frame: int | None = 0, sources: dict | None = None,
              max_epipolar_px: float = 5.0, like: int | None = None) -> pd.DataFrame:
    """Every marker in `frame` (first camera's index; the others at the paired frame; None = the
    first frame all cameras recorded) that looks like marker `like` (default: the project's first
    marker with a manual point; with none, every blue marker), paired across cameras by epipolar
    distance when the project holds a calibration (not markers like one among touching markers: a
    dense layer's beads lie a bead apart along any epipolar line). A proposal only: nothing is
    written. Unpaired detections get their own proposal (epipolar_px NaN). A proposal that is a marker the project
    already has (identity.py: where the marker is in this frame, or was last seen) takes its id
    (`existing` True, `match_px` the distance); the rest are numbered after the highest id in use.
    Also `model`, `contrast`: the appearance model each proposed seed gets (appearance.py) and the
    contrast it measured."""
    own = sources is None
    sources = sources or project.open_sources()
    try:
        cams = [c for c in project.cameras() if c in sources] or list(sources)
        ref = cams[0]
        offsets = camera_offsets(project, cams)
        if frame is None:
            frame = first_common_frame(sources, offsets, ref)
        if not 0 <= frame < len(sources[ref]):
            raise SandtrackError(f"frame {frame} outside 0..{len(sources[ref]) - 1}")
        dets, frames, images = {}, {}, {}
        models = reference_models(project, sources, cams, like)
        for c in cams:
            pf = (frame, 0.0) if c == ref else paired_frame(sources, offsets, ref, frame, c)
            if pf is None:
                continue
            frames[c] = pf[0]
            images[c] = sources[c].frame(pf[0])
            dets[c] = detect_markers(images[c], model=models.get(c))
        rows = []
        proposal = 1
        stereo = _stereo_for(project, cams)
        used = {c: set() for c in dets}
        # Markers among touching ones like them lie a bead apart along any epipolar line, and in a
        # slanted view partly hide each other: which blob pairs with which is not known from one frame.
        crowd = any(m.crowd for m in models.values())
        if stereo is not None and all(c in dets for c in stereo.cams) and not crowd:
            a, b = stereo.cams
            pairs = pair_by_epipolar(stereo, dets[a], dets[b], max_epipolar_px)
            pairs.sort(key=lambda p: (dets[a].x_px.iloc[p[0]], dets[a].y_px.iloc[p[0]]))
            for ia, ib, d in pairs:
                for c, i in ((a, ia), (b, ib)):
                    r = dets[c].iloc[i]
                    rows.append((proposal, c, frames[c], r.x_px, r.y_px, r.w, r.h, d))
                    used[c].add(i)
                proposal += 1
        for c, det in dets.items():
            order = det.sort_values(["x_px", "y_px"]).index
            for i in order:
                if i in used[c]:
                    continue
                r = det.loc[i]
                rows.append((proposal, c, frames[c], r.x_px, r.y_px, r.w, r.h, np.nan))
                proposal += 1
        proposals = pd.DataFrame(rows, columns=SEED_COLUMNS)
        looks = [_appearance_at(images[r.camera], r.x_px, r.y_px, r.w, r.h, models.get(r.camera))
                 for r in proposals.itertuples()]
        proposals["model"] = [a[0] for a in looks]
        proposals["contrast"] = [a[1] for a in looks]
        if models:  # like a seeded marker: a detection whose own box shows no marker is not one
            proposals = proposals[proposals["model"] != "none"].reset_index(drop=True)
        existing = project.markers()
        next_id = int(existing["id"].max()) + 1 if len(existing) else 1
        points = pd.concat([project.points(camera=c, frames=(f - MATCH_WINDOW_FRAMES, f + MATCH_WINDOW_FRAMES))
                            for c, f in frames.items()], ignore_index=True)
        if len(points):
            next_id = max(next_id, int(points["marker"].max()) + 1)
        matches = identity.match_proposals(proposals, identity.known_positions(points, frames))
        return identity.number_proposals(proposals, matches, next_id)
    finally:
        if own:
            _close(sources)


def _appearance_at(img, x: float, y: float, w: float, h: float, like=None) -> tuple[str, float]:
    """(model kind, contrast) the tracker learns from this seed box (like the model `like`);
    ("none", NaN) if it learns none."""
    try:
        d = learn(img, x, y, w, h, kind=None if like is None else like.kind, like=like).describe()
    except SandtrackError:
        return "none", float("nan")
    return d["model"], d["contrast"]


def reference_models(project, sources: dict, cams: list[str], like: int | None = None) -> dict:
    """Camera -> the appearance model of marker `like` (default: the lowest marker id with a manual
    point), learned at its first manual point in that camera, or in another camera when that one has
    none or its seed shows no marker; {} when there is no such marker (SandtrackError when `like` has
    no manual point, or none of its seeds shows a marker)."""
    pts = project.points()
    man = pts[(pts.status == MANUAL) & pts.x_px.notna()].sort_values(["marker", "frame"])
    if like is not None:
        man = man[man.marker == int(like)]
        if man.empty:
            raise SandtrackError(f"marker {like} has no manual point to learn its appearance from")
    if man.empty:
        return {}
    marker = int(man.marker.iloc[0])
    man = man[man.marker == marker]
    boxes = project.get(BOXES_KEY, {}) or {}
    models, failed = {}, ""
    for c in cams:
        rows = man[man.camera == c]
        if rows.empty or c not in sources:
            continue
        r = rows.iloc[0]
        img = sources[c].frame(int(r.frame))
        box = boxes.get(f"{marker}/{c}") or marker_box(img, r.x_px, r.y_px) or (DEFAULT_BOX_PX, DEFAULT_BOX_PX)
        try:
            models[c] = learn(img, float(r.x_px), float(r.y_px), box[0], box[1])
        except SandtrackError as exc:
            failed = f"marker {marker} ({c}, frame {int(r.frame)}): {exc}"
    if not models:
        if failed:
            raise SandtrackError(failed)
        return {}
    for c in cams:
        models.setdefault(c, next(iter(models.values())))
    return models


def _reference_or_none(project, sources: dict, cams: list[str]) -> dict:
    """reference_models, or {} when the marker they come from shows none."""
    try:
        return reference_models(project, sources, cams)
    except SandtrackError:
        return {}


def accept_seeds(project, seeds: pd.DataFrame, description: str = "accept seeds") -> int:
    """Write seeds (SEED_COLUMNS; epipolar_px optional) as markers and manual points. Returns rows."""
    if seeds is None or len(seeds) == 0:
        return 0
    missing = {"marker", "camera", "frame", "x_px", "y_px"} - set(seeds.columns)
    if missing:
        raise SandtrackError(f"seeds lack columns: {', '.join(sorted(missing))}")
    have = set(project.markers()["id"].astype(int))
    for m in sorted(set(seeds["marker"].astype(int)) - have):
        project.add_marker(str(m), int(m))
    rows = [(int(r.frame), str(r.camera), int(r.marker), float(r.x_px), float(r.y_px), MANUAL, None, None, None)
            for r in seeds.itertuples()]
    project.set_points(rows, description)
    _store_boxes(project, seeds)
    _store_kinds(project, seeds)
    return len(rows)


def _store_boxes(project, seeds: pd.DataFrame) -> None:
    if "w" not in seeds.columns or "h" not in seeds.columns:
        return
    boxes = dict(project.get(BOXES_KEY, {}) or {})
    changed = False
    for r in seeds.itertuples():
        if np.isfinite(r.w) and np.isfinite(r.h) and r.w > 0 and r.h > 0:
            k = f"{int(r.marker)}/{r.camera}"
            v = [float(r.w), float(r.h)]
            if boxes.get(k) != v:
                boxes[k] = v
                changed = True
    if changed:
        project.set(BOXES_KEY, boxes, "marker box sizes")


def _store_kinds(project, seeds: pd.DataFrame) -> None:
    """The appearance model auto-seed proposed for each seed (the one of the marker it is like): the
    tracker learns that kind first (learning.learn)."""
    if "model" not in seeds.columns:
        return
    kinds = dict(project.get(KINDS_KEY, {}) or {})
    new = {f"{int(r.marker)}/{r.camera}": str(r.model) for r in seeds.itertuples() if str(r.model) in KINDS}
    if any(kinds.get(k) != v for k, v in new.items()):
        kinds.update(new)
        project.set(KINDS_KEY, kinds, "marker appearance models")


def seed_marker(project, marker: int, camera: str, frame: int, x: float, y: float, w: float | None = None,
                h: float | None = None) -> None:
    """One operator seed: marker `marker` at (x, y) px in `camera`'s frame `frame` (a manual point)."""
    vids = project.videos()
    if camera not in vids:
        raise SandtrackError(f"no camera {camera!r} in this project ({', '.join(vids) or 'none'})")
    v = vids[camera]
    if not 0 <= frame < v.frames:
        raise SandtrackError(f"frame {frame} outside 0..{v.frames - 1} of {camera}")
    if not (np.isfinite(x) and np.isfinite(y)) or not (0 <= x < v.width and 0 <= y < v.height):
        raise SandtrackError(f"seed ({x}, {y}) lies outside the {v.width}x{v.height} image of {camera}")
    if w is not None and h is not None and (not w > 0 or not h > 0):
        raise SandtrackError(f"seed box {w}x{h} is empty")
    df = pd.DataFrame([(int(marker), camera, int(frame), float(x), float(y),
                        np.nan if w is None else float(w), np.nan if h is None else float(h), np.nan)],
                      columns=SEED_COLUMNS)
    accept_seeds(project, df, f"seed marker {marker} in {camera} at frame {frame}")


# -- tracking ---------------------------------------------------------------------------------
def _close(sources):
    for s in sources.values():
        close = getattr(s, "close", None)
        if close:
            close()


def _find_seeds(project, points: pd.DataFrame, markers, cams, sources, offsets, ref, start, direction):
    """Per (marker, camera): (frame, x, y) to start from; problems for those without one; and the
    markers of one camera only (never placed in the other: e.g. auto-seeded among touching lookalikes,
    which are not paired across cameras), which are no problem."""
    seeds, problems, one_camera = {}, [], set()
    have = points[points.x_px.notna()]
    placed = set(zip(points.marker.astype(int), points.camera, strict=True))
    if start is None:  # each track's first (last, backward) manual point
        found = {}
        for r in have[have.status == MANUAL].sort_values("frame").itertuples(index=False):
            key = (int(r.marker), r.camera)
            if direction < 0 or key not in found:
                found[key] = r
    else:  # each track's usable point at the paired frame of `start`
        found, at = {}, {}
        for c in cams:
            pf = (start, 0.0) if c == ref else paired_frame(sources, offsets, ref, start, c)
            at[c] = None if pf is None else pf[0]
            if pf is not None:
                rows = have[(have.camera == c) & (have.frame == pf[0]) & have.status.isin(_USABLE)]
                found.update(((int(r.marker), c), r) for r in rows.itertuples(index=False))
    for m in markers:
        for c in cams:
            r = found.get((m, c))
            if r is None:
                if (m, c) not in placed and any((m, o) in found for o in cams):
                    one_camera.add(m)
                elif start is None:
                    problems.append(f"marker {m} {c}: no seed (manual point)")
                elif at[c] is None:
                    problems.append(f"marker {m} {c}: frame {start} has no paired {c} frame")
                else:
                    problems.append(f"marker {m} {c}: no point at frame {at[c]} to start from")
                continue
            seeds[(m, c)] = (int(r.frame), float(r.x_px), float(r.y_px))
    return seeds, problems, sorted(one_camera)


def _merge_pairs(project, ed, engine: Engine, problems: list) -> list[dict]:
    """The crowd tracks the engine paired across the views (Engine.pairings: beads seeded in one view
    each) made one marker, in the run's edit `ed`: the first camera's marker keeps its id, the other
    view's points (and its box and appearance model) move to it (corrections.merge_in_edit). Two markers
    that both have points in one camera (placed there before this run) are left apart, with a problem
    line. Returns [{marker, from, camera, frames_on_line, frame}] of the merges made."""
    if not engine.pairings:
        return []
    points = project.points()
    cams_of = points.groupby("marker")["camera"].agg(set).to_dict()
    out = []
    for (keep, _), (drop, cam), together, frame in engine.pairings:
        shared = cams_of.get(keep, set()) & cams_of.get(drop, set())
        if shared:
            problems.append(f"marker {keep} and marker {drop} ({cam}) are one bead by their tracks, but both have "
                            f"points in {', '.join(sorted(shared))}: left apart (merge them by hand if right)")
            continue
        out.append({"marker": int(keep), "from": int(drop), "camera": cam, "frames_on_line": int(together),
                    "frame": int(frame)})
    if out:
        merge_in_edit(project, ed, [(p["marker"], p["from"]) for p in out])
    return out


def track_project(project, markers=None, start: int | None = None, stop: int | None = None,
                  direction: str = "forward", progress=None, should_stop=None, sources: dict | None = None,
                  params: TrackParams | None = None, chunk_steps: int = 25, epipolar_px: float = 2.0,
                  band_px: float = 3.0) -> dict:
    """Track markers from their seeds (or from frame `start`, first camera's index) to `stop`
    (inclusive; default: the end in that direction). Results go to the store as they are made.
    Markers of one camera each whose tracks the engine paired across the views (one bead: CrowdPairing.pair)
    are merged into the first camera's marker at the end, as part of the same edit (`paired_across_views`).
    Returns a summary dict (counts per marker and camera, stereo flags, ambiguities, problems, pairs)."""
    if direction not in ("forward", "backward"):
        raise SandtrackError(f"direction must be forward or backward, not {direction!r}")
    dirn = 1 if direction == "forward" else -1
    own = sources is None
    sources = sources or project.open_sources(cache_mb=TRACKING_CACHE_MB)
    feeds_list: list = []
    # The decoder threads need the GIL briefly for every frame; with the default 5 ms switch
    # interval they queue behind the tracking thread and decoding slows down a lot. 2 ms keeps
    # decoding as fast as 0.5 ms did, with fewer forced hand-overs (~3 % less process CPU).
    switch = sys.getswitchinterval()
    sys.setswitchinterval(min(switch, 0.002))
    try:
        cams = [c for c in project.cameras() if c in sources] or list(sources)
        ref = cams[0]
        offsets = camera_offsets(project, cams)
        n_ref = len(sources[ref])
        for name, v in (("start", start), ("stop", stop)):
            if v is not None and not 0 <= v < n_ref:
                raise SandtrackError(f"{name} frame {v} outside 0..{n_ref - 1}")
        all_markers = [int(m) for m in project.markers()["id"]]
        points = project.points()
        if markers is None:
            markers = sorted(set(all_markers) | set(points.marker.astype(int)))
        markers = [int(m) for m in markers]
        unknown = [m for m in markers if m not in all_markers and m not in set(points.marker)]
        if unknown:
            raise SandtrackError(f"unknown marker(s): {', '.join(map(str, unknown))}")
        seeds, problems, one_camera = _find_seeds(project, points, markers, cams, sources, offsets, ref, start, dirn)
        summary = {"direction": direction, "cameras": cams, "markers": markers, "problems": problems,
                   "one_camera_markers": one_camera, "paired_across_views": [],
                   "stereo": False, "rows_written": 0, "stopped": False, "per_marker": {}}
        for c in cams:
            if getattr(sources[c], "truncated", False):
                problems.append(f"{c} video is cut short: only its frames 0..{len(sources[c]) - 1} can be decoded; "
                                f"{c} is tracked up to there")
        if not seeds:
            summary.update(frames=0, status="nothing to track")
            return summary
        # Range on the first camera's clock.
        seed_ref = [_ref_index_of(sources, offsets, ref, c, f) for (m, c), (f, _, _) in seeds.items()]
        a = start if start is not None else (min(seed_ref) if dirn > 0 else max(seed_ref))
        b = stop if stop is not None else (n_ref - 1 if dirn > 0 else 0)
        if dirn * (b - a) < 0:
            raise SandtrackError(f"stop frame {b} lies {'before' if dirn > 0 else 'after'} the start frame {a}")
        steps = []
        last = {c: None for c in cams}
        for i in range(a, b + dirn, dirn):
            st = {}
            for c in cams:
                pf = (i, 0.0) if c == ref else paired_frame(sources, offsets, ref, i, c)
                if pf is None or pf[0] == last[c]:
                    continue
                last[c] = pf[0]
                st[c] = pf
            steps.append(st)
        # Decoding starts now, while the tracks are set up (their seed frames come from the same
        # sources, which hand them over under a lock; frames decoded first are cached for the other).
        feeds_list = [prefetch(sources[c], [st[c][0] for st in steps if c in st]) for c in cams]
        stereo = _stereo_for(project, cams, (epipolar_px, band_px))
        summary["stereo"] = stereo is not None
        engine = Engine(stereo=stereo, direction=dirn)
        boxes = project.get(BOXES_KEY, {}) or {}
        kinds = project.get(KINDS_KEY, {}) or {}
        refs = _reference_or_none(project, sources, cams) if kinds else {}
        params = params or TrackParams()
        # Decoded 4:2:0 video, on request: windows read with the colour re-interpolated (chroma.py).
        wrap = {}
        for (m, c), (f, x, y) in sorted(seeds.items(), key=lambda kv: (kv[0][1], kv[1][0])):
            img = sources[c].frame(f)
            if c not in wrap:
                wrap[c] = params.chroma_siting if params.chroma_siting and block_replicated(img) else None
            box = boxes.get(f"{m}/{c}") or marker_box(img, x, y) or (DEFAULT_BOX_PX, DEFAULT_BOX_PX)
            try:
                seed_img = Chroma420Frame(img, wrap[c]) if wrap[c] else img
                engine.add(MarkerTrack(m, c, seed_img, f, x, y, box[0], box[1], params, kind=kinds.get(f"{m}/{c}"),
                                       like=refs.get(c)), f)
            except SandtrackError as exc:
                problems.append(str(exc))
        if not engine.tracks:
            summary.update(frames=0, status="no marker could be started")
            return summary
        if params.luma_carry:
            intra = {c: intra_frames(sources[c]) for c in cams}
            for (_m, c), t in engine.tracks.items():
                t.intra = intra.get(c)
        man_pts = points[(points.status == MANUAL) & points.x_px.notna()]
        manual = {(int(r.marker), r.camera, int(r.frame)): (float(r.x_px), float(r.y_px))
                  for r in man_pts.itertuples() if (int(r.marker), r.camera) in engine.tracks}
        for key, (f, _, _) in seeds.items():
            manual.pop((key[0], key[1], f), None)
        feeds = dict(zip(cams, feeds_list, strict=True))
        t0 = time.perf_counter()
        t_track = cpu_track = 0.0
        n_obs = 0
        buf: list[tuple] = []
        desc = f"track {direction} from frame {a}" + (f" (markers {', '.join(map(str, markers))})" if markers else "")
        with project.edit(desc, sync_each_write=False) as ed:
            for k, st in enumerate(steps):
                if should_stop is not None and should_stop():
                    summary["stopped"] = True
                    break
                if k % BATCH_STEPS == 0:
                    ahead = steps[k:k + BATCH_STEPS]
                    for c, feed in feeds.items():
                        feed.wait_for(sum(c in s for s in ahead))
                frames = {}
                for c, (j, rem) in st.items():
                    jj, img = feeds[c].get()
                    if jj != j:
                        raise RuntimeError(f"frame order broken ({c}: wanted {j}, got {jj})")
                    frames[c] = (j, Chroma420Frame(img, wrap[c]) if wrap.get(c) else img, rem)
                t1, c1 = time.perf_counter(), time.thread_time()
                obs = engine.step(frames, manual)
                t_track += time.perf_counter() - t1
                cpu_track += time.thread_time() - c1
                n_obs += len(obs)
                buf.extend(o.row() for o in obs if o.status != MANUAL)
                if (k + 1) % chunk_steps == 0 and buf:
                    summary["rows_written"] += ed.write(buf)
                    buf = []
                if progress is not None:
                    progress(k + 1, len(steps))
            if buf:
                summary["rows_written"] += ed.write(buf)
            paired = _merge_pairs(project, ed, engine, problems)
        elapsed = time.perf_counter() - t0
        renamed = {(p["from"], p["camera"]): p["marker"] for p in paired}
        summary["paired_across_views"] = paired
        merged = {p["marker"] for p in paired} | {p["from"] for p in paired}
        summary["one_camera_markers"] = [m for m in one_camera if m not in merged]
        for event in engine.stereo_flags + engine.ambiguous:
            event["marker"] = renamed.get((event["marker"], event["camera"]), event["marker"])
        per = {}
        for (m, c), t in engine.tracks.items():
            per.setdefault(str(renamed.get((m, c), m)), {})[c] = {
                "tracked": t.counts[TRACKED], "occluded": t.counts[OCCLUDED], "lost": t.counts[LOST],
                "reacquired": t.reacquisitions, "at_rest": t.rest_frames, "last_status": t.status,
                "appearance": t.model.describe()}
        never = [f"marker {renamed.get((m, c), m)} {c}" for (m, c), t in engine.tracks.items()
                 if t.counts[TRACKED] == 0 and (t.counts[OCCLUDED] + t.counts[LOST]) > 0]
        summary.update(
            frames=len(steps), first_frame=a, last_frame=b,
            frames_by_camera={c: sum(c in st for st in steps) for c in cams},
            per_marker=per, stereo_flags=engine.stereo_flags, view_shifts=engine.view_shifts,
            ambiguous=engine.ambiguous, never_found=never, elapsed_s=round(elapsed, 3), track_s=round(t_track, 4),
            marker_frames=n_obs,
            track_ms_per_marker_frame=round(1000 * t_track / max(n_obs, 1), 4),
            track_cpu_ms_per_marker_frame=round(1000 * cpu_track / max(n_obs, 1), 4),
            status="stopped" if summary["stopped"] else "done")
        return summary
    finally:
        sys.setswitchinterval(switch)
        for p in feeds_list:
            p.close()
        if own:
            _close(sources)
