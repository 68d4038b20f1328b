"""Every particle (`sandtrack track --auto-seed --all --new-particles`) on the twin's crowds, beside
trackpy's `locate` + `link` on the same frames.

Per crowd case (`flume`, `flume-8bit`, `dense300`; rendered into the cache by bench_variants) and
camera: a project on its frames, one particle clicked as an operator does (the visible one farthest
from any other, CLICK_OFF px off its centre, snapped, its box from `marker_box`), then every particle
like it seeded in frame 0 and tracked to frame FRAMES - 1. Scored against the exact truth:
- seeded: the share of the particles visible at frame 0 with a seed within 3 px;
- coverage: the share of visible particle-frames with a `tracked` (or seed) point within 3 px that
  belongs to that particle (the marker's first point names its particle, groundtruth.match_marker_ids;
  a particle that lost its track and got a new id is still covered);
- mean / p95 error of the reported points on visible frames, identity switches (a `tracked` point
  within 3 px of another particle, groundtruth.identity_switches), tracks that follow no particle;
- CPU of detection + linking (decoding excluded) per particle in view per frame (the truth's visible
  particle-frames: the same denominator for both tools, whatever each reports), and per reported point;
- the joins at the end of the run (particle_joins.join_tracks, timed on their own): pieces joined across
  gaps, and fragments per true particle before / after (tracks whose measured points lie mostly on a
  particle, per particle having one); with two calibrated views, the particles paired across the views,
  right / wrong against the truth (both views' tracks mostly on the same particle), the tracks left unpaired
  as ambiguous, and the 3D error of the paired markers' triangulated points on frames both views see them.
trackpy 0.7 gets the same frames as one float channel: the frame along the seed's colour direction
(detect.project: the particle bright), with a grey closing of a third of a diameter (it fills a
glass bead's dark-after-projection centre, which otherwise pulls trackpy's centroid onto a ring);
diameter the odd number above the bead's, separation 0.7 diameter (touching beads), minmass the best
of a grid on frame 0 against the truth (the most generous setting), link search_range the fastest
bead's step per frame, memory 3, adaptive_stop 2 px.

`python benchmarks/bench_particles.py [CASE ...] [--frames N]` prints one JSON line per case.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_variants import CLICK_OFF, _truth, ensure_variant  # noqa: E402
from sandtrack_tui.camera import Calibration  # noqa: E402
from sandtrack_tui.groundtruth import REPORTED, identity_switches, match_marker_ids, score_tracking  # noqa: E402
from sandtrack_tui.store import Project  # noqa: E402
from sandtrack_tui.tracking.detect import project as project_colour  # noqa: E402
from sandtrack_tui.tracking.particle_joins import join_tracks  # noqa: E402
from sandtrack_tui.tracking.particles import seed_look, track_every_particle  # noqa: E402
from sandtrack_tui.tracking.run import accept_seeds  # noqa: E402
from sandtrack_tui.tracking.seeding import marker_box, snap_to_marker  # noqa: E402
from sandtrack_tui.video import FrameSource  # noqa: E402

CASES = ("flume", "flume-8bit", "dense300")
FRAMES = 120  # frames tracked per case (both tools)
NEAR_PX = 3.0


def _operator_seed(folder: Path, info: dict, truth: dict) -> pd.DataFrame:
    """The visible particle of frame 0 farthest from any other (in the first camera), clicked in
    every camera where it is visible."""
    from scipy.spatial import cKDTree

    cams = list(info["cameras"])
    t0 = truth[cams[0]]
    t0 = t0[t0.frame == 0]
    with FrameSource(folder / info["videos"][cams[0]], cache_mb=16) as src:
        H, W = src.frame(0).shape[:2]
    xy = t0[["x_px", "y_px"]].to_numpy()
    d, _ = cKDTree(xy).query(xy, k=2)
    ok = t0.visible.to_numpy() & (xy[:, 0] > 40) & (xy[:, 0] < W - 40) & (xy[:, 1] > 40) & (xy[:, 1] < H - 40)
    marker = int(t0.marker.to_numpy()[np.flatnonzero(ok)[np.argmax(d[ok, 1])]])
    rows = []
    for cam in cams:
        r = truth[cam][(truth[cam].marker == marker) & (truth[cam].frame == 0) & truth[cam].visible]
        if r.empty:
            continue
        with FrameSource(folder / info["videos"][cam], cache_mb=16) as src:
            img = src.frame(0)
        click = (r.x_px.iloc[0] + CLICK_OFF[0], r.y_px.iloc[0] + CLICK_OFF[1])
        x, y = snap_to_marker(img, *click) or click
        box = marker_box(img, x, y) or (16.0, 16.0)
        rows.append((1, cam, 0, x, y, box[0], box[1], np.nan))
    return pd.DataFrame(rows, columns=["marker", "camera", "frame", "x_px", "y_px", "w", "h", "epipolar_px"])


def score(points: pd.DataFrame, truth: dict, frames: int) -> dict:
    truth = {c: t[t.frame < frames] for c, t in truth.items()}
    t = SimpleNamespace(markers=truth)
    ids = match_marker_ids(points, t, max_px=NEAR_PX)
    out = {}
    seeded = visible = covered = vis_all = 0
    for cam, tt in truth.items():
        p = points[(points.camera == cam) & points.status.isin(REPORTED) & points.x_px.notna()]
        p = p.assign(true_marker=p.marker.map(ids)).dropna(subset=["true_marker"])
        m = p.merge(tt[tt.visible], left_on=["frame", "true_marker"], right_on=["frame", "marker"],
                    suffixes=("", "_t"))
        ok = np.hypot(m.x_px - m.x_px_t, m.y_px - m.y_px_t) <= NEAR_PX
        good = set(zip(m.frame[ok], m.marker_t[ok], strict=True))
        v = tt[tt.visible]
        vis_all += len(v)
        covered += sum((f, mk) in good for f, mk in zip(v.frame, v.marker, strict=True))
        v0 = v[v.frame == 0]
        visible += len(v0)
        seeded += sum((0, mk) in good for mk in v0.marker)
    out["seeded_pct"] = 100.0 * seeded / max(visible, 1)
    out["coverage_pct"] = 100.0 * covered / max(vis_all, 1)
    s = score_tracking(points, t, ids)
    out.update(mean_error_px=s["mean_error_px"], p95_error_px=s["p95_error_px"], false_locks=s["false_locks"])
    out["identity_switches"] = identity_switches(points, t, ids)["identity_switches"]
    out["tracks"] = int(points.marker.nunique())
    out["tracks_on_no_particle"] = int(points.marker.nunique() - len(ids))
    return out


def owners(points: pd.DataFrame, truth: dict, cam: str) -> dict:
    """Track id -> the true particle most of its measured points lie on (within NEAR_PX)."""
    p = points[(points.camera == cam) & points.status.isin(REPORTED) & points.x_px.notna()]
    t = truth[cam]
    m = p.merge(t[t.visible][["frame", "marker", "x_px", "y_px"]], on="frame", suffixes=("", "_t"))
    m = m[np.hypot(m.x_px - m.x_px_t, m.y_px - m.y_px_t) <= NEAR_PX]
    n = m.groupby(["marker", "marker_t"]).size().reset_index(name="n").sort_values("n")
    n = n.drop_duplicates("marker", keep="last")
    return dict(zip(n.marker.astype(int), n.marker_t.astype(int), strict=True))


def score_joins(before: pd.DataFrame, after: pd.DataFrame, truth: dict, proj) -> dict:
    cams = list(truth)
    out = {}
    for tag, pts in (("before", before), ("after", after)):
        own = [owners(pts, truth, c) for c in cams]
        out[f"fragments_per_particle_{tag}"] = sum(len(o) for o in own) / max(sum(len(set(o.values())) for o in own), 1)
    if len(cams) == 2 and proj.calibration() is not None:
        from sandtrack_tui.xyz import compute_xyz

        oa, ob = (owners(after, truth, c) for c in cams)
        both = sorted(set(oa) & set(ob))
        right = [m for m in both if oa[m] == ob[m]]
        out.update(pairs=len(both), pairs_right=len(right), pairs_wrong=len(both) - len(right))
        xyz = compute_xyz(proj, method="triangulation")
        xyz = xyz[xyz.marker.isin(right) & xyz.X_mm.notna()]
        xyz = xyz.assign(true_marker=xyz.marker.map(oa))
        t = truth[cams[0]]
        m = xyz.merge(t[t.visible], left_on=["frame", "true_marker"], right_on=["frame", "marker"],
                      suffixes=("", "_t"))
        err = np.linalg.norm(m[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
                             - m[["X_mm_t", "Y_mm_t", "Z_mm_t"]].to_numpy(float), axis=1)
        out["xyz_points"] = int(len(err))
        out["xyz_mean_error_mm"] = float(np.mean(err)) if len(err) else float("nan")
        out["xyz_p95_error_mm"] = float(np.percentile(err, 95)) if len(err) else float("nan")
    return out


def run_ours(name: str, frames: int = FRAMES) -> tuple[dict, dict]:
    folder = ensure_variant(name)
    info = json.loads((folder / "variant.json").read_text())
    cams = list(info["cameras"])
    truth = _truth(folder, cams)
    with tempfile.TemporaryDirectory() as tmp:
        proj = Project.create(Path(tmp) / "p.sandtrack", {c: folder / info["videos"][c] for c in cams})
        if (folder / "ground_truth" / "cameras.toml").is_file():
            proj.set_calibration(Calibration.load(folder / "ground_truth" / "cameras.toml"))
        proj.set("sync_offset_s", 0.0)
        accept_seeds(proj, _operator_seed(folder, info, truth))
        sources = proj.open_sources(cache_mb=32)
        looks = {c: v[0] for c, v in seed_look(proj, sources, cams).items()}
        c0 = time.process_time()
        summary = track_every_particle(proj, start=0, stop=frames - 1, new_particles=True, sources=sources,
                                       gap_closing=False, pairing=False)
        cpu = time.process_time() - c0
        before = proj.points()
        # the joins the run makes at its end (the same call on the same tracks), timed and scored on their own
        runs = {c: (0, frames - 1, looks[c].diameter_px) for c in cams}
        c0 = time.process_time()
        with proj.edit("joins") as ed:
            joins = join_tracks(proj, ed, runs, set(before.marker.unique()))
        join_cpu = time.process_time() - c0
        points = proj.points()
        joined = score_joins(before, points, truth, proj)
        proj.close()
    out = {"case": name, "frames": frames, "particles_visible_per_frame": round(float(np.mean(
        [truth[c][(truth[c].frame < frames) & truth[c].visible].groupby("frame").size().mean() for c in cams])), 1)}
    out.update(score(points, truth, frames))
    cams_s = summary["cameras"]
    n = sum(v["tracked"] + v["seeded"] for v in cams_s.values())
    track_ms = sum(v["cpu_ms_per_particle_frame"] * (v["tracked"] + v["seeded"]) for v in cams_s.values())
    out["cpu_ms_per_particle_frame"] = round(track_ms / max(n, 1), 4)
    out["cpu_ms_per_particle_in_view"] = round(track_ms / max(_in_view(truth, frames), 1), 4)
    out["run_cpu_s"] = round(cpu, 2)
    out["flagged_points"] = int(sum(v["flagged"] for v in cams_s.values()))
    out["new_particles"] = int(sum(v["new"] for v in cams_s.values()))
    out["ambiguous_withheld"] = int(sum(v["ambiguous"] for v in cams_s.values()))
    out["tracks_before_joins"] = int(before.marker.nunique())
    out["gaps_closed"] = int(sum(v["gaps_closed"] for v in joins["gaps"].values()))
    if joins["pairing"]:
        out["pairs_made"] = int(joins["pairing"]["paired"])
    if joins["pairing"]:
        out["unpaired_ambiguous"] = int(sum(joins["pairing"]["unpaired_ambiguous"].values()))
    out.update(joined)
    out["join_cpu_s"] = round(join_cpu, 2)
    return out, {"looks": looks, "truth": truth, "folder": folder, "info": info}


def run_trackpy(name: str, ctx: dict, frames: int = FRAMES) -> dict:
    import trackpy as tp

    tp.quiet()
    folder, info, truth = ctx["folder"], ctx["info"], ctx["truth"]
    pts, offset, cpu = [], 0, 0.0
    for cam in info["cameras"]:
        look = ctx["looks"][cam]
        dia = look.diameter_px
        diameter = int(np.ceil(dia)) | 1
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (max(3, int(dia / 3)) | 1,) * 2)
        with FrameSource(folder / info["videos"][cam], cache_mb=16) as src:
            imgs = [cv2.morphologyEx(project_colour(src.frame(i), look.weights), cv2.MORPH_CLOSE, kernel)
                    for i in range(frames)]
        imgs = [im - float(np.percentile(im, 1)) for im in imgs]
        t0 = truth[cam][(truth[cam].frame == 0) & truth[cam].visible][["x_px", "y_px"]].to_numpy()
        best = None
        f0 = tp.locate(imgs[0], diameter, separation=0.7 * dia)
        for q in (0, 10, 20, 30, 40, 50, 60):
            mm = float(np.percentile(f0.mass, q)) if len(f0) else 0.0
            sel = f0[f0.mass >= mm]
            from scipy.spatial import cKDTree

            d, _ = cKDTree(sel[["x", "y"]].to_numpy()).query(t0)
            d2, _ = cKDTree(t0).query(sel[["x", "y"]].to_numpy())
            f1 = (d <= NEAR_PX).mean() - (d2 > NEAR_PX).mean()
            if best is None or f1 > best[0]:
                best = (f1, mm)
        speed = float(np.hypot(truth[cam].vx_px, truth[cam].vy_px).max()) if "vx_px" in truth[cam] else 2 * dia
        c0 = time.process_time()
        feats = tp.batch(imgs, diameter, separation=0.7 * dia, minmass=best[1], processes=1)
        linked = tp.link(feats, search_range=max(speed, dia / 2), memory=3, adaptive_stop=2.0, adaptive_step=0.9)
        cpu += time.process_time() - c0
        pts.append(pd.DataFrame({"frame": linked.frame.astype(int), "camera": cam, "marker": linked.particle + offset,
                                 "x_px": linked.x, "y_px": linked.y, "status": "tracked"}))
        offset += int(linked.particle.max()) + 1
    points = pd.concat(pts, ignore_index=True)
    out = {"trackpy_" + k: v for k, v in score(points, truth, frames).items()}
    n = len(points)
    out["trackpy_cpu_ms_per_particle_frame"] = round(1000 * cpu / max(n, 1), 4)
    out["trackpy_cpu_ms_per_particle_in_view"] = round(1000 * cpu / max(_in_view(truth, frames), 1), 4)
    return out


def _in_view(truth: dict, frames: int) -> int:
    """Visible particle-frames of the first `frames` frames, over the cameras."""
    return int(sum(((t.frame < frames) & t.visible.astype(bool)).sum() for t in truth.values()))


def run(names: list[str] | None = None, frames: int = FRAMES) -> dict:
    out: dict = {}
    for name in names or CASES:
        ours, ctx = run_ours(name, frames)
        row = {**ours, **run_trackpy(name, ctx, frames)}
        for k, v in row.items():
            if k != "case":
                out[f"{name}.{k}"] = round(v, 4) if isinstance(v, float) else v
    return out


if __name__ == "__main__":
    args = sys.argv[1:]
    n = FRAMES
    if "--frames" in args:
        i = args.index("--frames")
        n = int(args[i + 1])
        del args[i:i + 2]
    for case in args or CASES:
        ours, ctx = run_ours(case, n)
        print(json.dumps({**ours, **run_trackpy(case, ctx, n)}), flush=True)
