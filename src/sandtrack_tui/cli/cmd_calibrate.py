"""`sandtrack calibrate`: cameras from board videos, from known points, or from Caliscope files.

    sandtrack calibrate --board BOARD.toml --side SIDE --front FRONT -o calibration.toml
        [--points points.csv] [--reference-frame N] [--reference-origin-mm X,Y,Z]
        [--reference reference.toml] [--camera NAME=PATH ...] [--project P.sandtrack] [--json]
    sandtrack calibrate --from-points points.csv -o calibration.toml [--image-size WxH] [--side V --front V]
    sandtrack calibrate --import-caliscope camera_array.toml [--names side,front] -o calibration.toml
    sandtrack calibrate --calibration calibration.toml --export-caliscope camera_array.toml
"""

from __future__ import annotations

import math
import time
from pathlib import Path

from ..errors import SandtrackError
from ..lens import LENS_NAMES
from .common import Progress, add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="calibrate the cameras (board videos, known points or Caliscope files)")
    p.add_argument("--board", help="board file (board.toml or Caliscope charuco.toml)")
    p.add_argument("--side", help="side camera calibration video or image folder")
    p.add_argument("--front", help="front camera calibration video or image folder")
    p.add_argument("--camera", action="append", default=[], metavar="NAME=PATH",
                   help="another camera's video or image folder (repeatable; for more than two cameras)")
    p.add_argument("-o", "--output", help="calibration file to write (calibration.toml)")
    p.add_argument("--points", help="also write the calibration points CSV (every corner seen by both cameras)")
    p.add_argument("--reference-frame", type=int, help="side frame where the board lies flat on the sand (world frame)")
    p.add_argument("--reference-origin-mm", help="world position X,Y,Z (mm) of the board origin in that frame")
    p.add_argument("--reference", help="reference.toml with `frame` and `origin_mm` (instead of the two above)")
    p.add_argument("--known-points", help="CSV of known world points (X_mm, Y_mm, Z_mm + pixel columns) for the "
                   "world frame (Kabsch, >= 3 points)")
    p.add_argument("--offset-s", action="append", default=[], metavar="[CAMERA=]SECONDS",
                   help="how much later a camera started recording than the first (side) camera (s): SECONDS for "
                   "the front camera (for every other camera where there is no front), CAMERA=SECONDS for one "
                   "(repeatable); default: measured from the audio (or the video) as `sandtrack sync` does")
    p.add_argument("--lens", action="append", default=[], metavar="[CAMERA=]MODEL",
                   help="lens model: auto (default: the simplest model whose cross-validated error is within "
                   f"noise of the best), or one of {', '.join(LENS_NAMES)}; CAMERA=MODEL for one camera (repeatable)")
    p.add_argument("--fisheye", action="append", default=[], metavar="NAME",
                   help="use the fisheye lens model for this camera (repeatable; same as --lens NAME=fisheye)")
    p.add_argument("--image-size", action="append", default=[], metavar="[CAMERA=]WxH",
                   help="image size for --from-points (default: read from the videos when given, else unknown: "
                   "the fit then uses the points only); CAMERA=WxH for one camera (repeatable)")
    p.add_argument("--budget", type=int, default=400, help="frames per camera searched first (default 400)")
    p.add_argument("--project", help="store the calibration and board in this project")
    p.add_argument("--from-points", help="fit the cameras to known correspondences (CSV: pixel columns + X/Y/Z_mm)")
    p.add_argument("--import-caliscope", help="read a Caliscope camera_array.toml or config.toml")
    p.add_argument("--names", help="camera names for --import-caliscope, in camera id order (e.g. side,front)")
    p.add_argument("--calibration", help="an existing calibration.toml (for --export-caliscope)")
    p.add_argument("--export-caliscope", help="also write the calibration as a Caliscope camera_array.toml")
    add_json_flag(p)
    p.set_defaults(func=run)


def _progress_fn(enabled: bool):
    bars: dict[str, Progress] = {}

    def fn(stage: str, done: int, total: int) -> None:
        if not enabled:
            return
        bar = bars.get(stage)
        if bar is None:
            bar = bars[stage] = Progress(total, label=stage)
        bar.total = max(total, 1)
        bar.update(done)
        if done >= total:
            bar.close()

    return fn


