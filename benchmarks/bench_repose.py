"""Angle of repose and the DEM sweep: accuracy against the rendered truth, speed.

`run() -> dict` renders the repose preset for two seeds into benchmarks/out/repose_seed{0,1} (not
committed; 25-40 deg heaps, jittered by the seed) and measures every file listed in its
ground_truth/repose.json:
- photos (level camera): error of the mean angle and of each flank, plain image and with the camera
  file; the photo from above: plain and calibrated; CPU seconds per 1080p photo;
- DEM dumps and exchange CSVs: error of the mean of the radial slices; the settling dump's settled value;
- the settling video: settled angle and the time it settles from, CPU per frame;
- a 45-run sweep (3 x 5 x 3 levels of restitution, rolling friction and Poisson's ratio; heaps as
  LIGGGHTS dumps and tracer trajectories, tests/sweep_synth.py): from the files with one and with two
  worker processes, and ranked and fitted alone from its table (wall and CPU seconds); the suggested
  parameters against the known optimum, R² of the angle surface.
Every figure is printed; CPU times are given beside wall times (the machine may be shared).
"""

from __future__ import annotations

import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def _cpu_s() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _render(seed: int) -> Path:
    from sandtrack_tui.twin.repose_sample import render_repose

    out = HERE / "out" / f"repose_seed{seed}"
    if not (out / "ground_truth" / "repose.json").is_file():
        render_repose(out, seed, log=lambda m: print(m, file=sys.stderr, flush=True))
    return out


def _measure_all(root: Path) -> dict:
    from sandtrack_tui.camera import Calibration
    from sandtrack_tui.repose import measure_path, result_angle

    rows = []
    for e in json.loads((root / "ground_truth" / "repose.json").read_text()):
        f = root / e["file"]
        cpu0, t0 = time.process_time(), time.perf_counter()
        res = measure_path(f)
        row = {"file": e["file"], "kind": e["kind"], "truth": e["angle_deg"], "cpu_s": time.process_time() - cpu0,
               "wall_s": time.perf_counter() - t0}
        row["angle"] = result_angle(res)[0]
        if e["kind"] == "photo":
            row["flank_err"] = [res.flanks[s].angle_deg - e[f"angle_{s}_deg"] for s in ("left", "right")]
            cal = measure_path(f, calibration=Calibration.load(root / e["camera"]))
            row["cal_angle"] = cal.angle_deg
            row["cal_flank_err"] = [cal.flanks[s].angle_deg - e[f"angle_{s}_deg"] for s in ("left", "right")]
        if e["kind"] in ("video",) or (e["kind"] == "dump" and "settled_from_s" in e):
            if e["kind"] == "dump":
                res = measure_path(f, dt=e["dt_s"])
            row["settled_from_err_s"] = res.settled.from_s - e["settled_from_s"]
            row["frames"] = len(res.time_s)
        rows.append(row)
    return rows


def _sweep() -> dict:
    import pandas as pd

    from sandtrack_tui.compare import read_experiment
    from sandtrack_tui.sweep import read_runs, run_sweep
    from sweep_synth import make_sweep, true_angle

    folder = HERE / "out" / "sweep45"
    if not (folder / "runs.csv").is_file():
        make_sweep(folder)
    runs, params = read_runs(folder / "runs.csv")
    exp = read_experiment(folder / "experiment.csv")
    target = float(true_angle(0.45, 0.22, 0.25))
    out = {"sweep_runs": len(runs)}
    res = None
    for workers in (1, 2):
        cpu0, t0 = _cpu_s(), time.perf_counter()
        res = run_sweep(runs, params, target, exp, dem_kw={"units": "mm"}, cmp_kw={"fps": 50.0}, workers=workers)
        out[f"sweep45_from_files_{workers}w_wall_s"] = round(time.perf_counter() - t0, 2)
        out[f"sweep45_from_files_{workers}w_cpu_s"] = round(_cpu_s() - cpu0, 2)
    table = res.table[["run", *params, "angle_deg", "rmse_3d_mm_all"]]
    walls, cpus = [], []
    for _ in range(5):
        cpu0, t0 = time.process_time(), time.perf_counter()
        fitted = run_sweep(table, params, target)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - cpu0)
    out["sweep45_rank_and_fit_wall_s_median"] = round(float(np.median(walls)), 3)
    out["sweep45_rank_and_fit_cpu_s_median"] = round(float(np.median(cpus)), 3)
    truth = pd.read_csv(folder / "runs.csv")
    truth["true"] = [true_angle(r.restitution, r.rolling_friction, r.poisson) for r in truth.itertuples()]
    merged = res.table.merge(truth[["run", "true"]], on="run")
    out["sweep45_angle_err_max_deg"] = round(float(np.abs(merged["angle_deg"] - merged["true"]).max()), 3)
    out["sweep45_angle_r2"] = round(res.surfaces["angle_deg"].r2, 4)
    out["sweep45_angle_q2"] = round(res.surfaces["angle_deg"].q2, 4)
    out["sweep45_rmse_r2"] = round(res.surfaces["rmse_3d_mm_all"].r2, 4)
    sg = res.suggestion["params"]
    out["sweep45_suggested"] = {k: round(v, 4) for k, v in sg.items()}
    out["sweep45_suggested_true_angle_err_deg"] = round(
        float(true_angle(sg["restitution"], sg["rolling_friction"], sg["poisson"]) - target), 3)
    out["sweep45_best_run"] = res.table.iloc[0]["run"]
    out["sweep45_same_ranking_from_table"] = fitted.table["run"].tolist() == res.table["run"].tolist()
    return out


