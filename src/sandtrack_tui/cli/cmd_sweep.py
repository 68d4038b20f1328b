"""`sandtrack sweep RUNS.csv`: a DEM parameter sweep against the experiment: ranking and response surface."""

from __future__ import annotations

from pathlib import Path

from .common import Progress, add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser(
        "sweep", help="rank a DEM parameter sweep against the experiment and fit a response surface",
        description="RUNS.csv: one row per DEM run: parameter columns, and angle_deg and/or repose (a dump, "
                    "exchange CSV, photo or saved JSON of the run's heap) and/or trajectories (its tracer "
                    "trajectories); paths relative to the CSV. Every run's angle error and trajectory metrics "
                    "against the experiment, the runs ranked, a quadratic response surface per response (R², "
                    "leave-one-out Q²) and the parameter set it suggests.")
    p.add_argument("runs", help="RUNS.csv")
    g = p.add_argument_group("the experiment")
    g.add_argument("--target-angle", type=float, metavar="DEG", help="the measured angle of repose (deg)")
    g.add_argument("--experiment-repose", metavar="PATH",
                   help="measure the experiment's angle from this photo, video, folder or saved JSON")
    g.add_argument("--experiment", metavar="TRAJ", help="the experiment's trajectories (project or exported CSV)")
    g.add_argument("--method", choices=["triangulation", "mlp", "residual"], help="3D method of the experiment")
    s = p.add_argument_group("ranking and fit")
    s.add_argument("--params", help="parameter columns, comma-separated (default: every numeric column)")
    s.add_argument("--metric", default="rmse_3d_mm_all",
                   choices=["rmse_3d_mm_all", "frechet_mm_median", "dtw_norm_mm_median", "final_error_mm_median",
                            "chi2_reduced"],
                   help="trajectory metric ranked (default rmse_3d_mm_all; chi2_reduced: the differences in units "
                        "of the combined uncertainty, see compare)")
    s.add_argument("--dem-sd-mm", type=float, default=0.0, metavar="MM",
                   help="the DEM's own uncertainty per axis, added to the experiment's (default 0)")
    s.add_argument("--exp-sd-mm", type=float, metavar="MM",
                   help="the experiment's sd per axis when its table has no sd columns (an older export)")
    s.add_argument("--weights", default="angle=1,trajectory=1", metavar="angle=W,trajectory=W",
                   help="weights of the criteria in the score (default 1 and 1)")
    d = p.add_argument_group("reading the runs' files")
    d.add_argument("--dem-units", choices=["m", "cm", "mm"], help="length unit of the DEM files")
    d.add_argument("--axes", default="x,y,z", help="DEM axes -> rig X,Y,Z for trajectories (default x,y,z)")
    d.add_argument("--offset-mm", default="0,0,0", help="DEM origin in rig coordinates for trajectories, mm")
    d.add_argument("--dt", type=float, help="DEM time step (s) for dumps without ITEM: TIME")
    d.add_argument("--up", help="the DEM's up axis for heaps (default: detected)")
    d.add_argument("--workers", type=int, default=1,
                   help="processes measuring the runs (default 1; more pay off for large dumps)")
    p.add_argument("--out", metavar="CSV", help="write the ranked table")
    p.add_argument("--plot", metavar="PNG", help="write the ranking, fit and effects as a figure")
    add_json_flag(p)
    p.set_defaults(func=run)


def _weights(text: str) -> dict:
    from ..errors import SandtrackError

    out = {}
    for part in text.split(","):
        key, _, val = part.partition("=")
        key = key.strip()
        try:
            w = float(val)
        except ValueError:
            w = -1.0
        if key not in ("angle", "trajectory") or not w >= 0:
            raise SandtrackError(f"--weights {text!r}: give angle=W,trajectory=W with W >= 0")
        out[key] = w
    return out


def run(args) -> int:
    from ..compare import read_experiment
    from ..errors import SandtrackError
    from ..repose import measure_path, result_angle
    from ..sweep import plot_sweep, read_runs, run_sweep, sweep_text
    from .cmd_compare import _triple

    if args.workers < 1:
        raise SandtrackError("--workers must be at least 1")
    params = [c.strip() for c in args.params.split(",")] if args.params else None
    runs, params = read_runs(args.runs, params)
    target = args.target_angle
    if args.experiment_repose:
        if target is not None:
            raise SandtrackError("give --target-angle or --experiment-repose, not both")
        target, sigma = result_angle(measure_path(args.experiment_repose))
        log(f"sweep: experiment angle of repose {target:.2f} deg (± {sigma:.2f}) from {args.experiment_repose}")
    exp = read_experiment(args.experiment, args.method) if args.experiment else None
    cmp_kw = {}
    if exp is not None:
        dts = exp.groupby("marker")["time_s"].diff().dropna()
        dts = dts[dts > 0]
        cmp_kw["fps"] = float(1.0 / dts.median()) if len(dts) else 50.0
        cmp_kw |= {"dem_sd_mm": args.dem_sd_mm, "exp_sd_mm": args.exp_sd_mm}
    dem_kw = {"units": args.dem_units, "axes": args.axes, "offset_mm": _triple(args.offset_mm)}
    if args.dt:
        dem_kw["dt"] = args.dt
    bar = Progress(len(runs), "sweep")
    res = run_sweep(runs, params, target, exp, args.metric, _weights(args.weights),
                    repose_kw={"up": args.up, "units": args.dem_units, "dt": args.dt}, dem_kw=dem_kw,
                    cmp_kw=cmp_kw, workers=args.workers,
                    progress=lambda done, total: bar.update(done))
    bar.close()
    out = res.to_dict()
    if args.out:
        res.table.to_csv(args.out, index=False, float_format="%.6g")
        out["table"] = str(Path(args.out))
    if args.plot:
        out["plot"] = str(plot_sweep(res, args.plot))
    emit(out, args.json, text=sweep_text(res))
    return 0
