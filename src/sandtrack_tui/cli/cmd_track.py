"""`sandtrack track PROJECT [--seeds seeds.csv] [--auto-seed] [--from N] [--to M] [--backward] [--markers 1,2]`.

Headless tracking. Seeds come from the project (its manual points), from a CSV
(`frame, camera, marker, x, y, w, h`: x, y = marker centre in pixels, w, h = box around it;
w, h may be empty) or from auto-seeding (every marker of frame --from that looks like the first seeded
one, or every blue marker; paired across cameras). Results are written to the project as they are
made, as one undoable edit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import SandtrackError
from .common import Progress, add_json_flag, emit, log

CSV_COLUMNS = ["frame", "camera", "marker", "x", "y", "w", "h"]


def register(sub) -> None:
    p = sub.add_parser("track", help="track the markers in both cameras (template + Kalman, stereo-checked)",
                       description="Tracks each marker in each camera from its seed; writes tracked/occluded/lost "
                                   "points to the project as it goes (one undoable edit).")
    p.add_argument("project", help="project file (NAME.sandtrack)")
    p.add_argument("--seeds", metavar="CSV",
                   help="seed file: frame, camera, marker, x, y, w, h (pixels; x, y = marker centre)")
    p.add_argument("--auto-seed", action="store_true",
                   help="seed every marker found in frame --from (default: the first frame both cameras "
                        "recorded) that looks like the project's first seeded marker (with none seeded: every "
                        "blue marker), paired across cameras by epipolar distance")
    p.add_argument("--all", dest="every", action="store_true",
                   help="with --auto-seed: every particle like the seeded one (hundreds), detected in every frame "
                        "and linked (forward from --from, or from the seed's frame), then pieces of a track joined "
                        "across short gaps and, with two calibrated cameras, tracks paired across the views (3D)")
    p.add_argument("--new-particles", action="store_true",
                   help="with --all: particles entering the view later get new ids")
    p.add_argument("--max-gap", type=int, default=None, metavar="N",
                   help="with --all: join a lost track to one starting at most N frames later where its motion "
                        "predicts it, when nothing else explains either as well (default 8)")
    p.add_argument("--no-gap-closing", action="store_true", help="with --all: leave lost tracks and new ones apart")
    p.add_argument("--no-pairing", action="store_true",
                   help="with --all: do not pair the tracks of two calibrated cameras across the views")
    p.add_argument("--like", type=int, metavar="MARKER",
                   help="with --auto-seed: find markers that look like this seeded marker (default: the first "
                        "seeded marker)")
    p.add_argument("--from", dest="start", type=int, metavar="N",
                   help="start frame (first camera's index); default: each marker's seed")
    p.add_argument("--to", dest="stop", type=int, metavar="M", help="last frame (inclusive); default: the end")
    p.add_argument("--backward", action="store_true", help="track backward in time")
    p.add_argument("--markers", metavar="LIST", help="comma-separated marker ids (default: all)")
    p.add_argument("--allow-unsynced", action="store_true",
                   help="track a project of several cameras whose sync offset was never set (taken as 0): only "
                        "right for cameras that start together; otherwise run `sandtrack sync PROJECT` first")
    add_json_flag(p)
    p.set_defaults(func=run)


def read_seeds_csv(path: str | Path) -> pd.DataFrame:
    """Seeds CSV -> DataFrame[marker, camera, frame, x_px, y_px, w, h]; clear errors on bad input."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"seed file not found: {p}")
    try:
        df = pd.read_csv(p, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise SandtrackError(f"{p}: not a readable CSV ({str(exc).splitlines()[0]})") from None
    df.columns = [str(c).strip().lower() for c in df.columns]
    missing = [c for c in CSV_COLUMNS[:5] if c not in df.columns]
    if missing:
        raise SandtrackError(f"{p}: missing column(s) {', '.join(missing)} (need {', '.join(CSV_COLUMNS)})")
    if df.empty:
        raise SandtrackError(f"{p}: no seed rows")
    for c in ("w", "h"):
        if c not in df.columns:
            df[c] = np.nan
    try:
        out = pd.DataFrame({
            "marker": df["marker"].astype(int), "camera": df["camera"].astype(str).str.strip(),
            "frame": df["frame"].astype(int), "x_px": df["x"].astype(float), "y_px": df["y"].astype(float),
            "w": pd.to_numeric(df["w"], errors="coerce"), "h": pd.to_numeric(df["h"], errors="coerce")})
    except (ValueError, TypeError) as exc:
        raise SandtrackError(f"{p}: non-numeric value ({exc})") from None
    if not np.isfinite(out[["x_px", "y_px"]].to_numpy()).all():
        raise SandtrackError(f"{p}: x and y must be numbers on every row")
    bad = out[(out.w <= 0) | (out.h <= 0)]
    if len(bad):
        r = bad.iloc[0]
        raise SandtrackError(f"{p}: marker {r.marker} has an empty box ({r.w}x{r.h})")
    return out


def _first_seeded(project) -> int | None:
    """The lowest marker id with a manual point (auto-seed's model), or None."""
    pts = project.points()
    man = pts[(pts.status == "manual") & pts.x_px.notna()]
    return int(man.marker.min()) if len(man) else None


def _check_seeds(project, seeds: pd.DataFrame) -> None:
    vids = project.videos()
    for r in seeds.itertuples():
        if r.camera not in vids:
            raise SandtrackError(f"seed of marker {r.marker}: no camera {r.camera!r} (have {', '.join(vids)})")
        v = vids[r.camera]
        if not 0 <= r.frame < v.frames:
            raise SandtrackError(f"seed of marker {r.marker}: frame {r.frame} outside 0..{v.frames - 1}")
        if not (0 <= r.x_px < v.width and 0 <= r.y_px < v.height):
            raise SandtrackError(f"seed of marker {r.marker} ({r.camera}): ({r.x_px}, {r.y_px}) lies outside the "
                                 f"{v.width}x{v.height} image")


def _check_sync(proj, args) -> None:
    """Several cameras and no sync offset yet: refuse, unless told the cameras start together."""
    if len(proj.cameras()) < 2 or proj.sync_confirmed():
        return
    if not args.allow_unsynced:
        raise SandtrackError(f"{args.project}: the cameras are not synced yet; run `sandtrack sync {args.project}` "
                             "first (with an offset of 0 the stereo check throws good views away once the markers "
                             "move), or pass --allow-unsynced if the cameras start together")
    log("warning: the cameras were never synced; tracking with an offset of 0 s (--allow-unsynced)")


def run(args) -> int:
    from ..store import Project
    from ..tracking.run import accept_seeds, auto_seed, track_project

    markers = None
    if args.markers:
        try:
            markers = [int(m) for m in args.markers.split(",") if m.strip()]
        except ValueError:
            raise SandtrackError(f"--markers: give ids separated by commas, not {args.markers!r}") from None
    if args.like is not None and not args.auto_seed:
        raise SandtrackError("--like goes with --auto-seed")
    if args.every and not args.auto_seed:
        raise SandtrackError("--all goes with --auto-seed")
    if args.new_particles and not args.every:
        raise SandtrackError("--new-particles goes with --auto-seed --all")
    for flag, given in (("--max-gap", args.max_gap is not None), ("--no-gap-closing", args.no_gap_closing),
                        ("--no-pairing", args.no_pairing)):
        if given and not args.every:
            raise SandtrackError(f"{flag} goes with --auto-seed --all")
    if args.every:
        if args.backward or markers or args.seeds:
            raise SandtrackError("--all tracks every particle forward from one seeded particle: leave out "
                                 "--backward, --markers and --seeds")
        return _run_every(args)
    with Project.open(args.project) as proj:
        _check_sync(proj, args)
        seeded = 0
        if args.seeds:
            seeds = read_seeds_csv(args.seeds)
            _check_seeds(proj, seeds)
            seeded = accept_seeds(proj, seeds, f"seeds from {Path(args.seeds).name}")
            log(f"track: {seeded} seed points from {args.seeds}")
        if args.auto_seed:
            like = args.like if args.like is not None else _first_seeded(proj)
            proposal = auto_seed(proj, frame=args.start, like=like)
            if proposal.empty:
                where = f"frame {args.start}" if args.start is not None else "the first frame both cameras recorded"
                what = "blue marker" if like is None else f"new marker like marker {like}"
                raise SandtrackError(f"auto-seed: no {what} found in {where}")
            seeded += accept_seeds(proj, proposal, "auto-seed")
            n_pairs = int(proposal.epipolar_px.notna().sum() // 2)
            kinds = ", ".join(f"{n} {k}" for k, n in proposal["model"].value_counts().items())
            log(f"track: auto-seed found {proposal.marker.nunique()} markers ({n_pairs} paired across cameras; "
                f"appearance models: {kinds})")
        if proj.points().query("status == 'manual'").empty and args.start is None:
            raise SandtrackError("no seeds: give --seeds CSV, --auto-seed, or seed markers in the TUI")
        bar = Progress(1, "track")

        def progress(done, total):
            bar.total = max(total, 1)
            bar.update(done)

        summary = track_project(proj, markers=markers, start=args.start, stop=args.stop,
                                direction="backward" if args.backward else "forward", progress=progress)
        bar.close()
        summary.update(xyz_uncertainty(proj, summary))
    summary["project"] = str(args.project)
    summary["seed_points"] = seeded
    for p in summary.get("problems", []):
        log(f"warning: {p}")
    one = summary.get("one_camera_markers") or []
    if one and len(summary.get("cameras", [])) > 1:
        log(f"note: {len(one)} marker(s) placed in one camera only (no 3D for them): {', '.join(map(str, one))}")
    emit(summary, args.json, _text(summary))
    return 0 if summary.get("frames", 0) > 0 else 1


def xyz_uncertainty(project, summary: dict) -> dict:
    """The median 1-sigma sd per axis (mm) of the triangulated XYZ over the tracked frames, and how many
    points had one: {"xyz_sd_median_mm": {"X": .., "Y": .., "Z": ..}, "xyz_points_with_sd": n}; empty
    without a calibration."""
    import numpy as np

    from ..xyz import SD_COLUMNS, compute_xyz, project_sd_holds

    first, last = summary.get("first_frame"), summary.get("last_frame")
    if first is None or last is None or project.calibration() is None:
        return {}
    lo, hi = sorted((int(first), int(last)))
    try:
        table = compute_xyz(project, method="triangulation", frames=range(lo, hi + 1))
    except SandtrackError:
        return {}
    sd = table[list(SD_COLUMNS)].to_numpy(float)
    ok = np.isfinite(sd).all(axis=1)
    if not ok.any():
        return {"xyz_points_with_sd": 0}
    med = np.median(sd[ok], axis=0)
    return {"xyz_sd_median_mm": {a: round(float(v), 4) for a, v in zip("XYZ", med, strict=True)},
            "xyz_points_with_sd": int(ok.sum()), "xyz_sd_holds": project_sd_holds(project, table)}


def _run_every(args) -> int:
    from ..store import Project
    from ..tracking.gaps import MAX_GAP_FRAMES
    from ..tracking.particles import track_every_particle

    max_gap = MAX_GAP_FRAMES if args.max_gap is None else args.max_gap
    if max_gap < 1:
        raise SandtrackError(f"--max-gap must be at least 1 frame, not {max_gap}")
    with Project.open(args.project) as proj:
        bar = Progress(1, "track")

        def progress(done, total):
            bar.total = max(total, 1)
            bar.update(done)

        summary = track_every_particle(proj, like=args.like, start=args.start, stop=args.stop,
                                       new_particles=args.new_particles, progress=progress,
                                       gap_closing=not args.no_gap_closing, pairing=not args.no_pairing,
                                       max_gap=max_gap)
        bar.close()
    summary["project"] = str(args.project)
    lines = []
    for c, v in summary["cameras"].items():
        lines.append(f"{c}: frames {v['first_frame']}..{v['last_frame']}: {v['seeded']} particles seeded, "
                     f"{v['tracked']} points tracked, {v['new']} new, {v['flagged']} flagged "
                     f"({v['occluded']} occluded, {v['lost']} lost); "
                     f"{v['cpu_ms_per_particle_frame']:.3f} ms CPU per particle-frame")
    lines += _joins_text(summary.get("joins"))
    lines.append(f"{summary['rows_written']} points written (one edit: `u` in the TUI undoes it)")
    emit(summary, args.json, "\n".join(lines))
    return 0 if summary.get("frames", 0) > 0 else 1


def _joins_text(joins: dict | None) -> list[str]:
    if not joins:
        return []
    lines = [f"{c}: {v['gaps_closed']} gaps closed (pieces of one track joined), {v['gaps_left_apart']} left apart "
             f"(another piece as likely)" for c, v in joins["gaps"].items()]
    pairing = joins.get("pairing")
    if pairing:
        amb = ", ".join(f"{c} {n}" for c, n in pairing["unpaired_ambiguous"].items())
        alone = ", ".join(f"{c} {n}" for c, n in pairing["unpaired_alone"].items())
        lines.append(f"{pairing['paired']} particles paired across the views (one marker each, 3D); left unpaired: "
                     f"{amb} tracks with another track on their epipolar line as well, {alone} with none")
    return lines


def _text(s: dict) -> str:
    from ..tracking.appearance import describe_text

    lines = [f"tracked {s.get('frames', 0)} frames {s['direction']} "
             f"({s.get('first_frame', '-')}..{s.get('last_frame', '-')}), "
             f"stereo check {'on' if s.get('stereo') else 'off'}, {s.get('rows_written', 0)} points written"]
    for m, cams in s.get("per_marker", {}).items():
        parts = [f"{c}: {v['tracked']} tracked, {v['occluded']} occluded, {v['lost']} lost" for c, v in cams.items()]
        lines.append(f"  marker {m}: " + "; ".join(parts))
        looks = [f"{c} {describe_text(v['appearance'])}" for c, v in cams.items() if v.get("appearance")]
        if looks:
            lines.append("    appearance: " + "; ".join(looks))
    if s.get("paired_across_views"):
        merged = ", ".join(f"{p['from']} ({p['camera']}) into {p['marker']}" for p in s["paired_across_views"])
        lines.append(f"  {len(s['paired_across_views'])} bead(s) seen in one view each, paired across the views by "
                     f"their tracks, made one marker with both views (3D): {merged}")
    if s.get("stereo_flags"):
        lines.append(f"  {len(s['stereo_flags'])} stereo inconsistencies flagged (view dropped, searched again)")
    if s.get("ambiguous"):
        lines.append(f"  {len(s['ambiguous'])} ambiguous re-acquisitions left to the operator")
    if s.get("never_found"):
        lines.append("  never found: " + ", ".join(s["never_found"]))
    if s.get("xyz_sd_median_mm"):
        sd = s["xyz_sd_median_mm"]
        lines.append(f"  XYZ by triangulation, median sd (1 sigma): X {sd['X']:.3f}, Y {sd['Y']:.3f}, "
                     f"Z {sd['Z']:.3f} mm over {s['xyz_points_with_sd']} points")
        if s.get("xyz_sd_holds"):
            lines.append(f"  {s['xyz_sd_holds']}")
    if s.get("stopped"):
        lines.append("  stopped early; what was tracked is saved")
    return "\n".join(lines)
