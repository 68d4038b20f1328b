"""`sandtrack new EXP.sandtrack --side SIDE [--front FRONT] [--camera NAME=PATH ...] [--board BOARD.toml]`."""

from __future__ import annotations

from pathlib import Path

from ..board import load_board
from ..errors import SandtrackError
from ..store import Project
from ..video import FramePair, FrameSource
from .common import add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser("new", help="create a project from a pair of videos")
    p.add_argument("project", help="project file to create (NAME.sandtrack)")
    p.add_argument("--side", required=True, help="side camera video (or image folder)")
    p.add_argument("--front", help="front camera video (or image folder); omit for a 2D-only project")
    p.add_argument("--camera", action="append", default=[], metavar="NAME=PATH",
                   help="another camera's video or image folder (repeatable; three or more cameras)")
    p.add_argument("--board", help="calibration board file (board.toml or Caliscope charuco.toml)")
    p.add_argument("--fps", type=float, help="frame rate of image folders (default 50; a video's own rate is read "
                   "from the file)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing project file")
    add_json_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    videos = {"side": args.side}
    if args.front:
        videos["front"] = args.front
    for spec in args.camera:
        name, sep, path = spec.partition("=")
        name = name.strip()
        if not sep or not name or not path:
            raise SandtrackError(f"--camera wants NAME=PATH, not {spec!r}")
        if name in videos:
            raise SandtrackError(f"camera {name!r} given twice")
        videos[name] = path
    if args.fps is not None and not 0 < args.fps <= 100_000:
        raise SandtrackError(f"--fps must be a frame rate above 0, not {args.fps:g}")
    sources = {c: FrameSource(v, cache_mb=16, fps=args.fps) for c, v in videos.items()}  # validates before creating
    warnings = []
    if "front" in sources:
        warnings = FramePair(sources["side"], sources["front"]).mismatch_warnings()
    for w in warnings:
        log(f"warning: {w}")
    board = load_board(args.board) if args.board else None
    proj = Project.create(Path(args.project), videos, overwrite=args.overwrite, fps=args.fps)
    if board is not None:
        proj.set("board", board.to_json_dict(), "set board")
    result = {
        "project": str(proj.path),
        "videos": {c: s.describe() for c, s in sources.items()},
        "warnings": warnings,
    }
    proj.close()
    emit(result, args.json, text=f"created {result['project']}")
    return 0
