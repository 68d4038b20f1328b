"""`sandtrack compare EXPERIMENT DEM... [--json] [--plots DIR]`: measured vs simulated trajectories."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import SandtrackError
from .common import add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser("compare", help="compare 3D trajectories with DEM runs (align, metrics, ranking, plots)",
                       description="EXPERIMENT: a project file or an exported trajectory CSV/Parquet "
                                   "(marker, time_s, X_mm, Y_mm, Z_mm). DEM: exchange CSVs "
                                   "(particle_id, time_s, x, y, z) or LIGGGHTS/LAMMPS dump files; several "
                                   "runs are ranked by agreement.")
    p.add_argument("experiment", help="project file or trajectory CSV/Parquet")
    p.add_argument("dem", nargs="+", help="DEM run(s): exchange CSV or dump file (a quoted glob for per-step dumps)")
    p.add_argument("--method", choices=["triangulation", "mlp", "residual"],
                   help="3D method of the experiment to use (default: triangulation when present)")
    p.add_argument("--dem-format", choices=["csv", "dump"], help="default: detected from the content")
    p.add_argument("--dem-units", choices=["m", "cm", "mm"], default=None,
                   help="DEM length unit (default: from column names such as x_mm, else guessed from the extent)")
    p.add_argument("--axes", default="x,y,z", help="DEM axes -> rig X,Y,Z, e.g. x,-z,y (default x,y,z)")
    p.add_argument("--offset-mm", default="0,0,0", help="DEM origin in rig coordinates, mm: X,Y,Z")
    p.add_argument("--dem-time-offset", type=float, default=0.0, help="added to DEM times (s)")
    p.add_argument("--dt", type=float, help="DEM time step (s), for dumps without ITEM: TIME")
    p.add_argument("--match", choices=["auto", "id", "nearest"], default="auto",
                   help="pair markers with particles by id or by nearest start (default: id if possible)")
    p.add_argument("--max-lag", type=float, default=0.5, help="time-shift search half-width around the onset (s)")
    p.add_argument("--time-shift", type=float, help="use this time shift (s) instead of aligning")
    p.add_argument("--exp-tool", help="tool track of the experiment (time_s, X_mm, Y_mm, Z_mm) for the onset")
    p.add_argument("--dem-tool", help="tool track of the DEM run(s) for the onset")
    p.add_argument("--exp-onset", type=float, metavar="S", help="experiment time (s) the tool starts moving")
    p.add_argument("--dem-onset", type=float, metavar="S", help="DEM time (s) the tool starts moving (often 0)")
    p.add_argument("--onset-mm", type=float, default=3.0, help="motion onset threshold (mm, default 3)")
    p.add_argument("--flag-mm", type=float, default=2.0, help="never flag particles with RMSE below this (mm)")
    p.add_argument("--fps", type=float, help="experiment frame rate (default: from the data)")
    u = p.add_argument_group("consistency in units of the measurement's error")
    u.add_argument("--dem-sd-mm", type=float, default=0.0, metavar="MM",
                   help="the DEM's own uncertainty per axis, added to the experiment's (default 0)")
    u.add_argument("--exp-sd-mm", type=float, metavar="MM",
                   help="the experiment's sd per axis when its table has no sd_X_mm, sd_Y_mm, sd_Z_mm columns "
                        "(an older export); without it such a table gets no χ²")
    u.add_argument("--alpha", type=float, default=0.05,
                   help="a run is consistent with the experiment when its χ² p-value is at least this (default 0.05)")
    u.add_argument("--rank-by", choices=["auto", "chi2", "rmse"], default="auto",
                   help="rank runs by χ² per degree of freedom or by RMSE (default: χ² when every run has one)")
    p.add_argument("--plots", metavar="DIR", help="write PNG plots here")
    add_json_flag(p)
    p.set_defaults(func=run)


def _triple(text: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(np.isfinite(v)):
        raise SandtrackError(f"--offset-mm {text!r}: give three numbers X,Y,Z")
    return v  # type: ignore[return-value]


def run(args) -> int:
    from ..compare import compare, error_text_plot, has_sd, plot_comparison, rank, read_experiment, read_tool
    from ..dem import read_dem

    exp = read_experiment(args.experiment, args.method)
    if not has_sd(exp):
        log(f"compare: {args.experiment} has no sd columns (sd_X_mm, sd_Y_mm, sd_Z_mm): " + (
            f"the experiment's sd is taken as {args.exp_sd_mm:g} mm per axis" if args.exp_sd_mm is not None
            else "no χ² (give --exp-sd-mm to assume an sd per axis); runs ranked by RMSE"))
        if args.rank_by == "chi2" and args.exp_sd_mm is None:
            raise SandtrackError("cannot rank by χ²: the experiment carries no sd columns; give --exp-sd-mm")
    fps = args.fps
    if fps is None:
        dts = exp.groupby("marker")["time_s"].diff().dropna()
        dts = dts[dts > 0]
        fps = float(1.0 / dts.median()) if len(dts) else 50.0
    exp_tool = read_tool(args.exp_tool) if args.exp_tool else None
    dem_tool = read_tool(args.dem_tool) if args.dem_tool else None
    offset = _triple(args.offset_mm)
    runs = []
    for path in args.dem:
        log(f"compare: reading {path}")
        kw = {"units": args.dem_units, "axes": args.axes, "offset_mm": offset, "time_offset_s": args.dem_time_offset}
        if args.dem_format != "csv":
            kw["dt"] = args.dt
        dem = read_dem(path, args.dem_format, **kw)
        if dem.attrs.get("units_guessed"):
            log(f"warning: {path}: no length unit given, positions taken as {dem.attrs['units_guessed']} "
                "(from their extent); pass --dem-units to be explicit")
        cmp = compare(exp, dem, name=Path(path).stem if "*" not in path else path, match=args.match, fps=fps,
                      max_lag_s=args.max_lag, onset_mm=args.onset_mm, exp_tool=exp_tool, dem_tool=dem_tool,
                      time_shift_s=args.time_shift, flag_mm=args.flag_mm, exp_onset_s=args.exp_onset,
                      dem_onset_s=args.dem_onset, dem_sd_mm=args.dem_sd_mm, exp_sd_mm=args.exp_sd_mm, alpha=args.alpha)
        cmp.summary["dem_units"] = dem.attrs.get("units")
        runs.append(cmp)
    ranking = rank(runs, {"auto": "auto", "chi2": "chi2_reduced", "rmse": "rmse_3d_mm_all"}[args.rank_by])
    plots = []
    if args.plots:
        for cmp in runs:
            plots += [str(p) for p in plot_comparison(cmp, args.plots)]
    result = {"experiment": str(args.experiment), "fps": fps, "runs": [c.to_dict() for c in runs],
              "ranking": ranking.to_dict("records"), "ranked_by": ranking.attrs["ranked_by"], "plots": plots}
    emit(result, args.json, text=_text(runs, ranking, fps, error_text_plot))
    return 0


def _text(runs, ranking, fps, error_text_plot) -> str:
    lines = []
    cols = ["marker", "particle_id", "rmse_3d_mm", "rmse_x_mm", "rmse_y_mm", "rmse_z_mm", "final_error_mm",
            "frechet_mm", "dtw_norm_mm", "max_dev_mm", "drift_mm_per_s", "chi2_reduced", "samples_eff", "p_value",
            "within_95_pct", "flagged"]
    for c in runs:
        s = c.summary
        lines.append(f"== {c.name}: time shift {c.time_shift_s * 1000:+.1f} ms ({c.time_shift_s * fps:+.2f} frames; "
                     f"onset from {c.onset.get('source')}), {s['particles']} particles")
        lines.append(f"   RMSE 3D all {s['rmse_3d_mm_all']:.2f} mm, median {s['rmse_3d_mm_median']:.2f} mm; "
                     f"Fréchet median {s['frechet_mm_median']:.2f} mm; DTW median {s['dtw_norm_mm_median']:.2f} mm; "
                     f"flagged: {', '.join(map(str, s['flagged_markers'])) or 'none'}")
        if s.get("uncertainty"):
            lines.append(f"   uncertainty: {s['uncertainty']}"
                         + (f"; {s['samples_without_sd']} samples without one left out of χ²"
                            if s.get("samples_without_sd") else "") + (f" ({s['note']})" if s.get("note") else ""))
        per = c.per_particle
        lines.append(per[[k for k in cols if k in per.columns]].to_string(
            index=False, float_format=lambda v: f"{v:.3g}" if abs(v) < 0.01 else f"{v:.2f}"))
        lines.append(error_text_plot(c))
        lines.append(f"{c.name}: {s['verdict']}")
    if len(runs) > 1:
        by = "χ² per degree of freedom" if ranking.attrs["ranked_by"] == "chi2_reduced" else "RMSE"
        lines.append(f"== ranking (best first, by {by}; rank_rmse: by RMSE)")
        lines.append(ranking.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    return "\n".join(lines)