def run(args) -> int:
    t0 = time.perf_counter()
    modes = [m for m in (args.from_points, args.import_caliscope, args.calibration) if m]
    if len(modes) > 1:
        raise SandtrackError("use only one of --from-points, --import-caliscope, --calibration")
    if args.from_points:
        result = _from_points(args)
    elif args.import_caliscope:
        result = _import(args)
    elif args.calibration:
        from ..camera import Calibration

        cal = Calibration.load(args.calibration)
        result = {"calibration": cal, "report": dict(cal.report)}
    else:
        result = _from_videos(args)
    cal = result["calibration"]
    report = result["report"]
    if args.output:
        cal.save(args.output)
        report["output"] = str(args.output)
    if args.export_caliscope:
        from ..calibration.caliscope import export_caliscope

        notes = export_caliscope(cal, args.export_caliscope)
        report["caliscope_export"] = str(args.export_caliscope)
        if notes:
            report["warnings"] = list(report.get("warnings") or []) + notes
    if args.project:
        from ..store import Project

        proj = Project.open(args.project)
        try:
            proj.set_calibration(cal)
            if result.get("board") is not None:
                proj.set("board", result["board"].to_json_dict(), "set board")
        finally:
            proj.close()
        report["project"] = str(args.project)
    if not (args.output or args.export_caliscope or args.project):
        raise SandtrackError("nothing to write: give -o calibration.toml, --export-caliscope or --project")
    report.setdefault("seconds", time.perf_counter() - t0)
    out = _summary(report)
    emit(out, args.json, text=_text(out))
    return 0


def _summary(report: dict) -> dict:
    keys = ["reprojection_rmse_px", "board_rmse_mm", "xyz_rmse_mm", "xyz_mean_mm", "per_camera", "views_used",
            "points", "seconds",
            "seconds_detect", "seconds_calibrate", "frames_detected", "corners_detected", "world", "warnings",
            "sync", "output", "points_csv", "caliscope_export", "project", "method", "source",
            "known_points_sd_mm", "known_points_in_two_cameras", "view_motion"]
    out = {k: report[k] for k in keys if k in report}
    out.setdefault("points", 0)
    out.setdefault("board_rmse_mm", None)  # only a board calibration measures the board
    return out


def _text(r: dict) -> str:
    lines = []
    if "reprojection_rmse_px" in r:
        lines.append(f"reprojection RMSE {r['reprojection_rmse_px']:.3f} px")
    if r.get("board_rmse_mm") is not None:
        lines.append(f"board geometry RMSE {r['board_rmse_mm']:.3f} mm")
    for n, c in (r.get("per_camera") or {}).items():
        rm = c.get("reprojection_rmse_px", c.get("rmse_px"))
        fx = c.get("fx")
        lens = f", lens {c['lens']}" if c.get("lens") else ""
        sd = f" ± {c['fx_sd_px']:.2f} px (1 sd of the fit)" if c.get("fx_sd_px") is not None else " px"
        lines.append(f"  {n}: fx {fx:.2f}{sd}, RMSE {rm:.3f} px{lens}" if fx is not None and rm is not None
                     else f"  {n}")
        if c.get("misdetected_corners") is not None:
            x, y = c["noise_px"]
            lines.append(f"    {c['misdetected_corners']} of {c['corners_screened']} corners misdetected (beyond "
                         f"{c['misdetection_limit_sd']:g} robust sd: not in the calibration points); the others' pixel "
                         f"noise x {x:.3f}, y {y:.3f} px")
            if c.get("view_shared_px"):
                lines.append("    and a shift one view's corners share, which its board pose absorbs, allowed for in a "
                             "corner's pixel sd: x {:.3f}, y {:.3f} px".format(*c["view_shared_px"]))
        elif c.get("noise_px"):
            lines.append("    own pixel noise (the known points' error taken out) x {:.3f}, y {:.3f} px"
                         .format(*c["noise_px"]))
        if c.get("calibrated_region_pct") is not None:
            lines.append(f"    the convex hull of its calibration points spans {c['calibrated_region_pct']:.0f} % of "
                         "the image (XYZ from pixels beyond it: calibrated_region = outside)")
        lines += _selection_lines(c.get("lens_selection"))
    if r.get("known_points_sd_mm"):
        lines.append("known points' own error (sd per axis, X / Y / Z): {:.4f} / {:.4f} / {:.4f} mm, from {} "
                     "points seen by two cameras or more".format(*r["known_points_sd_mm"],
                                                                 r.get("known_points_in_two_cameras")))
    world = r.get("world") or {}
    if world.get("rotation_sd_mrad"):
        lines.append("world frame ({}): rotation ± {:.3f} / {:.3f} / {:.3f} mrad about X / Y / Z, origin ± {:.3f} / "
                     "{:.3f} / {:.3f} mm (1 sd, the cameras' part included)"
                     .format(world.get("method", ""), *world["rotation_sd_mrad"], *world["origin_sd_mm"]))
    motion = r.get("view_motion") or {}
    if motion.get("views"):
        lines.append("one frame's views disagree as if the board moved between the cameras' exposures: sd {:.3f} / "
                     "{:.3f} / {:.3f} deg, {:.3f} / {:.3f} / {:.3f} mm about / along the rig's x / y / z ({} views; "
                     "in the parameters' sd)".format(*motion["rotation_sd_deg"], *motion["translation_sd_mm"],
                                                     motion["views"]))
    if "views_used" in r:
        lines.append(f"views used {r['views_used']}, points {r.get('points', 0)}, {r.get('seconds', 0):.1f} s")
    for w in r.get("warnings", []) or []:
        lines.append(f"warning: {w}")
    for k in ("output", "points_csv", "caliscope_export", "project"):
        if k in r:
            lines.append(f"wrote {r[k]}")
    return "\n".join(lines)


