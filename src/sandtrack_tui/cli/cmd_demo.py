"""`sandtrack demo [--fast] [--json]`: the whole pipeline on the rendered rig, scored against truth."""

from __future__ import annotations

from .common import add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser(
        "demo", help="run the whole pipeline on the sample data and score every stage against the truth",
        description="sync -> calibrate -> world frame -> calibration points -> train -> auto-seed -> track -> "
                    "XYZ -> export -> compare with the DEM trajectories, on the rendered rig. The regression "
                    "stage trains on the full preset's calibration videos (rendered once into the cache, "
                    "$SANDTRACK_CACHE or ~/.cache/sandtrack).")
    p.add_argument("--fast", action="store_true", help="small preset only and few epochs (about a minute)")
    p.add_argument("--epochs", type=int, help="training epochs (default: the regression's own)")
    p.add_argument("--workdir", help="keep the demo's project, model and exports in this folder")
    add_json_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..demo import format_table, run_demo

    result = run_demo(fast=args.fast, workdir=args.workdir, log=log, epochs=args.epochs)
    emit(result, args.json, text=format_table(result))
    return 0
