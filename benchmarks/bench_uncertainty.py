"""Do the XYZ sd columns hold what they claim? The share of true errors inside ±1.96 sd, per axis (95 % if
honest), for triangulation and the network.

1. The rendered sample (sample_data, the small preset; truth from its renderer): calibrated from its
   calibration videos (the bundle adjustment's covariance kept), then
   a. its calibration points (every board corner both cameras saw) through `xyz PIXELS.csv`'s path, and
   b. its tracked markers: auto-seed, track both ways, `compute_xyz` (each tracked point's sd from its
      match score), on the frames both cameras tracked; the network is the sample's own model.pt.
   `mlp_inconsistent_pct`: the share of the MLP's checked rows whose check against the triangulation
   failed (`regression.check`: the network's sd from its spread and that disagreement together; a failed
   row's, and that of a row outside the training volume (`mlp_outside_*`), from the disagreement alone).
2. The real stepped target (../shared/data/myptv_target, three cameras, surveyed dots): each camera fitted
   to two depth planes (`calibrate --from-points`, lens auto), the third plane triangulated, cameras 1+2
   and 1+2+3 (no network: three planes cannot train one). The pixel sd is each camera's own noise per
   image axis from the fit (`noise_px`). Two scores: `*_pct` (raw) the share of (XYZ - survey) within
   ±1.96 sd; `*_en_pct` the same against ±1.96 sqrt(sd² + σ_point²), σ_point the dots' own error per axis
   as the calibration on the two fitted planes estimated it (`known_points_sd_mm`, never from the
   held-out plane): the surveyed place is a reference with its own error, compared as a metrologist's
   Eₙ. `floor_*`: the same coverage by cameras fitted on all three planes (the held-out dots then in the
   fit).
3. Other calibration sessions of the twin (`calibration_sessions`): seeds 2.. of the small preset's
   calibration videos, the board resting at another place each (up to 40 mm across, 60 mm along the box) so
   that its reference detections, and the world frame fitted to them, are a new draw; each calibrated as the
   sample is, its corners scored as 1a, then pooled: the coverage over repeated calibrations, which one
   calibration's corners (one draw of the world frame and of the cameras) cannot judge. Each session's
   error is also split through the twin's true cameras (`against_true_cameras`): the pixel part's coverage,
   the calibration part in units of its own sd (rms z, pooled over the sessions), the world frame's χ². A
   session whose calibration fails is reported with its message.
4. `sandtrack xyz PIXELS.csv` on 1 M rows with that calibration (its covariance kept, so every row gets
   its sd): wall time of the whole command, best of `repeats`.

Run: `python benchmarks/bench_uncertainty.py` (prints JSON), or `run()` from benchmarks/run_all.py.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

SAMPLE = ROOT / "sample_data"
PLANES = (-12.0, -6.0, 0.0)


def _pct(c) -> list[float]:
    return [round(100 * float(v), 1) for v in c]


def calibrate_sample():
    from sandtrack_tui.board import load_board
    from sandtrack_tui.calibration.pipeline import calibrate_videos
    from sandtrack_tui.calibration.world import load_reference

    board = load_board(SAMPLE / "board.toml")
    frame, origin = load_reference(SAMPLE / "calibration" / "reference.toml")
    return calibrate_videos({c: SAMPLE / "calibration" / f"{c}.mp4" for c in ("side", "front")}, board,
                            reference_frame=frame, origin_mm=origin, with_points=True)


def calibration_points(res, model) -> dict:
    from sandtrack_tui.groundtruth import load_truth, true_points_xyz
    from sandtrack_tui.regression.spread import coverage
    from sandtrack_tui.xyz_pixels import camera_columns, xyz_from_pixels

    pts = res.points
    truth = true_points_xyz(pts, load_truth(SAMPLE))
    pixels = pts[["xs", "ys", "xf", "yf"]].reset_index(drop=True)
    out = {"points": int(len(pixels))}
    for method in ("triangulation", "mlp", "residual"):
        if method != "triangulation" and (model is None or (method == "residual" and not model.has_residual)):
            continue
        table, _ = xyz_from_pixels(pixels, camera_columns(pixels.columns), res.calibration, model, method=method)
        err = table[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float) - truth
        out[f"{method}_pct"] = _pct(coverage(err, table[["sd_X_mm", "sd_Y_mm", "sd_Z_mm"]].to_numpy(float)))
        if method == "mlp":
            out["mlp_inconsistent_pct"] = round(100 * float((table["network_check"] == "inconsistent").mean()), 1)
    return out


def tracked_markers(calibration, work: Path) -> dict:
    from sandtrack_tui.groundtruth import load_truth, match_marker_ids, xyz_truth
    from sandtrack_tui.regression.spread import coverage
    from sandtrack_tui.store import Project
    from sandtrack_tui.tracking.run import accept_seeds, auto_seed, track_project
    from sandtrack_tui.video import FramePair
    from sandtrack_tui.xyz import compute_xyz

    truth = load_truth(SAMPLE)
    exp = SAMPLE / "experiment"
    proj = Project.create(work / "t.sandtrack", {c: exp / f"{c}.mp4" for c in ("side", "front")}, overwrite=True)
    try:
        proj.set("sync_offset_s", truth.sync_offset_s)
        proj.set_calibration(calibration)
        if (SAMPLE / "model.pt").is_file():
            proj.set("model", {"path": str(SAMPLE / "model.pt")})
        sources = proj.open_sources()
        first, _ = FramePair(sources["side"], sources["front"], truth.sync_offset_s).side_range()
        accept_seeds(proj, auto_seed(proj, frame=first, sources=sources))
        track_project(proj, sources=sources)
        if first > 0:
            track_project(proj, sources=sources, start=first, direction="backward")
        for s in sources.values():
            s.close()
        id_map = match_marker_ids(proj.points(), truth)
        xyz = compute_xyz(proj, method="all")
    finally:
        proj.close()
    both = xyz[xyz["status_side"].isin(("tracked",)) & xyz["status_front"].isin(("tracked",))]
    out = {"nearest_frame_rows": int((xyz["xyz_source"] == "nearest_frame").sum())}
    for method, rows in both.groupby("method"):
        err = rows[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float) - xyz_truth(rows, truth, id_map)
        sd = rows[["sd_X_mm", "sd_Y_mm", "sd_Z_mm"]].to_numpy(float)
        out[f"{method}_pct"] = _pct(coverage(err, sd))
        out[f"{method}_rows_with_sd"] = int(np.isfinite(sd).all(axis=1).sum())
        out[f"{method}_median_sd_mm"] = [round(float(v), 3) for v in np.nanmedian(sd, axis=0)]
        if method == "mlp":
            checked = rows["network_check"].isin(("ok", "inconsistent"))
            out["mlp_inconsistent_pct"] = round(100 * float((rows["network_check"] == "inconsistent").sum()
                                                            / max(int(checked.sum()), 1)), 1)
    return out


def myptv() -> dict:
    import bench_lens
    from sandtrack_tui.calibration.from_points import calibrate_from_points

    if not bench_lens.DATA.is_dir():
        return {"skipped": f"{bench_lens.DATA} absent"}
    df = bench_lens.table()
    out, every, every_en = {}, [], []
    for cams in (("cam1", "cam2"), ("cam1", "cam2", "cam3")):
        for plane in PLANES:
            fit, test = df[df.Z_mm != plane], df[df.Z_mm == plane]
            cal = calibrate_from_points(fit, {n: (f"x_{n}", f"y_{n}") for n in cams}, lens="auto")
            key = f"Z{plane:g}_held_out_{'+'.join(n[-1] for n in cams)}"
            raw, en = _scored(cal, test, cams, out, key)
            every += raw
            every_en += en
    out["range_pct"] = [min(every), max(every)]
    out["range_en_pct"] = [min(every_en), max(every_en)]
    floor, floor_en = [], []
    for cams in (("cam1", "cam2"), ("cam1", "cam2", "cam3")):
        cal = calibrate_from_points(df, {n: (f"x_{n}", f"y_{n}") for n in cams}, lens="auto")
        out[f"sigma_point_mm_{'+'.join(n[-1] for n in cams)}"] = [round(v, 4) for v in
                                                                  cal.report["known_points_sd_mm"]]
        for plane in PLANES:
            raw, en = _scored(cal, df[df.Z_mm == plane], cams, out, f"floor_Z{plane:g}_{'+'.join(n[-1] for n in cams)}")
            floor += raw
            floor_en += en
    out["floor_range_pct"] = [min(floor), max(floor)]
    out["floor_range_en_pct"] = [min(floor_en), max(floor_en)]
    return out


def _session(seed: int) -> dict:
    """One calibration session of the twin, the board resting at a place drawn from the seed: coverage of its
    corners, their error, what the calibration chose."""
    import functools
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    import pandas as pd

    from sandtrack_tui.board import load_board
    from sandtrack_tui.calibration.pipeline import calibrate_videos
    from sandtrack_tui.errors import SandtrackError
    from sandtrack_tui.regression.spread import coverage
    from sandtrack_tui.triangulation import triangulate
    from sandtrack_tui.triangulation_sd import triangulation_sd
    from sandtrack_tui.twin import sample as twin
    from sandtrack_tui.twin.board_motion import REF_ORIGIN

    rng = np.random.default_rng(1000 + seed)
    rest = REF_ORIGIN + np.array([rng.uniform(-40, 40), 0.0, rng.uniform(-60, 60)])
    out = {"seed": seed, "rest_origin_mm": [round(float(v), 1) for v in rest]}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        # spawned, not forked: this process already runs threads (a fork could inherit a held lock)
        with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
            rendered = list(pool.map(functools.partial(twin._calibration_worker, rest_origin=rest),
                                     [(c, seed, "small", str(folder / f"{c}.mp4")) for c in ("side", "front")]))
        try:
            videos = {c: folder / f"{c}.mp4" for c in ("side", "front")}
            res = calibrate_videos(videos, load_board(SAMPLE / "board.toml"), reference_frame=twin.REF_FRAME,
                                   origin_mm=rest, with_points=True)
        except SandtrackError as exc:
            return {**out, "failed": str(exc)}
    truth = pd.DataFrame(next(r for r in rendered if r["camera"] == "side")["corners"],
                         columns=["frame", "corner_id", "x_px", "y_px", "X_mm", "Y_mm", "Z_mm"])
    pts = res.points.reset_index(drop=True)
    X = pts[["frame", "corner_id"]].merge(truth, on=["frame", "corner_id"], how="left")[["X_mm", "Y_mm", "Z_mm"]]
    pixels = {"side": pts[["xs", "ys"]].to_numpy(float), "front": pts[["xf", "yf"]].to_numpy(float)}
    rig, _ = triangulate(res.calibration, pixels, refine=True, world=False)
    err = res.calibration.to_world(rig) - X.to_numpy(float)
    sd = triangulation_sd(res.calibration, pixels, rig)
    ok = np.isfinite(err).all(axis=1) & np.isfinite(sd).all(axis=1)
    moving = ok & (pts["frame"].to_numpy() >= 80)  # the board lies at rest for the first 1.6 s
    out.update(against_true_cameras(res.calibration, pixels, rig, X.to_numpy(float)))
    return {**out, "corners": int(ok.sum()), "pct": _pct(coverage(err[ok], sd[ok])),
            "reprojection_rmse_px": round(float(res.report["reprojection_rmse_px"]), 3),
            "lens": {n: c.lens for n, c in res.calibration.cameras.items()},
            "lens_choice_spread": res.report["bundle"].get("lens_choice_spread"),
            "moving_mean_error_mm": [round(float(v), 3) for v in err[moving].mean(axis=0)],
            "moving_rms_error_mm": [round(float(v), 3) for v in np.sqrt((err[moving] ** 2).mean(axis=0))],
            "moving_median_sd_mm": [round(float(v), 3) for v in np.median(sd[moving], axis=0)],
            "_err": err[ok], "_sd": sd[ok]}


def against_true_cameras(calibration, pixels: dict, rig: np.ndarray, truth_mm: np.ndarray) -> dict:
    """One session's corner errors split in two through the twin's true cameras (ground_truth/cameras.toml,
    the same world axes; origins matched by the median): the pixel part (the same pixels triangulated
    through the true cameras, against the truth) scored against the sd without the calibration's part, and
    the calibration part (our XYZ against that) in units of the calibration's part of the sd: its rms z per
    axis is 1 when that part is honest (one draw per session: pool sessions). And the world frame's error
    (the first camera's pose in the world, ψ = rotation mrad, shift mm) against its stated covariance: χ²
    with 6 degrees of freedom."""
    from sandtrack_tui.calibration.world_uncertainty import psi
    from sandtrack_tui.camera import Calibration
    from sandtrack_tui.regression.spread import coverage
    from sandtrack_tui.triangulation import triangulate
    from sandtrack_tui.triangulation_sd import triangulation_sd

    true = Calibration.load(SAMPLE / "ground_truth" / "cameras.toml")
    through_true = true.to_world(triangulate(true, pixels, refine=True, world=False)[0])
    ours = calibration.to_world(rig)
    ok = np.isfinite(ours).all(axis=1) & np.isfinite(through_true).all(axis=1) & np.isfinite(truth_mm).all(axis=1)
    through_true = through_true + np.median(truth_mm[ok] - through_true[ok], axis=0)
    pixel_sd = triangulation_sd(calibration, pixels, rig, with_calibration=False)
    calibration_sd = triangulation_sd(calibration, pixels, rig, pixel_sd={n: np.zeros(len(rig)) for n in pixels})
    ok &= np.isfinite(pixel_sd).all(axis=1) & np.isfinite(calibration_sd).all(axis=1)
    z = (ours - through_true)[ok] / calibration_sd[ok]
    out = {"pixel_part_pct": _pct(coverage((through_true - truth_mm)[ok], pixel_sd[ok])),
           "calibration_part_rms_z": [round(float(v), 2) for v in np.sqrt(np.mean(z ** 2, axis=0))], "_z": z}
    joint = calibration.rig_uncertainty
    if joint is not None:
        d = psi(calibration.world_from_rig, true.world_from_rig)
        C = joint.world_jacobian @ joint.covariance @ joint.world_jacobian.T + joint.world_covariance
        out["world_frame_chi2"] = round(float(d @ np.linalg.solve(C, d)), 2)
    return out


def calibration_sessions(seeds=range(2, 8)) -> dict:
    """`_session` for each seed, and the coverage of their corners pooled."""
    from sandtrack_tui.regression.spread import coverage

    sessions = [_session(s) for s in seeds]
    done = [s for s in sessions if "failed" not in s]
    out = {"sessions": [{k: v for k, v in s.items() if not k.startswith("_")} for s in sessions]}
    if done:
        err, sd = np.vstack([s["_err"] for s in done]), np.vstack([s["_sd"] for s in done])
        out["pooled_pct"] = _pct(coverage(err, sd))
        out["per_session_mean_pct"] = [round(float(v), 1) for v in np.mean([s["pct"] for s in done], axis=0)]
        z = np.vstack([s["_z"] for s in done])
        out["calibration_part_rms_z"] = [round(float(v), 2) for v in np.sqrt(np.mean(z ** 2, axis=0))]
        chi2 = [s["world_frame_chi2"] for s in done if "world_frame_chi2" in s]
        if chi2:
            out["world_frame_chi2_per_dof"] = round(sum(chi2) / (6 * len(chi2)), 2)
    return out


def _scored(cal, test, cams, out: dict, key: str) -> tuple[list[float], list[float]]:
    """Coverage of the test dots (raw and Eₙ, module docstring) into out[key + "_pct" / "_en_pct"], the
    median sd and the rms error per axis beside them."""
    from sandtrack_tui.regression.spread import coverage
    from sandtrack_tui.triangulation_sd import camera_noise_px
    from sandtrack_tui.xyz import triangulate_with_sd

    pix = {n: test[[f"x_{n}", f"y_{n}"]].to_numpy(float) for n in cams}
    sd = {n: np.broadcast_to(camera_noise_px(cal, n), (len(test), 2)) for n in cams}
    xyz, _, s = triangulate_with_sd(cal, pix, sd, refine=True)
    err = xyz - test[["X_mm", "Y_mm", "Z_mm"]].to_numpy(float)
    point = np.asarray(cal.report.get("known_points_sd_mm", [0.0] * 3), float)
    out[f"{key}_pct"], out[f"{key}_en_pct"] = _pct(coverage(err, s)), _pct(coverage(err, np.hypot(s, point)))
    out[f"{key}_median_sd_mm"] = [round(float(v), 4) for v in np.nanmedian(s, axis=0)]
    from sandtrack_tui.calibration.region import region_labels

    outside = region_labels(cal, pix, len(test)) == "outside"
    out[f"{key}_outside_region_pct"] = round(100.0 * float(outside.mean()), 1)
    out[f"{key}_rms_error_mm"] = [round(float(v), 4) for v in np.sqrt(np.nanmean(err ** 2, axis=0))]
    return out[f"{key}_pct"], out[f"{key}_en_pct"]


def xyz_cli(calibration, repeats: int = 2) -> dict:
    import bench_xyz

    with tempfile.TemporaryDirectory() as tmp:
        cal_path, csv, out = Path(tmp) / "cal.toml", Path(tmp) / "pixels.csv", Path(tmp) / "xyz.csv"
        calibration.save(cal_path)
        bench_xyz.pixels_table(calibration, 1_000_000).to_csv(csv, index=False)
        bench_xyz.CAMERAS = cal_path
        bench_xyz.cli_run(csv, out)  # the compiled kernels into the cache once
        runs = [bench_xyz.cli_run(csv, out) for _ in range(repeats)]
        import pandas as pd

        sd = pd.read_csv(out, usecols=["sd_X_mm"])["sd_X_mm"]
    return {"cli_wall_s_runs": [round(w, 2) for w, _ in runs], "cli_wall_s_best": round(min(w for w, _ in runs), 2),
            "cli_cpu_s_best": round(min(c for _, c in runs), 2), "rows_with_sd": int(sd.notna().sum())}


def run(repeats: int = 2) -> dict:
    from sandtrack_tui.regression import load_model

    if not (SAMPLE / "ground_truth" / "cameras.toml").is_file():
        return {"skipped": "sample_data absent"}
    t0 = time.perf_counter()
    res = calibrate_sample()
    model = load_model(SAMPLE / "model.pt") if (SAMPLE / "model.pt").is_file() else None
    out = {"calibration_seconds": round(time.perf_counter() - t0, 1),
           "calibration_points": calibration_points(res, model)}
    with tempfile.TemporaryDirectory() as tmp:
        out["tracked_markers"] = tracked_markers(res.calibration, Path(tmp))
    out["myptv"] = myptv()
    out["calibration_sessions"] = calibration_sessions()
    out["xyz_cli_1m"] = xyz_cli(res.calibration, repeats)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


if __name__ == "__main__":
    print(json.dumps(run(), indent=2, default=float))
