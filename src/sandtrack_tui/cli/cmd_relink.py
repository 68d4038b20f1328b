"""`sandtrack relink PROJECT --side PATH [--front PATH]`: point a project at moved or changed videos."""

from __future__ import annotations

from ..store import Project
from .common import add_json_flag, emit


def register(sub) -> None:
    p = sub.add_parser("relink", help="point a project at videos that moved or changed")
    p.add_argument("project", help="project file (NAME.sandtrack)")
    p.add_argument("--side", help="new path of the side camera video")
    p.add_argument("--front", help="new path of the front camera video")
    p.add_argument("--camera", action="append", default=[], metavar="NAME=PATH", help="any other camera")
    add_json_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import SandtrackError

    links = dict(c.split("=", 1) for c in args.camera if "=" in c)
    if args.side:
        links["side"] = args.side
    if args.front:
        links["front"] = args.front
    with Project.open(args.project) as proj:
        if not links:
            problems = proj.video_problems()
            result = {"problems": [p.message() for p in problems]}
            emit(result, args.json, text="\n".join(result["problems"]) or "all videos found and unchanged")
            return 1 if problems else 0
        unknown = set(links) - set(proj.videos())
        if unknown:
            raise SandtrackError(f"the project has no camera {', '.join(sorted(unknown))} "
                                 f"(cameras: {', '.join(proj.cameras())})")
        refs = {cam: proj.link_video(cam, path) for cam, path in links.items()}
        result = {"relinked": {c: r.path for c, r in refs.items()},
                  "problems": [p.message() for p in proj.video_problems()]}
    emit(result, args.json, text="\n".join(f"{c}: {p}" for c, p in result["relinked"].items()))
    return 0
