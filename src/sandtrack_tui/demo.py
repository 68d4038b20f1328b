"""`sandtrack demo`: the study's whole pipeline on the rendered rig, headless, scored against truth.

sync -> calibration (+ world frame, calibration points) -> regression -> auto-seed + tracking ->
XYZ -> export -> comparison with the DEM trajectories. Each stage reports its time and its key
figures measured against the renderer's ground truth. The calibration-points and regression
stages use the full preset's calibration videos (rendered once into a cache folder), so the
training set has the study's size; `fast=True` uses the small preset only and few epochs.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .errors import SandtrackError

REPO_SAMPLE = Path(__file__).resolve().parents[2] / "sample_data"
STAGES = ("sync", "calibration", "regression", "tracking", "xyz", "export", "compare")


def cache_dir() -> Path:
    base = os.environ.get("SANDTRACK_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "sandtrack")
    return Path(base)


def renderer_version() -> str:
    """Hash of the sample renderer's source (twin/sample.py and every module of the package it
    imports): a cached render is redone when code it runs changed."""
    from .source_hash import source_hash

    return source_hash("sandtrack_tui.twin.sample")


def ensure_sample(preset: str, seed: int = 0, log: Callable[[str], None] = print) -> Path:
    """The sample folder for a preset: the bundled one for "small" (seed 0), else rendered once into
    the cache (an interrupted render is redone: a marker file is written last)."""
    if preset == "small" and seed == 0 and (REPO_SAMPLE / "ground_truth" / "cameras.toml").is_file():
        return REPO_SAMPLE
    from .twin.sample import render_sample

    out = cache_dir() / f"sample-{preset}-seed{seed}-{renderer_version()}"
    done = out / ".complete"
    if not done.is_file():
        log(f"rendering the {preset} sample preset into {out} (once)")
        if out.exists():
            shutil.rmtree(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        render_sample(out, seed=seed, preset=preset, log=log)
        done.write_text("ok\n")
    return out


def run_demo(fast: bool = False, workdir: str | Path | None = None, log: Callable[[str], None] = print,
             epochs: int | None = None) -> dict:
    """Run every stage; returns {"stages": {name: {"seconds": ..., figures...}}, "seconds": total}."""
    from .groundtruth import load_truth

    t_all = time.perf_counter()
    stages: dict[str, dict] = {}
    sample = ensure_sample("small", log=log)
    cal_sample = sample if fast else ensure_sample("full", log=log)
    truth = load_truth(sample)
    cal_truth = truth if cal_sample == sample else load_truth(cal_sample)
    own_tmp = workdir is None
    work = Path(tempfile.mkdtemp(prefix="sandtrack-demo-")) if own_tmp else Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    ctx: dict = {"sample": sample, "cal_sample": cal_sample, "truth": truth, "cal_truth": cal_truth,
                 "work": work, "fast": fast, "epochs": epochs, "log": log}
    try:
        for name in STAGES:
            log(f"-- {name}")
            t0 = time.perf_counter()
            figures = globals()[f"_stage_{name}"](ctx)
            stages[name] = {"seconds": round(time.perf_counter() - t0, 2), **figures}
            log(f"   {stages[name]['seconds']:.1f} s")
    finally:
        for src in ctx.get("sources", {}).values():
            src.close()
        if ctx.get("project") is not None:
            ctx["project"].close()
        if own_tmp:
            shutil.rmtree(work, ignore_errors=True)
    return {"stages": stages, "seconds": round(time.perf_counter() - t_all, 1), "fast": fast,
            "sample": str(sample), "calibration_sample": str(cal_sample)}


# -- stages ----------------------------------------------------------------------------------------
def _stage_sync(ctx) -> dict:
    from .sync import estimate_offset

    exp = ctx["sample"] / "experiment"
    res = estimate_offset(exp / "side.mp4", exp / "front.mp4")
    ctx["offset_s"] = res.offset_s
    return {"offset_s": res.offset_s, "offset_frames": res.offset_frames, "confidence": res.confidence,
            "offset_error_ms": 1000.0 * abs(res.offset_s - ctx["truth"].sync_offset_s)}


def _stage_calibration(ctx) -> dict:
    from .board import load_board
    from .calibration.pipeline import calibrate_videos
    from .calibration.world import load_reference
    from .groundtruth import score_calibration

    cs = ctx["cal_sample"]
    board = load_board(cs / "board.toml")
    frame, origin = load_reference(cs / "calibration" / "reference.toml")
    res = calibrate_videos({"side": cs / "calibration" / "side.mp4", "front": cs / "calibration" / "front.mp4"},
                           board, reference_frame=frame, origin_mm=origin, with_points=True)
    ctx["calibration"] = res.calibration
    ctx["points"] = res.points
    points_csv = ctx["work"] / "points.csv"
    res.points.to_csv(points_csv, index=False)
    ctx["points_csv"] = points_csv
    r = res.report
    score = score_calibration(res.calibration, ctx["cal_truth"])
    sync = {cam: info.get("method") for cam, info in (r.get("sync") or {}).items() if isinstance(info, dict)}
    return {"reprojection_rmse_px": r.get("reprojection_rmse_px"), "board_rmse_mm": r.get("board_rmse_mm"),
            "views_used": r.get("views_used"), "points": int(len(res.points)), "sync_methods": sync, **score}


def _stage_regression(ctx) -> dict:
    from .groundtruth import true_points_xyz
    from .regression.dataset import split_by_frame
    from .regression.model import predict
    from .regression.train import TrainConfig
    from .regression.workflow import train_to_file

    points = ctx["points"]
    cfg = TrainConfig.fast() if ctx["fast"] else TrainConfig()
    if ctx["epochs"]:
        cfg = TrainConfig(**{**cfg.__dict__, "epochs": ctx["epochs"]})
    model_path = ctx["work"] / "model.pt"
    model = train_to_file(points, model_path, calibration=ctx["calibration"], config=cfg)
    ctx["model_path"] = model_path
    m = model.metrics
    # Score the held-out frames against the renderer's true corner positions, not the training targets.
    _, _, test = split_by_frame(points["frame"].to_numpy(), cfg.val_frac, cfg.test_frac, cfg.seed)
    rows = points[test]
    truth_xyz = true_points_xyz(rows, ctx["cal_truth"])
    ok = np.isfinite(truth_xyz).all(axis=1)
    x = rows[["xs", "ys", "xf", "yf"]].to_numpy(float)[ok]
    t = truth_xyz[ok]
    out = {"points": int(len(points)), "test_points": int(ok.sum()), "train_seconds": m.get("train_seconds"),
           "epochs_run": m.get("epochs_run")}
    mlp = np.linalg.norm(predict(model, x) - t, axis=1)
    out["mlp_mean_error_mm"] = float(mlp.mean())
    out["mlp_sd_mm"] = float(mlp.std())
    pred = predict(model, x)
    for k, axis in enumerate("xyz"):
        ss_res = float(np.sum((pred[:, k] - t[:, k]) ** 2))
        ss_tot = float(np.sum((t[:, k] - t[:, k].mean()) ** 2))
        out[f"r2_{axis}"] = 1.0 - ss_res / ss_tot if ss_tot > 0 else float("nan")
    from .triangulation import triangulate

    tri, _ = triangulate(ctx["calibration"], {"side": x[:, :2], "front": x[:, 2:]})
    out["triangulation_mean_error_mm"] = float(np.nanmean(np.linalg.norm(tri - t, axis=1)))
    if model.has_residual:
        res = np.linalg.norm(predict(model, x, method="residual") - t, axis=1)
        out["residual_mean_error_mm"] = float(res.mean())
    out.update(_test_split_coverage(rows[ok], t, ctx["calibration"], model))
    return out


def _test_split_coverage(rows, truth_xyz: np.ndarray, calibration, model) -> dict:
    """The 95 % intervals of every method on the held-out calibration points, through `xyz PIXELS.csv`'s
    own path: the share of true errors inside, per axis."""
    from .groundtruth import coverage_by_method
    from .xyz_pixels import camera_columns, xyz_from_pixels

    pixels = rows[["xs", "ys", "xf", "yf"]].reset_index(drop=True)
    table, _ = xyz_from_pixels(pixels, camera_columns(pixels.columns), calibration, model, method="all")
    n_methods = len(table) // len(pixels)
    return coverage_by_method(table, np.repeat(truth_xyz, n_methods, axis=0))


def _stage_tracking(ctx) -> dict:
    from .groundtruth import match_marker_ids, score_tracking
    from .store import Project
    from .tracking.run import accept_seeds, auto_seed, track_project
    from .video import FramePair

    exp = ctx["sample"] / "experiment"
    project = Project.create(ctx["work"] / "demo.sandtrack", {"side": exp / "side.mp4", "front": exp / "front.mp4"},
                             overwrite=True)
    ctx["project"] = project
    project.set("sync_offset_s", ctx["offset_s"])
    project.set_calibration(ctx["calibration"])
    project.set("model", {"path": str(ctx["model_path"])})
    sources = project.open_sources()
    ctx["sources"] = sources
    # seed in the first side frame that the front camera also recorded, then track both ways
    first, _ = FramePair(sources["side"], sources["front"], ctx["offset_s"]).side_range()
    seeds = auto_seed(project, frame=first, sources=sources)
    if seeds.empty:
        raise SandtrackError(f"auto-seeding found no marker in frame {first}")
    accept_seeds(project, seeds)
    summary = track_project(project, sources=sources)
    if first > 0:
        track_project(project, sources=sources, start=first, direction="backward")
    points = project.points()
    id_map = match_marker_ids(points, ctx["truth"])
    ctx["id_map"] = id_map
    score = score_tracking(points, ctx["truth"], id_map)
    return {**score, "markers_seeded": int(seeds.marker.nunique()),
            "ms_per_marker_frame": summary.get("track_ms_per_marker_frame")}


def _stage_xyz(ctx) -> dict:
    from .groundtruth import coverage_by_method, score_xyz, xyz_truth
    from .xyz import compute_xyz

    xyz = compute_xyz(ctx["project"], method="all")
    ctx["xyz"] = xyz
    tri = score_xyz(xyz, ctx["truth"], ctx["id_map"], "triangulation")
    mlp = score_xyz(xyz, ctx["truth"], ctx["id_map"], "mlp")
    out = {"mean_error_mm": tri["mean_error_mm"], "p95_error_mm": tri["p95_error_mm"],
           "points_scored": tri["points_scored"], "mlp_mean_error_mm": mlp["mean_error_mm"],
           "mlp_p95_error_mm": mlp["p95_error_mm"]}
    if "residual" in set(xyz["method"]):
        out["residual_mean_error_mm"] = score_xyz(xyz, ctx["truth"], ctx["id_map"], "residual")["mean_error_mm"]
    # the tracked markers' 95 % intervals, on the frames both cameras measured (tracked or manual)
    measured = xyz[xyz["status_side"].isin(("tracked", "manual")) & xyz["status_front"].isin(("tracked", "manual"))]
    out.update(coverage_by_method(measured, xyz_truth(measured, ctx["truth"], ctx["id_map"])))
    return out


def _stage_export(ctx) -> dict:
    from .trajectories import export

    out = ctx["work"] / "trajectories.csv"
    df = ctx["xyz"].copy()  # every method: the comparison scores each one's uncertainty
    # export the truth's marker numbers, so the comparison pairs particles by id
    df["marker"] = df["marker"].map(ctx["id_map"]).fillna(-1).astype(int)
    df = df[df.marker > 0]
    export(df, out, "csv")
    ctx["export_csv"] = out
    return {"rows": int(len(df)), "bytes": out.stat().st_size}


def _stage_compare(ctx) -> dict:
    """DEM time 0 is the tool's start (side time tool_start_side_time_s) and dem(t) = truth(t - shift),
    so compare's time shift (experiment time - DEM time) should be tool_start - shift."""
    from .compare import compare, read_experiment
    from .dem import read_dem

    exp = read_experiment(ctx["export_csv"], "triangulation")
    dem = read_dem(ctx["sample"] / "dem" / "particles.csv")
    cmp = compare(exp, dem, name="particles")
    diff = ctx["truth"].dem_differences
    expected = float(diff["tool_start_side_time_s"]) - float(diff["time_shift_s"])
    out = {"recovered_shift_s": float(diff["tool_start_side_time_s"]) - cmp.time_shift_s,
           "true_shift_s": float(diff["time_shift_s"]),
           "shift_error_frames": abs(cmp.time_shift_s - expected) * 50.0,
           "particles": int(cmp.summary["particles"]),
           "flagged_particles": sorted(int(p) for p in cmp.summary["flagged_markers"]),
           "drifting_particles": sorted(int(p) for p in diff.get("drifting_particles", []))}
    # The DEM is the truth but for its drifting particles: with honest uncertainties the others are consistent
    # with the experiment and the drifting ones are not.
    for method in ("triangulation", "mlp", "residual"):
        try:
            c = compare(read_experiment(ctx["export_csv"], method), dem, name=method)
        except SandtrackError:
            continue
        if c.summary.get("consistent") is None:
            continue
        per = c.per_particle
        out[f"{method}_inconsistent_particles"] = sorted(int(m) for m in per.loc[per["p_value"] < c.summary["alpha"],
                                                                                  "marker"])
        out[f"{method}_within_95_pct_of_true_particles"] = float(
            per.loc[~per["marker"].isin(out["drifting_particles"]), "within_95_pct"].mean())
    return out


def format_table(result: dict) -> str:
    """One table of stages: time and key figures."""
    lines = [f"{'stage':<12} {'seconds':>8}  figures", "-" * 100]
    for name, figs in result["stages"].items():
        parts = []
        for k, v in figs.items():
            if k == "seconds":
                continue
            if isinstance(v, float):
                v = f"{v:.4g}"
            parts.append(f"{k}={v}")
        lines.append(f"{name:<12} {figs['seconds']:>8.1f}  " + ", ".join(parts))
    lines.append("-" * 100)
    lines.append(f"{'total':<12} {result['seconds']:>8.1f}")
    return "\n".join(lines)