def _selection_lines(sel: dict | None) -> list[str]:
    """The candidates of an automatic lens choice: training and cross-validated RMSE (px), and each one
    against the best on the same left-out units (RMSE above the best, units worse / better, p-value)."""
    if not sel:
        return []
    out = [f"    lens auto: {sel['cross_validation']}; {sel.get('compared', '')}",
           f"    rule: {sel['rule']}",
           "      lens            train / left-out px   vs best: RMSE  worse/better units  p"]
    for c in sel["candidates"]:
        if c.get("cv_rmse_px") is None:
            out.append(f"      {c['lens']:<15} {c.get('excluded', '')}")
            continue
        v = c.get("versus_best")
        noise = ("  (below the points' resolution)" if v and v["p_value"] < sel.get("alpha", 0.05)
                 else "  (not significantly worse)")
        mark = "  <- chosen" if c["chosen"] else (noise if c["within_noise"] else "")
        if v and not (v["units_worse"] or v["units_better"]):
            versus = f"{'best':>8}{'':18}"
        else:
            versus = (f"{v['rmse_excess_pct']:+6.1f} %  {v['units_worse']:>3} / {v['units_better']:<3}"
                      f"  {v['p_value']:<7.2g}" if v else "")
        out.append(f"      {c['lens']:<15} {c['train_rmse_px']:.3f} / {c['cv_rmse_px']:.3f}       {versus}{mark}")
    if sel.get("why"):
        out.append(f"    chosen {sel['why']}")
    if sel.get("spread"):
        out.append(f"    {sel['spread']}")
    return out


def _per_camera(values: list[str], parse) -> tuple[object | None, dict[str, object]]:
    """`--opt VALUE` (every camera) and `--opt CAMERA=VALUE` (one camera) -> (default, {camera: value})."""
    default, per = None, {}
    for v in values:
        name, _, value = v.rpartition("=")
        if name:
            per[name] = parse(value)
        else:
            default = parse(value)
    return default, per


def _lens_name(value: str) -> str:
    if value != "auto" and value not in LENS_NAMES:
        raise SandtrackError(f"--lens {value!r}: unknown lens model (auto, {', '.join(LENS_NAMES)})")
    return value


def _image_size(value: str) -> tuple[int, int]:
    w, sep, h = value.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = (0, 0)
    if not sep or min(size) <= 0:
        raise SandtrackError(f"--image-size {value!r}: give the size as WIDTHxHEIGHT in pixels, e.g. 1920x1080")
    return size


def _lenses(args, names: list[str]) -> dict[str, str]:
    default, per = _per_camera(args.lens, _lens_name)
    for n in args.fisheye:
        per[n] = "fisheye"
    unknown = sorted(set(per) - set(names))
    if unknown:
        raise SandtrackError(f"--lens/--fisheye {', '.join(unknown)}: no such camera ({', '.join(names)})")
    return {n: per.get(n, default or "auto") for n in names}


def _offsets(args, names: list[str]) -> dict[str, float] | None:
    """--offset-s: {camera: its start after the first camera's (s)}; None where none is given."""
    default, per = _per_camera(args.offset_s, _seconds)
    unknown = sorted(set(per) - set(names[1:]))
    if unknown:
        raise SandtrackError(f"--offset-s {', '.join(unknown)}: not a camera after the first, {names[0]} "
                             f"(one of {', '.join(names[1:])})")
    if default is not None:
        for n in ["front"] if "front" in names else names[1:]:
            per.setdefault(n, default)
    return per or None


