"""`sandtrack xyz`: world XYZ of the tracked markers (triangulation and/or the MLP)."""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import SandtrackError
from .common import add_json_flag, emit, log


def register(sub) -> None:
    from ..xyz import METHOD_CHOICES, OUTSIDE_POLICIES

    p = sub.add_parser("xyz", help="world XYZ (mm) of the tracked markers",
                       description="Print the XYZ table of one side frame (--frame N) or write every frame to "
                                   "a CSV (-o FILE). Front pixels are interpolated to the side frame's time.")
    p.add_argument("project", help="project file (.sandtrack)")
    p.add_argument("--frame", type=int, help="side frame index to print")
    p.add_argument("--method", choices=METHOD_CHOICES, default="both",
                   help="triangulation, mlp, residual, both (triangulation + mlp; default) or all")
    p.add_argument("--outside", choices=OUTSIDE_POLICIES, default="flag",
                   help="MLP rows outside the training volume: flag as method mlp_outside (default), "
                        "nan (no XYZ) or keep")
    p.add_argument("-o", "--output", help="write all frames to this CSV")
    add_json_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..store import Project
    from ..xyz import compute_xyz

    t0 = time.perf_counter()
    if args.frame is None and not args.output:
        raise SandtrackError("give --frame N to print one frame, or -o FILE.csv to write all frames")
    if args.frame is not None and args.frame < 0:
        raise SandtrackError("--frame must be 0 or more")
    with Project.open(args.project) as project:
        frames = None if args.frame is None else [args.frame]
        table = compute_xyz(project, method=args.method, frames=frames, outside=args.outside)
    if args.output:
        out = Path(args.output)
        if not out.parent.exists():
            raise SandtrackError(f"folder does not exist: {out.parent}")
        try:
            table.to_csv(out, index=False, float_format="%.4f")
        except OSError as exc:
            raise SandtrackError(f"cannot write {out}: {exc.strerror}") from None
        log(f"wrote {len(table)} rows to {out}")
    result = {"rows": len(table), "frames": int(table["frame"].nunique()),
              "markers": int(table["marker"].nunique()),
              "methods": {m: {"rows": int(len(g)), "with_xyz": int(g["X_mm"].notna().sum())}
                          for m, g in table.groupby("method")},
              "seconds": time.perf_counter() - t0}
    if args.output:
        result["output"] = str(args.output)
    if args.frame is not None:
        result["frame"] = args.frame
        result["table"] = table.to_dict(orient="records")
        text = _format(table) if len(table) else f"frame {args.frame}: no points"
    else:
        text = "\n".join(f"{m}: {v['rows']} rows, {v['with_xyz']} with XYZ" for m, v in result["methods"].items())
    emit(result, args.json, text)
    return 0


def _format(table) -> str:
    show = table.copy()
    for c in ("xs", "ys", "xf", "yf"):
        show[c] = show[c].round(2)
    for c in ("X_mm", "Y_mm", "Z_mm"):
        show[c] = show[c].round(2)
    show["residual_px"] = show["residual_px"].round(3)
    show["time_s"] = show["time_s"].round(4)
    return show.to_string(index=False, na_rep="-")
