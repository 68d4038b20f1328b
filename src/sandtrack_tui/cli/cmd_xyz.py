"""`sandtrack xyz`: world XYZ of the tracked markers of a project, or of any pixels CSV
(triangulation, the MLP, its residual variant)."""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import SandtrackError
from .common import add_json_flag, emit, log


def register(sub) -> None:
    from ..xyz import METHOD_CHOICES, OUTSIDE_POLICIES

    p = sub.add_parser("xyz", help="world XYZ (mm) of the tracked markers, or of a pixels CSV",
                       description="With a project: print the XYZ table of one frame of its first camera "
                                   "(--frame N) or write every frame to a CSV (-o FILE); the other cameras' pixels "
                                   "are interpolated to that frame's time, and every calibrated camera with a point "
                                   "is triangulated (one camera: x, y in mm through its scale). With a pixels CSV "
                                   "(xs, ys, xf, yf or x_CAMERA, y_CAMERA columns; "
                                   "other columns are passed through): XYZ of every row with --calibration and/or "
                                   "--model, written to -o FILE (or to stdout).")
    p.add_argument("project", metavar="INPUT", help="project file (.sandtrack) or pixels CSV")
    p.add_argument("--frame", type=int, help="frame index of the first camera to print (project)")
    p.add_argument("--calibration", help="calibration.toml (pixels CSV)")
    p.add_argument("--model", help="regression model.pt for the mlp and residual methods (pixels CSV)")
    p.add_argument("--method", choices=METHOD_CHOICES, default="both",
                   help="triangulation, mlp, residual, both (triangulation + mlp; default) or all")
    p.add_argument("--outside", choices=OUTSIDE_POLICIES, default="flag",
                   help="MLP rows outside the training volume: flag as method mlp_outside (default), "
                        "nan (no XYZ) or keep")
    p.add_argument("--covariance", action="store_true",
                   help="also the triangulated rows' covariances between the axes (cov_XY_mm2, cov_XZ_mm2, "
                        "cov_YZ_mm2, after the sd): the errors of X, Y and Z are correlated")
    p.add_argument("-o", "--output", help="write all frames to this CSV")
    add_json_flag(p)
    p.set_defaults(func=run)


def _is_project(path: Path) -> bool:
    """A project is a .sandtrack or SQLite file; anything else is read as a pixels CSV."""
    if path.suffix.lower() == ".sandtrack" or path.is_dir():
        return True
    try:
        with open(path, "rb") as fh:
            return fh.read(16) == b"SQLite format 3\x00"
    except OSError:
        return False


def run(args) -> int:
    path = Path(args.project)
    if not path.exists():
        raise SandtrackError(f"input not found: {path}")
    if not _is_project(path):
        return run_pixels(args)
    if args.calibration or args.model:
        raise SandtrackError("--calibration and --model go with a pixels CSV; a project uses its own")
    return run_project(args)


def run_pixels(args) -> int:
    from ..xyz_pixels import read_pixels, write_table, xyz_from_pixels

    t0 = time.perf_counter()
    if args.frame is not None:
        raise SandtrackError("--frame goes with a project; a pixels CSV gives XYZ for every row")
    calibration = model = None
    if args.calibration:
        from ..camera import Calibration

        calibration = Calibration.load(args.calibration)
    if args.model:
        from ..xyz import load_cached_model

        model = load_cached_model(args.model)
    df, cams = read_pixels(args.project)
    t_read = time.perf_counter() - t0
    table, notes = xyz_from_pixels(df, cams, calibration, model, method=args.method, outside=args.outside,
                                   covariance=args.covariance)
    t_xyz = time.perf_counter() - t0 - t_read
    if args.output:
        out = Path(args.output)
        if not out.parent.exists():
            raise SandtrackError(f"folder does not exist: {out.parent}")
        write_table(table, out)
    elif not args.json:
        write_table(table, None)
    result = {"rows": len(df), "cameras": {n: list(xy) for n, xy in cams.items()},
              "methods": {m: {"rows": int(len(g)), "with_xyz": int(g["X_mm"].notna().sum())}
                          for m, g in table.groupby("method")},
              "notes": notes, "seconds_read": t_read, "seconds_xyz": t_xyz, "seconds": time.perf_counter() - t0}
    if args.output:
        result["output"] = str(args.output)
    elif args.json:
        result["table"] = table.to_dict(orient="records")
    lines = [f"{m}: {v['rows']} rows, {v['with_xyz']} with XYZ" for m, v in result["methods"].items()] + notes
    if args.output:
        lines.append(f"wrote {len(table)} rows to {args.output}")
    if args.output or args.json:
        emit(result, args.json, "\n".join(lines))
    else:
        for line in lines:
            log(line)
    return 0


def run_project(args) -> int:
    import numpy as np

    from ..store import Project
    from ..xyz import COV_COLUMNS, compute_xyz, project_sd_holds

    t0 = time.perf_counter()
    if args.frame is None and not args.output:
        raise SandtrackError("give --frame N to print one frame, or -o FILE.csv to write all frames")
    if args.frame is not None and args.frame < 0:
        raise SandtrackError("--frame must be 0 or more")
    with Project.open(args.project) as project:
        frames = None if args.frame is None else [args.frame]
        table = compute_xyz(project, method=args.method, frames=frames, outside=args.outside,
                            covariance=args.covariance)
        holds = project_sd_holds(project, table)
    if args.output:
        out = Path(args.output)
        if not out.parent.exists():
            raise SandtrackError(f"folder does not exist: {out.parent}")
        try:
            # the covariances in mm² to 1e-6 (0.0001 mm² would round a 0.03 mm sd's away), the rest to 1e-4
            cov = {c: np.where(np.isfinite(v := table[c].to_numpy(float)), np.char.mod("%.6f", v), "")
                   for c in COV_COLUMNS if c in table.columns}
            table.assign(**cov).to_csv(out, index=False, float_format="%.4f")
        except OSError as exc:
            raise SandtrackError(f"cannot write {out}: {exc.strerror}") from None
        log(f"wrote {len(table)} rows to {out}")
    result = {"rows": len(table), "frames": int(table["frame"].nunique()),
              "markers": int(table["marker"].nunique()),
              "methods": {m: {"rows": int(len(g)), "with_xyz": int(g["X_mm"].notna().sum())}
                          for m, g in table.groupby("method")},
              "seconds": time.perf_counter() - t0}
    if holds:
        result["sd_holds"] = holds
    if args.output:
        result["output"] = str(args.output)
    if args.frame is not None:
        result["frame"] = args.frame
        result["table"] = table.to_dict(orient="records")
        text = _format(table) if len(table) else f"frame {args.frame}: no points"
    else:
        text = "\n".join(f"{m}: {v['rows']} rows, {v['with_xyz']} with XYZ" for m, v in result["methods"].items())
    emit(result, args.json, text + (f"\n{holds}" if holds else ""))
    return 0


def _format(table) -> str:
    from ..trajectories import table_cameras
    from ..xyz import pixel_columns

    show = table.copy()
    for c in (col for cam in table_cameras(table) for col in pixel_columns(cam)):
        show[c] = show[c].round(2)
    for c in ("X_mm", "Y_mm", "Z_mm"):
        show[c] = show[c].round(2)
    show["residual_px"] = show["residual_px"].round(3)
    show["time_s"] = show["time_s"].round(4)
    return show.to_string(index=False, na_rep="-")