def _seconds(value: str) -> float:
    try:
        s = float(value)
    except ValueError:
        s = math.nan
    if not math.isfinite(s):
        raise SandtrackError(f"--offset-s {value!r}: give the offset in seconds, e.g. 0.26 or -1.5")
    return s


def _videos(args) -> dict[str, str]:
    videos = _videos_given(args)
    if len(videos) < 2:
        raise SandtrackError("give the calibration videos of two cameras: --side SIDE --front FRONT")
    return videos


def _videos_given(args) -> dict[str, str]:
    videos: dict[str, str] = {}
    if args.side:
        videos["side"] = args.side
    if args.front:
        videos["front"] = args.front
    for spec in args.camera:
        if "=" not in spec:
            raise SandtrackError(f"--camera needs NAME=PATH, not {spec!r}")
        name, path = spec.split("=", 1)
        if not name or name in videos:
            raise SandtrackError(f"--camera {spec!r}: empty or repeated camera name")
        videos[name] = path
    return videos


def _from_videos(args) -> dict:
    import pandas as pd

    from ..board import load_board
    from ..calibration.pipeline import calibrate_videos
    from ..calibration.points import write_points
    from ..calibration.world import load_reference, parse_origin

    if not args.board:
        raise SandtrackError("--board BOARD.toml is needed to calibrate from videos")
    board = load_board(args.board)
    videos = _videos(args)
    names = list(videos)
    ref_frame, origin = args.reference_frame, (0.0, 0.0, 0.0)
    if args.reference:
        ref_frame, origin = load_reference(args.reference)
    if args.reference_frame is not None:
        ref_frame = args.reference_frame
    if args.reference_origin_mm:
        origin = parse_origin(args.reference_origin_mm)
    known = None
    if args.known_points:
        p = Path(args.known_points)
        if not p.is_file():
            raise SandtrackError(f"known points file not found: {p}")
        known = pd.read_csv(p)
    offsets = _offsets(args, names)
    models = _lenses(args, names)
    if not args.json:
        log(f"calibrating {', '.join(names)} with a {board.columns}x{board.rows} {board.type} board")
    res = calibrate_videos(videos, board, offsets_s=offsets, reference_frame=ref_frame, origin_mm=origin,
                           known_points=known, with_points=bool(args.points), models=models,
                           detect_budget=args.budget, progress=_progress_fn(not args.json))
    report = dict(res.report)
    if args.points:
        write_points(res.points, args.points)
        report["points_csv"] = str(args.points)
    return {"calibration": res.calibration, "report": report, "board": board}


def _from_points(args) -> dict:
    from ..calibration.from_points import calibrate_from_points, read_points_table

    t0 = time.perf_counter()
    df, cams = read_points_table(args.from_points)
    if len(cams) < 2:
        raise SandtrackError(f"{args.from_points}: pixel columns of at least two cameras are needed")
    names = list(cams)
    cal = calibrate_from_points(df, cams, sizes=_sizes(args, names), lens=_lenses(args, names))
    report = dict(cal.report)
    report["per_camera"] = report.pop("per_camera")
    report["views_used"] = 0
    report["seconds"] = time.perf_counter() - t0
    cal.report = report
    return {"calibration": cal, "report": report}


def _sizes(args, names: list[str]) -> dict[str, tuple[int, int]]:
    """Image sizes for --from-points: --image-size, else the videos' (--side/--front/--camera)."""
    default, per = _per_camera(args.image_size, _image_size)
    sizes = {n: per.get(n, default) for n in names if per.get(n, default) is not None}
    videos = {}
    if args.side or args.front or args.camera:
        videos = {n: p for n, p in _videos_given(args).items() if n not in sizes}
    from ..calibration.detect import open_source

    for n, path in videos.items():
        if n in names:
            src = open_source(path)
            sizes[n] = (src.width, src.height)
    unknown = sorted(set(per) - set(names))
    if unknown:
        raise SandtrackError(f"--image-size {', '.join(unknown)}: no such camera in the points ({', '.join(names)})")
    return sizes


def _import(args) -> dict:
    from ..calibration.caliscope import import_caliscope

    names = [n.strip() for n in args.names.split(",")] if args.names else None
    cal = import_caliscope(args.import_caliscope, names)
    report = dict(cal.report)
    report["per_camera"] = {n: {"fx": float(c.matrix[0, 0]), "rmse_px": c.rmse_px} for n, c in cal.cameras.items()}
    report["views_used"] = 0
    return {"calibration": cal, "report": report}
