"""`sandtrack train`: fit the pixel -> XYZ MLP to calibration points and measure it."""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import SandtrackError
from .common import Progress, add_json_flag, emit, log


def register(sub) -> None:
    p = sub.add_parser("train", help="train the pixel -> XYZ regression model (MLP) on calibration points",
                       description="Train the study's MLP (4-512-1024-256-3) on points.csv (frame, corner_id, xs, "
                                   "ys, xf, yf, X_mm, Y_mm, Z_mm), split by frame into train/validation/test, and "
                                   "report its test errors beside direct triangulation and the residual variant.")
    p.add_argument("points", help="points.csv from `sandtrack calibrate --points`")
    p.add_argument("-o", "--output", required=True, help="model file to write (.pt)")
    p.add_argument("--project", help="store the model path and its metrics in this project "
                                     "(its calibration is used for the comparison unless --calibration is given)")
    p.add_argument("--calibration", help="calibration.toml for the triangulation comparison and the residual variant")
    p.add_argument("--epochs", type=int, help="maximum epochs (default 30, --fast 6; early stopping may end sooner)")
    p.add_argument("--batch-size", type=int, help="batch size (default 512, --fast 256)")
    p.add_argument("--seed", type=int, default=0, help="random seed (split, weights, batches); default 0")
    p.add_argument("--fast", action="store_true", help="a quick, rougher model (few epochs): for tests and previews")
    p.add_argument("--no-residual", action="store_true", help="skip the residual variant")
    p.add_argument("--threads", type=int, help="CPU threads (default: all cores, or 1 when they are busy); the "
                                               "same seed and thread count give the same weights")
    add_json_flag(p)
    p.set_defaults(func=run)


def run(args) -> int:
    from ..regression import TrainConfig, load_points
    from ..regression.workflow import PROJECT_KEYS, train_to_file

    t0 = time.perf_counter()
    points = load_points(args.points)
    out = Path(args.output)
    if not out.parent.exists():
        raise SandtrackError(f"folder does not exist: {out.parent}")
    kw = {"seed": args.seed, "residual": not args.no_residual}
    if args.threads is not None:
        if args.threads < 1:
            raise SandtrackError("--threads must be at least 1")
        kw["threads"] = args.threads
    if args.epochs is not None:
        if args.epochs < 1:
            raise SandtrackError("--epochs must be at least 1")
        kw["epochs"] = args.epochs
    if args.batch_size is not None:
        if args.batch_size < 1:
            raise SandtrackError("--batch-size must be at least 1")
        kw["batch_size"] = args.batch_size
    cfg = TrainConfig.fast(**kw) if args.fast else TrainConfig(**kw)
    project = None
    if args.project:
        from ..store import Project

        project = Project.open(args.project)
    try:
        calibration = _calibration(args, project)
        log(f"training on {len(points)} points ({points['frame'].nunique()} frames)"
            + ("" if calibration else "; no calibration: no triangulation comparison"))
        bar = Progress(cfg.total_epochs(calibration is not None), "train")
        model = train_to_file(points, out, calibration=calibration, project=project, config=cfg,
                              progress=lambda e, loss, val: bar.update(e, f"val {val:.2f} mm"))
        bar.close()
    finally:
        if project is not None:
            project.close()
    m = model.metrics
    result = {k: m.get(k) for k in PROJECT_KEYS if k in m or k in ("triangulation_mean_error_mm",
                                                                   "residual_mean_error_mm")}
    result.update({"model": str(out), "seconds": time.perf_counter() - t0})
    emit(result, args.json, _text(m, out))
    return 0


def _calibration(args, project):
    from ..camera import Calibration

    if args.calibration:
        return Calibration.load(args.calibration)
    if project is not None:
        return project.calibration()
    return None


def _text(m: dict, out: Path) -> str:
    lines = [f"model: {out}",
             f"points: {m['points']} ({m['train_points']} train / {m['val_points']} validation / "
             f"{m['test_points']} test, split by frame)",
             f"training: {m['epochs_run']} epochs (best {m['best_epoch']}, {m['stopped']}), "
             f"{m['train_seconds']:.1f} s on {m['device']} x{m['threads']}",
             "test errors (mm):      mean     SD  median    p95"]
    for name in ("mlp", "triangulation", "residual"):
        if f"{name}_mean_error_mm" in m:
            lines.append(f"  {name:<17} {m[f'{name}_mean_error_mm']:8.3f} {m[f'{name}_sd_mm']:6.3f} "
                         f"{m[f'{name}_median_mm']:7.3f} {m[f'{name}_p95_mm']:6.3f}")
    lines.append(f"  (predicting the mean: {m['baseline_mean_error_mm']:.1f} mm)")
    for name in ("mlp", "residual"):
        if f"{name}_coverage95_pct_x" in m:
            cov = "  ".join(f"{a.upper()} {m[f'{name}_coverage95_pct_{a}']:.1f} %" for a in "xyz")
            sd = " / ".join(f"{m[f'{name}_sd_median_mm_{a}']:.3f}" for a in "xyz")
            lines.append(f"{name} spread: test errors within ±1.96 sd: {cov} (median sd X/Y/Z {sd} mm)")
    lines.append(f"MLP R²: X {m['r2_x']:.5f}  Y {m['r2_y']:.5f}  Z {m['r2_z']:.5f}")
    if m.get("test_outside_bounds"):
        lines.append(f"warning: {m['test_outside_bounds']} test points lie outside the training pixel range")
    return "\n".join(lines)
