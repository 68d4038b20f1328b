"""`sandtrack import PROJECT FILE --format davinci|dltdv ...`: pixel tracks from other tools."""

from __future__ import annotations

from pathlib import Path

from ..errors import SandtrackError
from .common import add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser("import", help="import pixel tracks (DaVinci Resolve tracker CSV, DLTdv/Argus xypts)",
                       description="Imported points get status 'imported'; the whole file is validated first "
                                   "and written as one undoable edit.")
    p.add_argument("project", help="project file (NAME.sandtrack)")
    p.add_argument("file", help="the file to import")
    p.add_argument("--format", choices=["davinci", "dltdv"], required=True)
    p.add_argument("--camera", help="davinci: the camera the track belongs to (a camera of the project)")
    p.add_argument("--marker", type=int, help="davinci: marker id to write (created if new)")
    p.add_argument("--label", help="davinci: label for a new marker")
    p.add_argument("--y-units", choices=["height", "width"],
                   help="davinci: y normalised by image height (point controls) or width (paths; 0-0.5625 for 16:9)")
    p.add_argument("--frame-offset", type=int, default=0,
                   help="davinci: subtract this from the file's frame numbers (e.g. a timeline start)")
    p.add_argument("--cameras",
                   help="dltdv: project camera names for cam1,cam2,... (default: the project's cameras in order, "
                        "side and front first)")
    p.add_argument("--first-frame", type=int, default=0, help="dltdv: frame index of the file's first row")
    p.add_argument("--no-flip-y", action="store_true", help="dltdv: y is already top-left origin, y down")
    p.add_argument("--preview", metavar="PNG",
                   help="also write the imported track over its middle frame, to check the convention")
    add_json_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import pandas as pd

    from ..store import Project
    from ..trajectories import import_points, read_davinci, read_dltdv_xypts

    with Project.open(args.project) as proj:
        vids = proj.videos()
        if args.format == "davinci":
            if not args.camera or args.marker is None or not args.y_units:
                raise SandtrackError("davinci import needs --camera, --marker and --y-units (height or width)")
            if args.camera not in vids:
                raise SandtrackError(f"the project has no {args.camera} video "
                                     f"(its cameras: {', '.join(proj.cameras())})")
            ref = vids[args.camera]
            pts = read_davinci(args.file, ref.width, ref.height, args.y_units, args.frame_offset)
            rows = pts.assign(camera=args.camera, marker=args.marker)
            labels = {args.marker: args.label} if args.label else None
        else:
            cams = tuple(c.strip() for c in args.cameras.split(",") if c.strip()) if args.cameras else \
                tuple(proj.cameras())
            missing = [c for c in cams if c not in vids]
            if missing:
                raise SandtrackError(f"the project has no {', '.join(missing)} video")
            pts = read_dltdv_xypts(args.file, {c: vids[c].height for c in cams}, cams,
                                   flip_y=not args.no_flip_y, first_frame=args.first_frame)
            rows = pts.rename(columns={"point": "marker"})
            labels = {int(m): f"pt{int(m)}" for m in rows["marker"].unique()}
        rows = pd.DataFrame(rows[["frame", "camera", "marker", "x_px", "y_px"]])
        result = import_points(proj, rows, f"import {Path(args.file).name} ({args.format})", labels)
        if args.preview:
            _preview(proj, rows, args.preview)
            result["preview"] = args.preview
    log(f"imported {result['points']} points")
    emit(result, args.json, text=f"imported {result['points']} points of markers "
                                  f"{', '.join(map(str, result['markers']))} into {args.project}")
    return 0


def _preview(proj, rows, png) -> None:
    import cv2

    from ..trajectories import preview_image

    cam = rows["camera"].iloc[0]
    r = rows[rows["camera"] == cam]
    frame = int(r["frame"].iloc[len(r) // 2])
    src = proj.open_sources(cache_mb=32)[cam]
    img = preview_image(src.frame(frame), r, frame)
    if not cv2.imwrite(str(png), img):
        raise SandtrackError(f"cannot write {png}")
