"""The tracker on the twin's harder cases (twin/variants.py): one row per variant.

Each variant (marker style, sand tone, dense identical beads, fast and blurred, large, shaken and
panned camera) is rendered once into the cache (`sandtrack demo`'s cache folder, keyed on the
renderer's source; not into git), then tracked as a user would: a project on its videos or image
folders (with the true cameras when both views are still), seeded as a user would: the first
marker clicked in each camera 1.8 px off its centre, snapped (`snap_to_marker`) with the box
`marker_box` gives, then auto-seed finds every marker like it in that frame (`auto_seed`, paired
across the cameras by epipolar distance), then `track_project` forward. Scored against the exact truth like the sample
(groundtruth.score_tracking): mean / p95 error on visible tracked frames, false locks (> 3 px),
hidden frames flagged, flagged frames truly hidden; plus the share of visible frames tracked,
identity switches (a `tracked` point within 3 px of another marker's true centre) and the
appearance models chosen, and the tracking step's CPU per marker and frame (decoding excluded).

The crowds (catalog.CROWDS: `dense300`, `flume`, `flume-8bit`: hundreds of identical beads, to be detected
in every frame and linked rather than seeded one by one) are not tracked here: `--crowds` renders them
into the cache and loads them (every camera's frames through FrameSource, the truth files), one row
each with the render's cost, its size on disk and what its truth holds.

`python benchmarks/bench_variants.py [NAME ...]` runs some; figures print as a table. With `--why`,
every false lock and every run of frames flagged while the marker was visible is listed too, with the
tracker's own verdict at the run's first frame (its best match in the gate and the test it failed, or
how far its prediction was from the marker against the window it searched); one line counts those
frames: without a position, with a flagged position within 1.5 px of the truth, and with the same
marker visible, and tracked, in another camera at that frame.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sandtrack_tui.camera import Calibration  # noqa: E402
from sandtrack_tui.demo import cache_dir  # noqa: E402
from sandtrack_tui.groundtruth import REPORTED, identity_switches, match_marker_ids, score_tracking, score_xyz  # noqa: E402
from sandtrack_tui.store import Project  # noqa: E402
from sandtrack_tui.tracking.matcher import TemplateMatcher  # noqa: E402
from sandtrack_tui.tracking.run import accept_seeds, auto_seed, track_project  # noqa: E402
from sandtrack_tui.tracking.seeding import marker_box, snap_to_marker  # noqa: E402
from sandtrack_tui.tracking.tracker import MarkerTrack  # noqa: E402
from sandtrack_tui.twin.catalog import CROWDS, VARIANTS, cache_key, render_variant  # noqa: E402
from sandtrack_tui.video import FrameSource  # noqa: E402
from sandtrack_tui.xyz import compute_xyz  # noqa: E402

CLICK_OFF = (1.5, -1.0)


def ensure_variant(name: str, seed: int = 0) -> Path:
    out = cache_dir() / f"variant-{name}-seed{seed}-{cache_key(name)}"
    if not (out / ".complete").is_file():
        if out.exists():
            shutil.rmtree(out)
        out.mkdir(parents=True)
        render_variant(name, out, seed=seed, log=lambda m: print(m, file=sys.stderr, flush=True))
        (out / ".complete").write_text("ok\n")
    return out


def _truth(folder: Path, cams) -> dict:
    out = {}
    for c in cams:
        t = pd.read_csv(folder / "ground_truth" / f"markers_{c}.csv")
        t["visible"] = t["visible"].astype(bool)
        out[c] = t
    return out


def _click(videos: dict, truth: dict, marker: int, frame: int = 0) -> pd.DataFrame:
    """One marker seeded as an operator does it: a click CLICK_OFF px off its centre, snapped, with
    the box marker_box gives."""
    rows = []
    for cam, t in truth.items():
        r = t[(t.marker == marker) & (t.frame == frame)].iloc[0]
        with FrameSource(videos[cam], cache_mb=64) as src:
            img = src.frame(frame)
        click = (r.x_px + CLICK_OFF[0], r.y_px + CLICK_OFF[1])
        snapped = snap_to_marker(img, *click) or click
        box = marker_box(img, *snapped) or (16.0, 16.0)
        rows.append((1, cam, frame, snapped[0], snapped[1], box[0], box[1], np.nan))
    return pd.DataFrame(rows, columns=["marker", "camera", "frame", "x_px", "y_px", "w", "h", "epipolar_px"])


def _seed(proj, videos: dict, truth: dict) -> dict:
    """The first marker clicked in each camera, then auto-seed: every marker like it in frame 0
    (paired across the cameras by epipolar distance when calibrated). Returns how it went."""
    first = int(min(t[(t.frame == 0) & t.visible].marker.min() for t in truth.values()))
    accept_seeds(proj, _click(videos, truth, first))
    proposal = auto_seed(proj, frame=0)
    accept_seeds(proj, proposal)
    n_true = int(sum(t[(t.frame == 0) & t.visible].marker.nunique() for t in truth.values()))
    return {"seeded_points": int(len(proposal)) + len(truth), "markers_visible_at_seed": n_true,
            "autoseed_models": ",".join(f"{k}:{n}" for k, n in proposal["model"].value_counts().items())}


def run_variant(name: str, seed: int = 0, keep: dict | None = None) -> dict:
    """Figures of one variant; `keep` (a dict) receives the points and the truth."""
    folder = ensure_variant(name, seed)
    info = json.loads((folder / "variant.json").read_text())
    cams = list(info["cameras"])
    videos = {c: folder / info["videos"][c] for c in cams}
    truth = _truth(folder, cams)
    with tempfile.TemporaryDirectory() as tmp:
        proj = Project.create(Path(tmp) / "v.sandtrack", videos)
        cal_file = folder / "ground_truth" / "cameras.toml"
        if cal_file.is_file():
            proj.set_calibration(Calibration.load(cal_file))
        proj.set("sync_offset_s", 0.0)
        seeding = _seed(proj, videos, truth)
        c0 = time.process_time()
        summary = track_project(proj)
        cpu = time.process_time() - c0
        points = proj.points()
        xyz = compute_xyz(proj, method="triangulation") if summary["stereo"] else None
        proj.close()
    t = SimpleNamespace(markers=truth)
    ids = match_marker_ids(points, t)
    if keep is not None:
        keep.update(points=points, truth=truth, ids=ids, summary=summary)
    out = {"variant": name, "cameras": len(cams), "markers": int(truth[cams[0]].marker.nunique()),
           "frames": info["frames"], "stereo": summary["stereo"], **seeding}
    out.update(score_tracking(points, t, ids))
    out.update(identity_switches(points, t, ids))
    kinds: dict = {}
    for cams_of in summary["per_marker"].values():
        for v in cams_of.values():
            kinds[v["appearance"]["model"]] = kinds.get(v["appearance"]["model"], 0) + 1
    out["models"] = ",".join(f"{k}:{n}" for k, n in sorted(kinds.items()))
    out["seed_problems"] = len(summary["problems"])
    out["track_cpu_ms_per_marker_frame"] = summary.get("track_cpu_ms_per_marker_frame")
    out["track_ms_per_marker_frame"] = summary.get("track_ms_per_marker_frame")
    out["run_cpu_s"] = round(cpu, 2)
    out["ambiguous"] = len(summary.get("ambiguous", []))
    out["paired_across_views"] = len(summary.get("paired_across_views", []))
    if xyz is not None:
        out.update(score_3d(xyz, points, truth, ids))
    out["stereo_flags"] = len(summary.get("stereo_flags", []))
    return out


def score_3d(xyz: pd.DataFrame, points: pd.DataFrame, truth: dict, ids: dict) -> dict:
    """The triangulated XYZ against the twin's true bead centres (markers_*.csv X_mm, Y_mm, Z_mm, the
    reference camera's frames): mean / p95 error (mm) of every finite XYZ, how many true markers get any
    3D, the same figures of the rows whose every view was measured (tracked or manual: not a flagged view's
    coasting position), and how many markers hold two true markers' points (their views matched to different markers at
    their first point in each camera: a wrong pairing across the views)."""
    ref = next(iter(truth))
    traj = SimpleNamespace(trajectories=truth[ref][["frame", "marker", "X_mm", "Y_mm", "Z_mm"]])
    scored = score_xyz(xyz, traj, ids, "triangulation")
    measured = np.logical_and.reduce([xyz[f"status_{c}"].isin(REPORTED) for c in truth])
    both = score_xyz(xyz[measured], traj, ids, "triangulation")
    have = xyz[(xyz.method == "triangulation") & xyz.X_mm.notna() & xyz.marker.isin(list(ids))]
    wrong = 0
    for mk, rows in points[points.x_px.notna() & points.marker.isin(list(ids))].groupby("marker"):
        per_cam = {c: match_marker_ids(g, SimpleNamespace(markers=truth)).get(int(mk))
                   for c, g in rows.groupby("camera")}
        wrong += len(set(per_cam.values())) > 1
    return {"xyz_mean_error_mm": scored["mean_error_mm"], "xyz_p95_error_mm": scored["p95_error_mm"],
            "xyz_points": scored["points_scored"], "xyz_measured_mean_error_mm": both["mean_error_mm"],
            "xyz_measured_p95_error_mm": both["p95_error_mm"], "xyz_measured_points": both["points_scored"],
            "markers_with_3d": int(have.marker.map(ids).nunique()),
            "markers_mixed_across_views": wrong}


@contextmanager
def _verdicts(out: dict):
    """Record, per (camera, marker, frame), what the tracker saw (diagnostics for --why only): its
    prediction and search half-size, and the best match of its own gated search (or of a
    re-acquisition's check) with the thresholds it had to pass."""
    match0, propose0, verify0, apply0 = (TemplateMatcher.match, MarkerTrack.propose, MarkerTrack.verify_at,
                                         MarkerTrack.apply)

    def match(self, *a, **k):
        self._why = match0(self, *a, **k)
        return self._why

    def searched(how, orig):
        def wrapped(self, img, *a, **k):
            self.matcher._why = None
            res = orig(self, img, *a, **k)
            self._why = (how, self.matcher._why, res is not None)
            return res
        return wrapped

    def apply(self, frame_index, *a, **k):
        hx, hy = self.search_halfsize()
        rec = {"pred": tuple(map(float, self.kf.xy)), "half": float(max(hx, hy)), "was": self.status}
        how = getattr(self, "_why", None)
        if how is not None:
            rec.update(search=how[0], match=how[1], passed=how[2])
        self._why = None
        out[(self.camera, self.marker, int(frame_index))] = rec
        return apply0(self, frame_index, *a, **k)

    TemplateMatcher.match = match
    MarkerTrack.propose, MarkerTrack.verify_at = searched("gate", propose0), searched("re-acquisition", verify0)
    MarkerTrack.apply = apply
    try:
        yield out
    finally:
        TemplateMatcher.match, MarkerTrack.propose, MarkerTrack.verify_at, MarkerTrack.apply = (
            match0, propose0, verify0, apply0)


def _verdict_text(rec: dict | None, tx: float, ty: float, params) -> str:
    if rec is None:
        return "not searched"
    gap = float(np.hypot(rec["pred"][0] - tx, rec["pred"][1] - ty))
    where = f"prediction {gap:.1f} px from the marker, window ±{rec['half']:.0f} px"
    m = rec.get("match")
    if m is None:
        what = f"{rec.get('search', 'no search')}: no match"
    else:
        tests = (("score", m.score, params.min_score), ("psr", m.psr, params.min_psr),
                 ("coverage", m.colour_frac, params.min_colour))
        fails = [f"{n} {v:.2f} < {t:.2f}" for n, v, t in tests if v < t]
        what = (f"{rec['search']}: match {np.hypot(m.x - tx, m.y - ty):.1f} px from the marker, score "
                f"{m.score:.2f}, psr {m.psr:.1f}, coverage {m.colour_frac:.2f}"
                + (f" (failed: {', '.join(fails)})" if fails and not rec.get("passed") else ""))
    return f"was {rec['was']}; {what}; {where}"


def explain(points: pd.DataFrame, truth: dict, ids: dict, verdicts: dict) -> list[str]:
    """One line per false lock (> 3 px) and per run of frames flagged while the marker was visible."""
    from sandtrack_tui.tracking.tracker import TrackParams

    params, back = TrackParams(), {v: k for k, v in ids.items()}
    lines = []
    for cam, t in truth.items():
        p = points[(points.camera == cam) & points.marker.isin(list(ids))]
        p = p.assign(true_marker=p.marker.map(ids))
        m = p.merge(t, left_on=["frame", "true_marker"], right_on=["frame", "marker"], suffixes=("", "_t"))
        m = m.sort_values(["true_marker", "frame"])
        m = m.assign(err=np.hypot(m.x_px - m.x_px_t, m.y_px - m.y_px_t))
        for r in m[m.status.isin(["tracked", "manual"]) & (m.err > 3)].itertuples():
            rec = verdicts.get((cam, back[r.true_marker], int(r.frame)))
            lines.append(f"false lock   {cam:>5} marker {r.true_marker} frame {r.frame}: {r.err:.1f} px off, "
                         f"truth visible {r.visible_fraction:.2f}; {_verdict_text(rec, r.x_px_t, r.y_px_t, params)}")
        bad = m[m.status.isin(["occluded", "lost"]) & m.visible.astype(bool)]
        for tm, g in bad.groupby("true_marker"):
            frames = g.frame.to_numpy()
            for run in np.split(np.arange(len(g)), np.nonzero(np.diff(frames) > 1)[0] + 1):
                first, last = g.iloc[run[0]], g.iloc[run[-1]]
                rec = verdicts.get((cam, back[tm], int(first.frame)))
                moved = float(np.hypot(last.x_px_t - first.x_px_t, last.y_px_t - first.y_px_t))
                lines.append(f"flagged seen {cam:>5} marker {tm} frames {first.frame}-{last.frame} ({len(run)}, "
                             f"{'/'.join(sorted(set(g.iloc[run].status)))}), moved {moved:.1f} px; "
                             f"{_verdict_text(rec, first.x_px_t, first.y_px_t, params)}")
    return lines


def flag_causes(points: pd.DataFrame, truth: dict, ids: dict) -> str:
    """One line on the marker-frames flagged while visible: how many have no position at all, how many
    a flagged position within 1.5 px of the truth, and how many have the same marker visible in another
    camera at that frame, and tracked there within 3 px (the most a re-identification from the other
    view, its position and the epipolar line, could give back)."""
    p = points[points.marker.isin(list(ids))]
    p = p.assign(true_marker=p.marker.map(ids))
    merged = []
    for cam, t in truth.items():
        m = p[p.camera == cam].merge(t, left_on=["frame", "true_marker"], right_on=["frame", "marker"],
                                     suffixes=("", "_t"))
        merged.append(m.assign(err=np.hypot(m.x_px - m.x_px_t, m.y_px - m.y_px_t)))
    m = pd.concat(merged)
    held = m[m.status.isin(["tracked", "manual"]) & (m.err <= 3)]
    held_at = set(zip(held.camera, held.frame, held.true_marker, strict=True))
    seen_at = {(c, f, tm) for c, t in truth.items() for f, tm in zip(t.frame[t.visible], t.marker[t.visible],
                                                                      strict=True)}
    bad = m[m.status.isin(["occluded", "lost"]) & m.visible.astype(bool)]
    keys = list(zip(bad.camera, bad.frame, bad.true_marker, strict=True))

    def elsewhere(at: set) -> int:
        return sum(any((c, f, tm) in at for c in truth if c != cam) for cam, f, tm in keys)

    return (f"flagged while visible: {len(bad)} marker-frames; no position {int(bad.err.isna().sum())}, "
            f"flagged position within 1.5 px {int((bad.err <= 1.5).sum())}; the same marker visible in another "
            f"camera at that frame {elsewhere(seen_at)}, tracked there {elsewhere(held_at)}")


def load_crowd(name: str, seed: int = 0) -> dict:
    """A crowd case rendered (once) and read back: its frames through FrameSource, its truth."""
    folder = ensure_variant(name, seed)
    info = json.loads((folder / "variant.json").read_text())
    cams = list(info["cameras"])
    truth = _truth(folder, cams)
    out = {"variant": name, "cameras": len(cams), "frames": info["frames"], "render_cpu_s": info["render_cpu_s"],
           "disk_mb": round(sum(f.stat().st_size for f in folder.rglob("*") if f.is_file()) / 1e6, 1)}
    for cam in cams:
        t = truth[cam]
        with FrameSource(folder / info["videos"][cam], cache_mb=16) as src:
            first, last = src.frame(0), src.frame(len(src) - 1)
            out[f"{cam}.frames_read"] = len(src)
            out[f"{cam}.size"] = f"{first.shape[1]}x{first.shape[0]}"
            out[f"{cam}.luma_mean"] = round(float(np.mean([first.mean(), last.mean()])), 1)
        per_frame = t.groupby("frame")
        out[f"{cam}.markers"] = int(t.marker.nunique())
        out[f"{cam}.markers_per_frame"] = round(float(per_frame.size().mean()), 1)
        out[f"{cam}.visible_per_frame"] = round(float(per_frame.visible.sum().mean()), 1)
        if "state" in t:
            for state in ("rolling", "saltating"):
                out[f"{cam}.{state}_per_frame"] = round(float((t.state == state).groupby(t.frame).sum().mean()), 1)
            out[f"{cam}.speed_px_per_frame_max"] = round(float(np.hypot(t.vx_px, t.vy_px).max()), 1)
    return out


def seeded_names() -> list[str]:
    """The cases tracked here (seeded, then auto-seeded): every case but the crowds."""
    return [n for n in VARIANTS if n not in CROWDS]


def run(names: list[str] | None = None) -> dict:
    rows = [load_crowd(n) if n in CROWDS else run_variant(n) for n in (names or seeded_names())]
    out: dict = {}
    for r in rows:
        for k, v in r.items():
            if k != "variant":
                out[f"{r['variant']}.{k}"] = round(v, 4) if isinstance(v, float) else v
    return out


def _table(rows: list[dict]) -> str:
    cols = [("variant", "{}"), ("models", "{}"), ("mean_error_px", "{:.3f}"), ("p95_error_px", "{:.3f}"),
            ("false_locks", "{}"), ("hidden_flagged_pct", "{:.1f}"), ("flagged_truly_hidden_pct", "{:.1f}"),
            ("visible_tracked_pct", "{:.1f}"), ("identity_switches", "{}"), ("track_cpu_ms_per_marker_frame",
                                                                              "{:.3f}"),
            ("markers_with_3d", "{}"), ("xyz_mean_error_mm", "{:.2f}"), ("xyz_p95_error_mm", "{:.2f}")]
    lines = [" | ".join(c for c, _ in cols)]
    for r in rows:
        lines.append(" | ".join(f.format(r.get(c)) if r.get(c) is not None else "-" for c, f in cols))
    return "\n".join(lines)


if __name__ == "__main__":
    why = "--why" in sys.argv[1:]
    if "--crowds" in sys.argv[1:]:
        for n in CROWDS:
            print(json.dumps(load_crowd(n)), flush=True)
        sys.exit(0)
    names = [a for a in sys.argv[1:] if a != "--why"] or seeded_names()
    rows = []
    for n in names:
        if n in CROWDS:
            print(json.dumps(load_crowd(n)), flush=True)
            continue
        if why:
            keep: dict = {}
            with _verdicts({}) as verdicts:
                rows.append(run_variant(n, keep=keep))
            print("\n".join(explain(keep["points"], keep["truth"], keep["ids"], verdicts)))
            print(flag_causes(keep["points"], keep["truth"], keep["ids"]))
        else:
            rows.append(run_variant(n))
        print(json.dumps(rows[-1]), flush=True)
    print(_table(rows))
