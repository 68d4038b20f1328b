"""`sandtrack sync SIDE FRONT [--project P]` or `sandtrack sync PROJECT.sandtrack`: the camera time offset."""

from __future__ import annotations

from pathlib import Path

from ..errors import SandtrackError
from .common import add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser("sync", help="time offset between the side and front videos (audio clap, else video)",
                       description="Finds how much later the front camera started recording than the side "
                                   "camera (an event at side time t is at front time t - offset).")
    p.add_argument("inputs", nargs="+", metavar="SIDE FRONT | PROJECT",
                   help="the side and front videos, or a project file (its videos; the offset is stored)")
    p.add_argument("--project", help="store the offset into this project file")
    p.add_argument("--method", choices=["auto", "audio", "video"], default="auto",
                   help="audio (clap), video (flash or motion onset), or auto: audio, else video (default)")
    p.add_argument("--max-offset", type=float, default=None, metavar="S",
                   help="largest plausible |offset| in seconds (narrows the search)")
    p.add_argument("--min-confidence", type=float, default=None, metavar="C",
                   help="refuse below this confidence (0-1, default 0.35)")
    add_json_flag(p)
    p.set_defaults(func=run)


def _is_project(path: str) -> bool:
    p = Path(path)
    if p.suffix == ".sandtrack":
        return True
    try:
        with p.open("rb") as fh:
            return fh.read(16) == b"SQLite format 3\x00"
    except OSError:
        return False


def run(args) -> int:
    from ..store import Project
    from ..sync import MIN_CONFIDENCE, estimate_offset, sound_path_bound_s, sound_path_line
    from ..xyz import project_calibration

    project_path = args.project
    if len(args.inputs) == 1:
        if not _is_project(args.inputs[0]):
            raise SandtrackError("give two videos (SIDE FRONT) or one project file (NAME.sandtrack)")
        project_path = args.inputs[0]
        with Project.open(project_path) as proj:
            vids = proj.videos()
            if "side" not in vids or "front" not in vids:
                raise SandtrackError(f"{project_path}: the project needs a side and a front video to sync")
            for problem in proj.video_problems(check_content=False):
                raise SandtrackError(problem.message())
            side, front = vids["side"].path, vids["front"].path
    elif len(args.inputs) == 2:
        side, front = args.inputs
    else:
        raise SandtrackError("give two videos (SIDE FRONT) or one project file")
    log(f"sync: {side} <-> {front} ({args.method})")
    res = estimate_offset(side, front, method=args.method, max_offset_s=args.max_offset,
                          min_confidence=MIN_CONFIDENCE if args.min_confidence is None else args.min_confidence)
    out = {"side": str(side), "front": str(front), **res.to_dict()}
    bound = None
    if project_path:
        with Project.open(project_path) as proj:
            proj.set("sync_offset_s", res.offset_s, f"sync offset {res.offset_s * 1000:+.2f} ms ({res.method})")
            proj.set("sync_result", {k: v for k, v in out.items() if k != "details"}, "sync details")
            if res.method == "audio":
                bound = sound_path_bound_s(project_calibration(proj))
        out["project"] = str(project_path)
    text = res.summary()
    if bound is not None:
        out["sound_path_bound_ms"] = 1000.0 * bound
        text += "\n" + sound_path_line(bound)
    if "warning" in res.details:
        log(f"warning: {res.details['warning']}")
    if project_path:
        text += f"\nstored in {project_path}"
    emit(out, args.json, text)
    return 0