def run() -> dict:
    cpu0, t0 = _cpu_s(), time.perf_counter()
    roots = [_render(seed) for seed in (0, 1)]
    out: dict = {"render_two_presets_wall_s": round(time.perf_counter() - t0, 1),
                 "render_two_presets_cpu_s": round(_cpu_s() - cpu0, 1)}
    rows = [r for root in roots for r in _measure_all(root)]
    level = [r for r in rows if r["kind"] == "photo" and "high" not in r["file"]]
    high = [r for r in rows if "high" in r["file"]]
    dumps = [r for r in rows if r["kind"] in ("dump", "csv") and "settling" not in r["file"]]
    video = [r for r in rows if r["kind"] == "video"]
    settle_dump = [r for r in rows if "settling.liggghts" in r["file"]]
    out["photos_level"] = len(level)
    out["photo_mean_err_max_deg"] = round(max(abs(r["angle"] - r["truth"]) for r in level), 3)
    out["photo_mean_err_mean_deg"] = round(float(np.mean([r["angle"] - r["truth"] for r in level])), 3)
    out["photo_flank_err_max_deg"] = round(max(max(map(abs, r["flank_err"])) for r in level), 3)
    out["photo_cal_mean_err_max_deg"] = round(max(abs(r["cal_angle"] - r["truth"]) for r in level), 3)
    out["photo_cal_flank_err_max_deg"] = round(max(max(map(abs, r["cal_flank_err"])) for r in level), 3)
    out["photo_cal_flank_err_rms_deg"] = round(float(np.sqrt(np.mean([e ** 2 for r in level
                                                                        for e in r["cal_flank_err"]]))), 3)
    out["photo_from_above_plain_err_deg"] = [round(r["angle"] - r["truth"], 2) for r in high]
    out["photo_from_above_cal_err_deg"] = [round(r["cal_angle"] - r["truth"], 3) for r in high]
    out["photo_1080p_cpu_s_median"] = round(float(np.median([r["cpu_s"] for r in level])), 3)
    out["dumps_and_csv"] = len(dumps)
    sym = [r for r in dumps if "asym" not in r["file"]]
    out["dump_err_max_deg"] = round(max(abs(r["angle"] - r["truth"]) for r in sym), 3)
    out["dump_err_mean_deg"] = round(float(np.mean([r["angle"] - r["truth"] for r in sym])), 3)
    out["dump_asym_err_deg"] = [round(r["angle"] - r["truth"], 3) for r in dumps if "asym" in r["file"]]
    out["dump_cpu_s_median"] = round(float(np.median([r["cpu_s"] for r in dumps])), 3)
    out["video_settled_err_deg"] = [round(r["angle"] - r["truth"], 3) for r in video]
    out["video_settled_from_err_s"] = [round(r["settled_from_err_s"], 2) for r in video]
    out["video_cpu_s_per_frame"] = round(float(np.mean([r["cpu_s"] / r["frames"] for r in video])), 3)
    out["settling_dump_err_deg"] = [round(r["angle"] - r["truth"], 3) for r in settle_dump]
    out |= _sweep()
    out["per_file"] = [{k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()} for r in rows]
    for k, v in out.items():
        if k != "per_file":
            print(f"{k}: {v}", file=sys.stderr)
    return out


if __name__ == "__main__":
    run()
