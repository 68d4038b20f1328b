"""Lens models on a real stepped target (../shared/data/myptv_target: three real cameras, surveyed dots
on the depth planes Z = -12, -6, 0 mm), the protocol of its README: fit `calibrate --from-points` on
two planes, triangulate the held-out plane, mean / p95 of the 3D error (mm).

For every held-out plane and for cameras 1+2 and 1+2+3: the automatic choice (`--lens auto`, what it
chose per camera, CPU seconds of the fit), and every lens model forced on all cameras, so the choice
can be judged against what each model would have given on the held-out plane (which the choice never
sees). Skipped when the data is absent.

Run: `python benchmarks/bench_lens.py` (prints JSON), or `run()` from benchmarks/run_all.py.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sandtrack_tui.calibration.from_points import calibrate_from_points  # noqa: E402
from sandtrack_tui.lens import AUTO_LENSES  # noqa: E402
from sandtrack_tui.triangulation import triangulate  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "myptv_target"
README_FIGURES = {"-12": 0.092, "-6": 0.072, "0": 0.289}  # cameras 1+2, the five-term model, before the choice


def table() -> pd.DataFrame:
    parts = [pd.read_csv(DATA / f"cam{i}_cal_points.txt", sep=r"\s+", header=None,
                         names=[f"x_cam{i}", f"y_cam{i}", "X_mm", "Y_mm", "Z_mm"]) for i in (1, 2, 3)]
    df = parts[0]
    for p in parts[1:]:
        df = df.merge(p, on=["X_mm", "Y_mm", "Z_mm"], how="outer")
    return df


def held_out(df: pd.DataFrame, plane: float, cams: tuple[str, ...], lens: str) -> dict:
    fit, test = df[df.Z_mm != plane], df[df.Z_mm == plane]
    c = time.process_time()
    cal = calibrate_from_points(fit, {n: (f"x_{n}", f"y_{n}") for n in cams}, lens=lens)
    cpu = time.process_time() - c
    xyz, _ = triangulate(cal, {n: test[[f"x_{n}", f"y_{n}"]].to_numpy(float) for n in cams}, refine=True)
    err = np.linalg.norm(xyz - test[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), axis=1)
    err = err[np.isfinite(err)]
    out = {"mean_mm": round(float(err.mean()), 4), "p95_mm": round(float(np.percentile(err, 95)), 4),
           "points": int(len(err)), "fit_points": int(len(fit)), "fit_cpu_s": round(cpu, 2)}
    if lens == "auto":
        out["chosen"] = {n: r["lens"] for n, r in cal.report["per_camera"].items()}
    return out


def run() -> dict:
    if not (DATA / "cam3_cal_points.txt").exists():
        return {"skipped": f"{DATA} absent"}
    df = table()
    out: dict = {"readme_figures_cameras_1_2_before": README_FIGURES}
    for plane in (-12.0, -6.0, 0.0):
        for cams in (("cam1", "cam2"), ("cam1", "cam2", "cam3")):
            key = f"Z{plane:g}_held_out_{'+'.join(c[-1] for c in cams)}"
            out[key + "_auto"] = held_out(df, plane, cams, "auto")
            out[key + "_forced_mean_mm"] = {lens: held_out(df, plane, cams, lens)["mean_mm"] for lens in AUTO_LENSES}
    return out


if __name__ == "__main__":
    print(json.dumps(run(), indent=2, default=float))
