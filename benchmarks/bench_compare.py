"""Comparison with DEM: time-shift recovery, drift flags, speed; sample_data if present.

- synthetic: 10 markers pushed by a tool, experiment at 50 fps with 0.3 mm noise, DEM at 100 Hz on
  its own clock (known shift) with some particles drifting; shift error (frames) and flag
  precision/recall over several cases; time per comparison; 100 particles for scale.
- distances: discrete Fréchet + normalised DTW on 400 x 400 samples.
- consistency: the same synthetic cases with the experiment's sd columns (its true noise, 0.3 mm): χ²/dof,
  the share of runs called consistent when the DEM is exact (the test's size: should be ~95 %), and
  of runs called inconsistent when the DEM is 1.5 mm off along one axis (its power: should be 100 %); the
  CPU time of a comparison with and without sd columns.
- sample_data: ground_truth/trajectories.csv vs dem/particles.csv, against dem/differences.json.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "tests"))

from compare_synth import make_case  # noqa: E402
from sandtrack_tui import compare as C  # noqa: E402
from sandtrack_tui import dem as D  # noqa: E402

FPS = 50.0


def _synthetic() -> dict:
    cases = [(0.137, {3: 6.0, 7: 4.0}, 0), (-0.31, {5: 3.0}, 3), (0.0, {}, 5), (0.4444, {1: 2.0, 2: 2.0}, 7),
             (0.2, {9: 1.5}, 9)]
    errs, times, tp, fp, fn = [], [], 0, 0, 0
    for shift, drift, seed in cases:
        exp, dem = make_case(shift_s=shift, drift=drift, seed=seed)
        t0 = time.perf_counter()
        c = C.compare(exp, dem, fps=FPS)
        times.append(time.perf_counter() - t0)
        errs.append(abs(c.time_shift_s - shift) * FPS)
        flagged = set(c.summary["flagged_markers"])
        tp += len(flagged & set(drift))
        fp += len(flagged - set(drift))
        fn += len(set(drift) - flagged)
    exp, dem = make_case(shift_s=0.1, drift={5: 3.0}, n=100, seed=1)
    t0 = time.perf_counter()
    C.compare(exp, dem, fps=FPS)
    t100 = time.perf_counter() - t0
    return {"synthetic_cases": len(cases), "shift_error_frames_max": round(max(errs), 4),
            "shift_error_frames_mean": round(float(np.mean(errs)), 4), "drift_flags_true": tp,
            "drift_flags_false": fp, "drift_flags_missed": fn,
            "seconds_per_compare_10_particles": round(np.mean(times), 2),
            "seconds_compare_100_particles": round(t100, 2)}


def _distances() -> dict:
    rng = np.random.default_rng(0)
    a = np.cumsum(rng.normal(size=(400, 3)), axis=0)
    b = a + rng.normal(scale=0.5, size=a.shape)
    t0 = time.perf_counter()
    C.discrete_frechet(a, b)
    C.dtw_normalised(a, b)
    return {"frechet_plus_dtw_400x400_seconds": round(time.perf_counter() - t0, 3)}


def _sample_data() -> dict:
    """sample_data/dem/differences.json: dem(t) = truth(t - time_shift_s) + drift * t, DEM t = 0 at the
    tool start (side time tool_start_side_time_s). So the experiment time of DEM time t is
    tool_start + t - time_shift_s: compare's time_shift_s (experiment - DEM) should be
    tool_start - time_shift_s."""
    gt = ROOT / "sample_data" / "ground_truth" / "trajectories.csv"
    dem_csv = ROOT / "sample_data" / "dem" / "particles.csv"
    diff = ROOT / "sample_data" / "dem" / "differences.json"
    if not (gt.is_file() and dem_csv.is_file() and diff.is_file()):
        return {"sample_data": "absent"}
    doc = json.loads(diff.read_text())
    exp = C.read_experiment(gt)
    unit = str(doc.get("units", "")).split(",")[0].strip()
    dem = D.read_exchange_csv(dem_csv, units=unit if unit in D.UNIT_TO_MM else None)
    t0 = time.perf_counter()
    c = C.compare(exp, dem, fps=FPS)
    out = {"sample_seconds": round(time.perf_counter() - t0, 2), "sample_time_shift_s": round(c.time_shift_s, 5),
           "sample_flagged": c.summary["flagged_markers"],
           "sample_rmse_3d_mm_median": round(c.summary["rmse_3d_mm_median"], 3),
           "sample_unit_guess": D.guess_units(dem[["X_mm", "Y_mm", "Z_mm"]].to_numpy())}
    if "time_shift_s" in doc and "tool_start_side_time_s" in doc:
        expected = float(doc["tool_start_side_time_s"]) - float(doc["time_shift_s"])
        out["sample_expected_time_shift_s"] = expected
        out["sample_shift_error_frames"] = round(abs(c.time_shift_s - expected) * FPS, 4)
    if "drifting_particles" in doc:
        ids = sorted(int(d) for d in doc["drifting_particles"])
        out["sample_true_drifting"] = ids
        out["sample_flags_match"] = sorted(c.summary["flagged_markers"]) == ids
    return out




def _consistency(seeds: int = 20) -> dict:
    sd_cols = {c: 0.3 for c in C.SD_COLUMNS}
    reduced, consistent, caught, cpu_sd, cpu_bare = [], 0, 0, [], []
    for seed in range(seeds):
        exp, dem = make_case(shift_s=0.137, seed=seed)
        t0 = time.process_time()
        c = C.compare(exp.assign(**sd_cols), dem, fps=FPS)
        cpu_sd.append(time.process_time() - t0)
        reduced.append(c.summary["chi2_reduced"])
        consistent += bool(c.summary["consistent"])
        off = C.compare(exp.assign(**sd_cols), dem.assign(Y_mm=dem["Y_mm"] + 1.5), fps=FPS)
        caught += off.summary["consistent"] is False
        t0 = time.process_time()
        C.compare(exp, dem, fps=FPS)
        cpu_bare.append(time.process_time() - t0)
    return {"consistency_runs": seeds, "chi2_reduced_mean": round(float(np.mean(reduced)), 3),
            "chi2_reduced_max": round(float(np.max(reduced)), 3),
            "exact_dem_called_consistent_pct": round(100 * consistent / seeds, 1),
            "offset_1_5mm_called_inconsistent_pct": round(100 * caught / seeds, 1),
            "cpu_seconds_per_compare_with_sd": round(float(np.median(cpu_sd)), 3),
            "cpu_seconds_per_compare_without_sd": round(float(np.median(cpu_bare)), 3)}


def run() -> dict:
    out = _synthetic()
    out.update(_consistency())
    out.update(_distances())
    out.update(_sample_data())
    return out


if __name__ == "__main__":
    for k, v in run().items():
        print(f"{k}: {v}")
