"""DEM comparison in units of the measurement's error: χ² against its effective degrees of freedom,
the 95 % band, the verdict per run, ranking by it; with and without the experiment's sd columns."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from compare_synth import make_case  # noqa: E402
from sandtrack_tui import compare as C  # noqa: E402
from sandtrack_tui import consistency as K  # noqa: E402
from sandtrack_tui import dem as D  # noqa: E402
from sandtrack_tui.cli import main  # noqa: E402

FPS = 50.0
NOISE = 0.3  # make_case's experiment noise per axis (mm); its DEM is exact


def with_sd(exp: pd.DataFrame, sd: float = NOISE) -> pd.DataFrame:
    return exp.assign(**{c: sd for c in C.SD_COLUMNS})


def test_chi2_null_distribution_is_honest_for_white_correlated_and_constant_errors():
    """Under the hypothesis (differences = measurement error of the stated sd), the p-value falls below 5 %
    about 5 % of the time or less, whether the errors are independent frame to frame, strongly correlated, or
    one constant error per trajectory (a resting marker); the naive count (3 dof per frame) rejects the
    correlated ones five to ten times too often."""
    rng = np.random.default_rng(0)
    n, reps = 150, 300
    rejected = {"white": 0, "ar": 0, "constant": 0}
    naive_rejected = {"ar": 0, "constant": 0}
    for _ in range(reps):
        ar = np.zeros((n, 3))
        x = rng.normal(size=3)
        for i in range(n):
            x = 0.95 * x + np.sqrt(1 - 0.95 ** 2) * rng.normal(size=3)
            ar[i] = x
        cases = {"white": rng.normal(size=(n, 3)), "ar": ar, "constant": np.tile(rng.normal(size=3), (n, 1))}
        for name, w in cases.items():
            c = K.chi2_of_track(np.arange(n), w)
            rejected[name] += c.p_value < 0.05
        from scipy import stats

        for name in naive_rejected:
            naive_rejected[name] += stats.chi2.sf(float((cases[name] ** 2).sum()), 3 * n) < 0.05
    rate = {k: v / reps for k, v in rejected.items()}
    assert 0.025 <= rate["white"] <= 0.075 and rate["ar"] <= 0.075 and rate["constant"] <= 0.085, rate
    assert min(naive_rejected.values()) / reps > 0.25, naive_rejected
    # the effective samples: all for white noise, about one for a constant error
    assert K.chi2_of_track(np.arange(n), rng.normal(size=(n, 3))).dof_eff / 3 > 0.9 * n
    assert K.chi2_of_track(np.arange(n), np.ones((n, 3))).dof_eff / 3 == pytest.approx(1.0, abs=0.05)
    # gaps in the frame grid (occlusions) are lags of their own, not neighbours
    frames = np.r_[np.arange(60), np.arange(100, 160)]
    assert K.chi2_of_track(frames, np.ones((120, 3))).samples == 120


def test_whitening_uses_covariances_and_skips_unusable_samples():
    cov = K.covariances(np.array([[1.0, 2.0, 3.0], [1.0, 1.0, np.nan], [0.0, 0.0, 0.0]]),
                        np.array([[0.5, 0.0, 0.0], [0, 0, 0], [0, 0, 0]]))
    d = np.array([[1.0, 2.0, 3.0], [1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    w, ok = K.whiten(d, cov)
    assert ok.tolist() == [True, False, False]  # NaN sd; an sd of 0 (no DEM term) claims exactness
    assert float(w[0] @ w[0]) == pytest.approx(float(d[0] @ np.linalg.solve(cov[0], d[0])))
    w, ok = K.whiten(d, K.covariances(np.zeros((3, 3)), None, extra_sd=0.5))
    assert ok.all() and np.allclose(w, d / 0.5)


def test_known_noise_gives_chi2_near_its_dof_and_a_consistent_run():
    exp, dem = make_case(shift_s=0.137, seed=0)
    c = C.compare(with_sd(exp), dem, fps=FPS)
    s = c.summary
    assert abs(c.time_shift_s - 0.137) < 0.004  # the χ² part leaves the alignment alone
    assert s["consistent"] is True and s["p_value"] > 0.05
    assert s["chi2_reduced"] == pytest.approx(1.0, abs=0.06)
    assert s["chi2_dof"] == pytest.approx(3 * s["samples_with_sd"] - 1)  # one dof for the time shift
    assert 0.8 * s["samples_with_sd"] < s["samples_eff"] <= s["samples_with_sd"]  # white noise: ~all independent
    assert 93.0 < s["within_95_pct"] < 97.0
    per = c.per_particle
    assert ((per["chi2_reduced"] > 0.85) & (per["chi2_reduced"] < 1.15)).all()
    assert "consistent with the experiment at the 5 % level" in s["verdict"]
    # the same run judged with a DEM uncertainty of its own: smaller χ², still consistent
    looser = C.compare(with_sd(exp), dem, fps=FPS, dem_sd_mm=0.3)
    assert looser.summary["chi2_reduced"] == pytest.approx(0.5, abs=0.05)


def test_a_1_5_mm_offset_is_detected_and_an_underestimated_sd_is_not_excused():
    exp, dem = make_case(shift_s=0.137, seed=3)
    shifted = dem.assign(Y_mm=dem["Y_mm"] + 1.5)
    c = C.compare(with_sd(exp), shifted, fps=FPS)
    s = c.summary
    assert s["consistent"] is False and s["p_value"] < 1e-6
    assert s["within_95_pct"] < 10 and s["chi2_reduced"] > 8
    # a persistent difference counts as correlated: few effective samples, and still rejected
    assert s["samples_eff"] < 0.05 * s["samples_with_sd"]
    assert (c.per_particle["p_value"] < 1e-3).all()
    assert "NOT consistent" in s["verdict"]
    # measured with a sd half the true noise: the run no longer looks consistent either
    half = C.compare(with_sd(exp, NOISE / 2), dem, fps=FPS)
    assert half.summary["consistent"] is False and half.summary["chi2_reduced"] == pytest.approx(4.0, rel=0.1)


def test_a_biased_measurement_with_its_bias_stated_is_judged_by_the_gaussian_behind_its_interval():
    """An experiment whose error has a known, varying mean (a network's error as the triangulation measured
    it, 2 mm) and 0.3 mm about it, stated as the export states it (sd: the 95 % interval around the XYZ;
    bias_*: the mean): the χ² with the bias is the one of the noise alone, and the time shift is found; read
    as centred, the same sd makes the exact DEM inconsistent (every error sits near its interval's edge)."""
    from sandtrack_tui.interval import interval_sd

    exp, dem = make_case(shift_s=0.137, seed=2)
    t, m = exp["time_s"].to_numpy(), exp["marker"].to_numpy()
    bias = np.column_stack([2.0 * np.sin(2 * np.pi * t / 3.0 + m + k) for k in range(3)])
    biased = exp.assign(X_mm=exp["X_mm"] + bias[:, 0], Y_mm=exp["Y_mm"] + bias[:, 1], Z_mm=exp["Z_mm"] + bias[:, 2])
    sd = interval_sd(bias, np.full(bias.shape, NOISE))
    stated = biased.assign(**{c: sd[:, k] for k, c in enumerate(C.SD_COLUMNS)},
                           **{c: bias[:, k] for k, c in enumerate(C.BIAS_COLUMNS)})
    c = C.compare(stated, dem, fps=FPS)
    assert abs(c.time_shift_s - 0.137) < 0.004
    assert c.summary["consistent"] is True and c.summary["chi2_reduced"] == pytest.approx(1.0, abs=0.08)
    assert 93.0 < c.summary["within_95_pct"] < 97.0
    assert c.errors[1]["bias_Y_mm"].abs().max() > 1.5  # the plots' band is centred on it
    centred = C.compare(stated.drop(columns=list(C.BIAS_COLUMNS)), dem, fps=FPS, time_shift_s=c.time_shift_s)
    assert centred.summary["consistent"] is False and centred.summary["within_95_pct"] < 90, centred.summary
    # rows without a bias (empty) are centred ones, as before
    part = stated.copy()
    part.loc[part["marker"] == 1, list(C.BIAS_COLUMNS)] = np.nan
    part.loc[part["marker"] == 1, list(C.SD_COLUMNS)] = NOISE
    part.loc[part["marker"] == 1, ["X_mm", "Y_mm", "Z_mm"]] = exp.loc[exp["marker"] == 1, ["X_mm", "Y_mm", "Z_mm"]]
    mixed = C.compare(part, dem, fps=FPS)
    assert mixed.summary["consistent"] is True and mixed.summary["chi2_reduced"] == pytest.approx(1.0, abs=0.08)


def test_rows_without_sd_and_tables_without_sd_columns():
    exp, dem = make_case(shift_s=0.0, seed=5, n=4)
    exp = with_sd(exp)
    exp.loc[exp.index[::10], "sd_X_mm"] = np.nan  # e.g. a network's XYZ outside its training volume
    c = C.compare(exp, dem, fps=FPS)
    assert c.summary["samples_without_sd"] == int(np.ceil(len(exp) / 10)) and c.summary["consistent"] is True
    bare = C.compare(exp.drop(columns=list(C.SD_COLUMNS)), dem, fps=FPS)
    assert bare.summary["consistent"] is None and np.isnan(bare.summary["chi2_reduced"])
    assert "no sd columns" in bare.summary["verdict"] and "chi2_reduced" not in bare.per_particle
    assumed = C.compare(exp.drop(columns=list(C.SD_COLUMNS)), dem, fps=FPS, exp_sd_mm=0.3)
    assert assumed.summary["consistent"] is True and "assumed" in assumed.summary["uncertainty"]
    empty = C.compare(exp.assign(**{c: np.nan for c in C.SD_COLUMNS}), dem, fps=FPS)
    assert empty.summary["consistent"] is None  # sd columns that are all empty carry nothing
    with pytest.raises(Exception, match="or none"):
        C.compare(exp.drop(columns=["sd_Z_mm"]), dem, fps=FPS)
    with pytest.raises(Exception, match="bias_X_mm, bias_Y_mm, bias_Z_mm or none"):
        C.compare(exp.assign(bias_X_mm=0.0), dem, fps=FPS)
    with pytest.raises(Exception, match=">= 0"):
        C.compare(exp, dem, fps=FPS, dem_sd_mm=-1)


def test_ranking_by_chi2_and_by_rmse_both_shown():
    """Two runs with the same RMSE: one misses where the experiment is precise, the other where it is not.
    χ² tells them apart (and calls the second consistent); RMSE cannot."""
    exp, dem = make_case(shift_s=0.1, seed=2, n=6, noise_mm=0.05)
    exp = with_sd(exp, 0.05)
    precise = exp["marker"] <= 3
    exp.loc[~precise, list(C.SD_COLUMNS)] = 1.0
    off_precise = dem.assign(X_mm=dem["X_mm"] + np.where(dem["particle_id"] <= 3, 0.6, 0.0))
    off_loose = dem.assign(X_mm=dem["X_mm"] + np.where(dem["particle_id"] > 3, 0.6, 0.0))
    runs = [C.compare(exp, d, name=n, fps=FPS, time_shift_s=0.1) for n, d in
            (("misses_precise", off_precise), ("misses_loose", off_loose))]
    r = C.rank(runs)
    assert r.attrs["ranked_by"] == "chi2_reduced"
    assert list(r["name"]) == ["misses_loose", "misses_precise"]
    assert r.set_index("name").loc["misses_loose", "consistent"] and not r.set_index("name").loc[
        "misses_precise", "consistent"]
    assert abs(r["rmse_3d_mm_all"].iloc[0] - r["rmse_3d_mm_all"].iloc[1]) < 0.02
    assert sorted(r["rank_rmse"]) == [1, 2]
    assert list(C.rank(runs, "rmse_3d_mm_all")["rank"]) == [1, 2]


def test_cli_compare_with_and_without_sd_columns(tmp_path, capsys):
    exp, dem = make_case(shift_s=0.137, seed=0, n=5)
    with_sd(exp).to_csv(tmp_path / "exp.csv", index=False)
    exp.to_csv(tmp_path / "old.csv", index=False)
    D.write_exchange_csv(dem, tmp_path / "good.csv", units="m")
    D.write_exchange_csv(dem.assign(Z_mm=dem["Z_mm"] + 1.5), tmp_path / "off.csv", units="m")
    plots = tmp_path / "plots"
    assert main(["compare", str(tmp_path / "exp.csv"), str(tmp_path / "off.csv"), str(tmp_path / "good.csv"),
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["ranked_by"] == "chi2_reduced" and [r["name"] for r in out["ranking"]] == ["good", "off"]
    runs = {r["name"]: r["summary"] for r in out["runs"]}
    assert runs["good"]["consistent"] is True and runs["off"]["consistent"] is False
    assert main(["compare", str(tmp_path / "exp.csv"), str(tmp_path / "off.csv"), "--plots", str(plots)]) == 0
    capsys.readouterr()
    assert (plots / "off_marker1.png").stat().st_size > (plots / "off_error_over_time.png").stat().st_size / 4
    # text: one verdict line per run, the band in the terminal plot
    assert main(["compare", str(tmp_path / "exp.csv"), str(tmp_path / "good.csv"), str(tmp_path / "off.csv")]) == 0
    text = capsys.readouterr().out
    assert "good: consistent with the experiment" in text and "off: NOT consistent" in text
    assert "95 % band edge" in text and "rank_rmse" in text
    # an older export without sd columns: said on stderr, ranked by RMSE, no χ²; or with an assumed sd
    assert main(["compare", str(tmp_path / "old.csv"), str(tmp_path / "good.csv"), str(tmp_path / "off.csv"),
                 "--json"]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert "has no sd columns" in cap.err and out["ranked_by"] == "rmse_3d_mm_all"
    assert all(r["summary"]["consistent"] is None for r in out["runs"])
    assert main(["compare", str(tmp_path / "old.csv"), str(tmp_path / "good.csv"), "--exp-sd-mm", "0.3",
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["runs"][0]["summary"]["consistent"] is True
    assert main(["compare", str(tmp_path / "old.csv"), str(tmp_path / "good.csv"), "--rank-by", "chi2"]) == 1
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1].startswith("sandtrack compare: error: cannot rank by χ²")
    assert "reading" not in err  # refused before any run was read


def test_f6_screen_gives_the_verdict_and_the_band(tmp_path):
    """The TUI's DEM comparison on a project tracked exactly (the XYZ carries no sd by triangulation here):
    with an assumed experiment sd it judges an exact DEM consistent and one 3 mm off not."""
    import asyncio

    from sandtrack_tui.tui.app import SandtrackApp
    from sandtrack_tui.tui.screens.compare import CompareScreen
    from tui_synth import MARKERS, N_FRAMES, make_project, true_xy, true_xyz

    project = make_project(tmp_path, calibrated=True)
    project.set_points([(f, cam, m, *true_xy(m, f, cam), "tracked") for m in MARKERS for f in range(N_FRAMES)
                        for cam in ("side", "front")], "tracks")
    dem = pd.DataFrame([{"particle_id": m, "time_s": f / 50.0, **dict(zip(C.AXES, true_xyz(m, f), strict=True))}
                        for m in MARKERS for f in range(N_FRAMES)])
    D.write_exchange_csv(dem, tmp_path / "exact.csv", units="mm")
    D.write_exchange_csv(dem.assign(Y_mm=dem["Y_mm"] + 3.0), tmp_path / "off.csv", units="mm")

    async def run() -> dict:
        verdicts = {}
        app = SandtrackApp(project)
        async with app.run_test(size=(120, 50)) as pilot:
            await pilot.pause(0.2)
            await pilot.press("f6")
            await pilot.pause(0.2)
            screen = app.screen
            assert isinstance(screen, CompareScreen)
            screen.query_one("#exp_sd").value = "0.5"
            for name in ("exact", "off"):
                screen.query_one("#dem").value = str(tmp_path / f"{name}.csv")
                screen.query_one("#verdict").update("")
                await pilot.click("#run")
                for _ in range(400):
                    await pilot.pause(0.05)
                    text = str(screen.query_one("#verdict").render())
                    if app.bg_task is None and text:
                        break
                verdicts[name] = text
                verdicts[name + "_plot"] = str(screen.query_one("#plot").render())
            screen.query_one("#dem_sd").value = "x"
            await pilot.click("#run")
            await pilot.pause(0.1)
            assert any("sd fields take a number" in n.message for n in app._notifications)
        return verdicts

    try:
        v = asyncio.run(run())
    finally:
        project.close()
    assert v["exact"].startswith("exact: consistent with the experiment")
    assert v["off"].startswith("off: NOT consistent") and "95 % band edge" in v["off_plot"]


def test_samples_beyond_the_calibrated_region_are_counted_in_the_verdict():
    """An export's `calibrated_region` column: the run's verdict says how many of the compared samples lie
    where the lens model extrapolated; the χ² itself is unchanged."""
    exp, dem = make_case(shift_s=0.137, seed=0)
    exp = with_sd(exp)
    plain = C.compare(exp, dem, fps=FPS).summary
    outside = exp["marker"] == exp["marker"].iloc[0]
    marked = C.compare(exp.assign(calibrated_region=np.where(outside, "outside", "inside")), dem, fps=FPS).summary
    assert marked["samples_outside_calibrated_region"] == int(outside.sum()) > 0
    assert marked["verdict"].startswith(plain["verdict"])
    assert f"; {int(outside.sum())} of the experiment's samples lie beyond the calibrated image region" in \
        marked["verdict"]
    assert marked["chi2_reduced"] == plain["chi2_reduced"] and "samples_outside_calibrated_region" not in plain
