"""`sandtrack [tui] [PROJECT]`: the terminal UI.

Without a project it opens the sample project: a project file in the user's data folder
(``$XDG_DATA_HOME/sandtrack/sample.sandtrack``, else ``~/.local/share/sandtrack/``) that links the
bundled sample videos (``sample_data/experiment/side.mp4``, ``front.mp4``) and comes ready for
tracking: synced from the videos' audio, with the sample's calibration, its calibration points
and its trained network (``sample_data/calibration.toml``, ``calibration/points.csv``, ``model.pt``,
made by ``make sample-model``), so that the live table shows XYZ by triangulation and by the
network from the first marker on. It is made on first run and made again if the sample videos
change; a sample project made before these were bundled gets what it lacks once.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from ..errors import SandtrackError
from .common import log

REPO_ROOT = Path(__file__).resolve().parents[3]
SAMPLE_DATA = Path(os.environ.get("SANDTRACK_SAMPLE_DATA", REPO_ROOT / "sample_data"))
CALIBRATION_CANDIDATES = ("experiment/calibration.toml", "calibration.toml", "ground_truth/cameras.toml")
SAMPLE_MODEL = "model.pt"
SAMPLE_POINTS = "calibration/points.csv"
SETUP_KEY = "sample_setup"  # meta key: the sample project got its sync, calibration and network


def register(sub) -> None:
    p = sub.add_parser("tui", help="open the terminal UI (default)")
    p.add_argument("project", nargs="?", help="project file; the bundled sample project if omitted")
    p.add_argument("--video", action="append", default=[], metavar="CAMERA=PATH",
                   help="relink a camera's video before opening (e.g. after moving the files)")
    p.add_argument("--colors", choices=["truecolor", "256"],
                   help="force the colour mode (default: detected; over SSH set COLORTERM=truecolor)")
    p.add_argument("--graphics", choices=["auto", "kitty", "sixel", "blocks"], default="auto",
                   help="how frames are drawn: real pixels through the kitty graphics protocol or sixel, or "
                        "half-block characters; auto (default) asks the terminal")
    p.set_defaults(func=run)


def data_dir() -> Path:
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "sandtrack"


def sample_project(sample_data: Path = SAMPLE_DATA, target: Path | None = None) -> Path:
    """The sample project file, made (or remade if the sample videos changed) as needed."""
    from ..store import Project

    side, front = sample_data / "experiment" / "side.mp4", sample_data / "experiment" / "front.mp4"
    if not (side.is_file() and front.is_file()):
        raise SandtrackError(f"no project given and the sample videos are missing ({side}); "
                             "make them with `make sample`, or open a project: sandtrack PROJECT.sandtrack")
    path = target or data_dir() / "sample.sandtrack"
    if path.exists():
        try:
            with Project.open(path) as proj:
                problems = proj.video_problems()
                done = proj.meta(SETUP_KEY) is not None
        except SandtrackError:
            problems = ["unreadable"]
        if not problems:
            if not done:
                with Project.open(path) as proj:
                    _set_up(proj, sample_data)
            return path
        if Path(str(path) + "-wal").exists():
            # SQLite removes the WAL when the last connection closes: someone still has it open
            raise SandtrackError(f"the sample videos changed, but the sample project {path} is open in another "
                                 "sandtrack: close that one first")
        backup = path.with_suffix(".sandtrack.old")
        shutil.move(path, backup)  # the sample changed: keep the old edits aside, start afresh
        for suffix in ("-wal", "-shm"):
            Path(str(path) + suffix).unlink(missing_ok=True)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SandtrackError(f"cannot create {path.parent}: {exc.strerror}") from None
    with Project.create(path, {"side": side, "front": front}) as proj:
        _set_up(proj, sample_data)
    return path


def _set_up(proj, sample_data: Path) -> None:
    """Give the sample project what it lacks of: calibration, sync offset, calibration points and network."""
    from ..camera import Calibration

    if proj.get("calibration") is None:
        for rel in CALIBRATION_CANDIDATES:
            cal_path = sample_data / rel
            if cal_path.is_file():
                try:
                    proj.set_calibration(Calibration.load(cal_path))
                    break
                except SandtrackError:
                    continue
    if not proj.sync_confirmed():
        _sync(proj)
    points = sample_data / SAMPLE_POINTS
    if proj.get("calibration_points") is None and points.is_file():
        proj.set("calibration_points", str(points.resolve()), "sample calibration points")
    model = sample_data / SAMPLE_MODEL
    if proj.get("model") is None and model.is_file():
        _link_model(proj, model)
    proj.set_meta(SETUP_KEY, "1")  # once: what the user undoes afterwards stays undone


def _sync(proj) -> None:
    """The sample's own audio sync (the F2 screen's result); left unset when the videos have no clap."""
    from ..sync import estimate_offset

    vids = proj.videos()
    log("sample project: syncing the sample videos from their audio (once)")
    try:
        res = estimate_offset(vids["side"].path, vids["front"].path, method="audio")
    except SandtrackError as exc:
        log(f"sample project: not synced ({exc}); F2 syncs it")
        return
    proj.set("sync_offset_s", res.offset_s, f"sync offset {res.offset_s * 1000:+.2f} ms ({res.method})")


def _link_model(proj, model: Path) -> None:
    from ..regression.workflow import PROJECT_KEYS
    from ..xyz import load_cached_model

    try:
        metrics = load_cached_model(model).metrics
    except SandtrackError as exc:
        log(f"sample project: the bundled network is unreadable ({exc}); F4 trains one")
        return
    proj.set("model", {"path": str(model.resolve()), **{k: metrics[k] for k in PROJECT_KEYS if k in metrics}},
             "sample network")


def relink(path: Path, specs: list[str]) -> None:
    from ..store import Project

    with Project.open(path) as proj:
        for spec in specs:
            camera, sep, video = spec.partition("=")
            if not sep or not camera or not video:
                raise SandtrackError(f"--video wants CAMERA=PATH, not {spec!r}")
            if not Path(video).exists():
                raise SandtrackError(f"video not found: {video}")
            proj.link_video(camera, video)


def run(args) -> int:
    path = Path(args.project) if args.project else sample_project()
    if args.video:
        relink(path, args.video)
    from ..tui.app import SandtrackApp
    from ..tui.termcaps import detect

    app = SandtrackApp(path, colors=args.colors)
    app.pixels.graphics = detect(args.graphics)  # after the project opened: a bad one never queries the terminal
    app.run()
    return int(app.return_code or 0)
