"""Lens models on a real stepped target (../shared/data/myptv_target: three real cameras, surveyed dots
on the depth planes Z = -12, -6, 0 mm), the protocol of its README: fit `calibrate --from-points` on
two planes, triangulate the held-out plane, mean / p95 of the 3D error (mm).

For every held-out plane and for cameras 1+2 and 1+2+3: the automatic choice (`--lens auto`, what it
chose per camera, CPU seconds of the fit), and every lens model forced on all cameras, so the choice
can be judged against what each model would have given on the held-out plane (which the choice never
sees): `auto_over_best` is the automatic choice's mean error over the best forced model's. Skipped when
the data is absent. The target has three planes only, so the protocol of fitting the three middle planes
of a five-plane target and predicting the two outer ones runs on `five_plane_twin`: two cameras
(f = 2000 px, 0.3 px noise) before the five-plane target of tests/test_lens_select.py, with a thin-prism
lens (the richer terms needed) and with the same lens without its prism terms, over seeds 0-4.

`noise_floor`: what the protocol gives when the only error is the dots' own detection error. The
cameras fitted on all three planes stand for the truth; each dot's residuals (all cameras together, so
that an error common to the cameras, such as a dot printed off its place, stays common) are handed to
another dot of the same plane seen by the same cameras, drawn with replacement, on top of the exact
projections; the protocol is then run on each such copy of the target: held-out error of the refitted
cameras, error of the true cameras on the same pixels (the held-out dots' own error, which no
calibration removes), and how often cameras 1+2 reach the target and three cameras beat two.
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
sys.path.insert(0, str(ROOT / "tests"))

from sandtrack_tui.calibration.from_points import calibrate_from_points  # noqa: E402
from sandtrack_tui.lens import AUTO_LENSES  # noqa: E402
from sandtrack_tui.triangulation import triangulate  # noqa: E402
from test_lens_select import PRISM_LENS, five_plane_target, outer_planes_error  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "myptv_target"
README_FIGURES = {"-12": 0.092, "-6": 0.072, "0": 0.289}  # cameras 1+2, the five-term model, before the choice
TARGETS = {-12.0: 0.08, 0.0: 0.15}  # mean mm, cameras 1+2, plane held out


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


def noise_floor(df: pd.DataFrame, lens: str = "tangential", copies: int = 100, seed: int = 0) -> dict:
    """The protocol on copies of the target whose only error is resampled detection noise (see above).
    `lens`: the model fitted (the automatic choice on every held-out plane of this target)."""
    cams = ("cam1", "cam2", "cam3")
    cols = {n: (f"x_{n}", f"y_{n}") for n in cams}
    truth = calibrate_from_points(df, cols, lens=lens)
    X = df[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
    exact = {n: truth.cameras[n].project(truth.to_rig(X)) for n in cams}
    rng = np.random.default_rng(seed)
    planes = (-12.0, -6.0, 0.0)
    runs: dict = {p: [] for p in planes}
    seen = np.stack([df[list(cols[n])].notna().all(axis=1).to_numpy() for n in cams], axis=1)
    resid = {n: df[list(cols[n])].to_numpy(float) - exact[n] for n in cams}
    pattern = seen @ (1 << np.arange(len(cams))) + 8 * np.searchsorted(planes, X[:, 2])
    for _ in range(copies):
        source = np.arange(len(df))
        for g in np.unique(pattern):
            rows = np.flatnonzero(pattern == g)
            source[rows] = rows[rng.integers(0, len(rows), len(rows))]
        copy = df[["X_mm", "Y_mm", "Z_mm"]].copy()
        for n in cams:
            px = exact[n] + resid[n][source]
            copy[cols[n][0]], copy[cols[n][1]] = px[:, 0], px[:, 1]
        for p in planes:
            fit, test = copy[copy.Z_mm != p], copy[copy.Z_mm == p]
            cal = calibrate_from_points(fit, cols, lens=lens, jackknife=False)  # no sd used here
            runs[p].append([_mean_error(c, test, use) for c in (cal, truth) for use in (cams[:2], cams)])
    out = {"lens": lens, "copies": copies}
    for p, r in runs.items():
        r = np.array(r)  # columns: refitted 1+2, refitted 1+2+3, true cameras 1+2, true cameras 1+2+3
        out[f"Z{p:g}_held_out"] = {
            "cameras_1_2_mean_sd_mm": [round(float(r[:, 0].mean()), 4), round(float(r[:, 0].std()), 4)],
            "cameras_1_2_3_mean_sd_mm": [round(float(r[:, 1].mean()), 4), round(float(r[:, 1].std()), 4)],
            "true_cameras_1_2_mean_mm": round(float(r[:, 2].mean()), 4),
            "true_cameras_1_2_3_mean_mm": round(float(r[:, 3].mean()), 4),
            "share_cameras_1_2_within_target": round(float(np.mean(r[:, 0] <= TARGETS.get(p, np.inf))), 3)
            if p in TARGETS else None,
            "share_three_cameras_better": round(float(np.mean(r[:, 1] < r[:, 0])), 3)}
    return out


def _mean_error(cal, test: pd.DataFrame, cams) -> float:
    xyz, _ = triangulate(cal, {n: test[[f"x_{n}", f"y_{n}"]].to_numpy(float) for n in cams}, refine=True)
    err = np.linalg.norm(xyz - test[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), axis=1)
    return float(np.nanmean(err))


def five_plane_twin(seeds=range(5)) -> dict:
    """The outer-planes protocol on the twin five-plane target (module docstring): per lens, the automatic
    choice's mean error on the outer planes over the best forced model's, per seed, and the choices."""
    out = {}
    for label, distortion in (("prism_lens", PRISM_LENS), ("without_prism", PRISM_LENS[:5])):
        ratios, chosen = [], []
        for seed in seeds:
            df = five_plane_target(distortion, seed)
            auto, cal = outer_planes_error(df, "auto")
            best = min(outer_planes_error(df, lens)[0] for lens in AUTO_LENSES)
            ratios.append(round(auto / best, 4))
            chosen.append([r["lens"] for r in cal.report["per_camera"].values()])
        out[label] = {"auto_over_best": ratios, "worst_auto_over_best": max(ratios), "chosen": chosen}
    return out


def run() -> dict:
    out: dict = {"five_plane_twin": five_plane_twin()}
    if not (DATA / "cam3_cal_points.txt").exists():
        return {**out, "skipped": f"{DATA} absent"}
    df = table()
    out["readme_figures_cameras_1_2_before"] = README_FIGURES
    ratios = []
    for plane in (-12.0, -6.0, 0.0):
        for cams in (("cam1", "cam2"), ("cam1", "cam2", "cam3")):
            key = f"Z{plane:g}_held_out_{'+'.join(c[-1] for c in cams)}"
            out[key + "_auto"] = held_out(df, plane, cams, "auto")
            out[key + "_forced_mean_mm"] = {lens: held_out(df, plane, cams, lens)["mean_mm"] for lens in AUTO_LENSES}
            ratio = out[key + "_auto"]["mean_mm"] / min(out[key + "_forced_mean_mm"].values())
            out[key + "_auto"]["auto_over_best"] = round(ratio, 4)
            ratios.append(ratio)
    out["worst_auto_over_best"] = round(max(ratios), 4)
    out["mean_auto_over_best"] = round(float(np.mean(ratios)), 4)
    c = time.process_time()
    out["noise_floor"] = noise_floor(df)
    out["noise_floor"]["cpu_s"] = round(time.process_time() - c, 1)
    return out


if __name__ == "__main__":
    print(json.dumps(run(), indent=2, default=float))
