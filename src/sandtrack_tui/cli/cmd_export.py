"""`sandtrack export PROJECT -o FILE [--format csv|parquet|dltdv]`: the 3D trajectories of every camera."""

from __future__ import annotations

from pathlib import Path

from ..errors import SandtrackError
from .common import add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser("export", help="export the 3D trajectories (tidy CSV, Parquet, DLTdv/Argus CSVs)")
    p.add_argument("project", help="project file (NAME.sandtrack)")
    p.add_argument("-o", "--output", required=True,
                   help="output file (.csv, .parquet), or the file prefix for --format dltdv")
    p.add_argument("--format", choices=["csv", "parquet", "dltdv"], default=None,
                   help="default: from the output's suffix")
    p.add_argument("--covariance", action="store_true",
                   help="tidy table: also the triangulated rows' covariances between the axes (cov_XY_mm2, "
                        "cov_XZ_mm2, cov_YZ_mm2, after the sd)")
    p.add_argument("--method", choices=["both", "all", "triangulation", "mlp", "residual"], default="both",
                   help="3D method(s) to export (dltdv takes one: triangulation unless mlp is given)")
    add_json_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..store import Project
    from ..trajectories import export, export_table
    from ..xyz import project_sd_holds

    with Project.open(args.project) as proj:
        vids = proj.videos()
        if not vids:
            raise SandtrackError(f"{args.project}: the project has no videos")
        heights = {c: float(v.height) for c, v in vids.items()}
        log(f"export: computing 3D positions ({args.method})")
        df, pixels_only = export_table(proj, method=args.method, covariance=args.covariance)
        holds = None if pixels_only else project_sd_holds(proj, df)
    if pixels_only:
        log(f"export: {pixels_only}")
    method = None if args.method in ("both", "all") or pixels_only else args.method
    paths = export(df, Path(args.output), fmt=args.format, heights=heights, method=method)
    result = {"files": [str(p) for p in paths], "rows": int(len(df)), "markers": int(df["marker"].nunique()),
              "frames": int(df["frame"].nunique()), "pixels_only": pixels_only}
    if holds:
        result["sd_holds"] = holds
    emit(result, args.json, text="\n".join([f"wrote {p}" for p in paths] + ([holds] if holds else [])))
    return 0
