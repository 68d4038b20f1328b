"""DEM parameter sweep: response-surface fit against known quadratics, ranking, the suggested parameters,
a sweep of rendered DEM heaps and tracer trajectories with a known optimum, the CLI, bad input."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.cli import main
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.sweep import Coding, fit_surface, read_runs, run_sweep
from sweep_synth import make_sweep, true_angle


def test_quadratic_surface_recovers_a_known_quadratic():
    X = np.array(list(itertools.product([0.1, 0.2, 0.3], [1.0, 2.0, 4.0], [5.0, 6.0, 7.0])))
    coding = Coding.from_runs(X, ["a", "b", "c"])
    x = coding.code(X)
    y = 30 + 2 * x[:, 0] - 3 * x[:, 1] + 0.5 * x[:, 2] + 1.5 * x[:, 0] * x[:, 1] - 2 * x[:, 1] ** 2
    s = fit_surface(x, y, ["a", "b", "c"], "angle_deg")
    assert s.model == "quadratic" and s.r2 == pytest.approx(1.0) and s.q2 == pytest.approx(1.0)
    coef = dict(zip(s.terms, s.coef, strict=True))
    expect = {"1": 30, "a": 2, "b": -3, "c": 0.5, "a*b": 1.5, "b^2": -2, "a^2": 0, "c^2": 0, "a*c": 0, "b*c": 0}
    for term, value in expect.items():
        assert coef[term] == pytest.approx(value, abs=1e-9)
    noisy = y + np.random.default_rng(0).normal(0, 0.5, len(y))
    s2 = fit_surface(x, noisy, ["a", "b", "c"], "angle_deg")
    assert 0.9 < s2.r2 < 1.0 and s2.q2 < s2.r2 and s2.rmse == pytest.approx(0.5, rel=0.5)
    pick = np.random.default_rng(1).choice(len(y), 9, replace=False)
    few = fit_surface(x[pick], y[pick], ["a", "b", "c"], "angle_deg")  # too few runs for the full quadratic
    assert few.model != "quadratic"
    with pytest.raises(SandtrackError, match="do not support"):
        fit_surface(x[:9], y[:9], ["a", "b", "c"], "angle_deg")  # a is the same in all of them


def test_angle_only_sweep_ranks_by_error_and_suggests_a_set_on_the_target(tmp_path):
    rows = [{"run": f"r{k}", "e": e, "mu": mu, "angle_deg": true_angle(e, mu, 0.25)}
            for k, (e, mu) in enumerate(itertools.product([0.3, 0.5, 0.7], [0.05, 0.1, 0.2, 0.3, 0.4]))]
    pd.DataFrame(rows).to_csv(tmp_path / "runs.csv", index=False)
    runs, params = read_runs(tmp_path / "runs.csv")
    assert params == ["e", "mu"]
    res = run_sweep(runs, params, target_angle_deg=31.0)
    err = np.abs(res.table["angle_deg"] - 31.0).to_numpy()
    assert (np.diff(err) >= 0).all() and res.table["rank"].tolist() == list(range(1, 16))
    sg = res.suggestion
    assert sg["predicted"]["angle_deg"] == pytest.approx(31.0, abs=0.01)
    assert abs(true_angle(sg["params"]["e"], sg["params"]["mu"], 0.25) - 31.0) < 0.001
    assert "many parameter sets" in sg["note"]


@pytest.fixture(scope="module")
def synthetic_sweep(tmp_path_factory):
    levels = {"restitution": [0.3, 0.7], "rolling_friction": [0.05, 0.15, 0.3], "poisson": [0.2, 0.3]}
    return make_sweep(tmp_path_factory.mktemp("sweep"), levels=levels, height_mm=40.0, diameter_mm=3.5)


def test_sweep_of_dem_runs_ranks_fits_and_suggests(synthetic_sweep, capsys, tmp_path):
    runs_csv, truth, target = synthetic_sweep
    folder = runs_csv.parent
    assert main(["sweep", str(runs_csv), "--target-angle", f"{target}", "--experiment",
                 str(folder / "experiment.csv"), "--dem-units", "mm", "--workers", "1", "--json",
                 "--out", str(tmp_path / "ranked.csv"), "--plot", str(tmp_path / "sweep.png")]) == 0
    out = json.loads(capsys.readouterr().out)
    table = pd.DataFrame(out["runs"]).merge(truth[["run", "true_angle_deg"]], on="run")
    assert np.abs(table["angle_deg"] - table["true_angle_deg"]).max() < 0.6  # every run's heap measured
    assert table["rank"].tolist() == list(range(1, len(table) + 1))
    # the best run is the one nearest the experiment's parameters (0.45, 0.22, 0.25) on this grid
    assert table.iloc[0]["rolling_friction"] in (0.15, 0.3)
    assert out["surfaces"]["angle_deg"]["r2"] > 0.999  # measured 0.99934
    sg = out["suggestion"]["params"]
    assert abs(sg["rolling_friction"] - 0.22) < 0.0063  # measured 0.0042
    # the suggestion's true angle: measured 0.016 deg from the target
    assert abs(true_angle(sg["restitution"], sg["rolling_friction"], sg["poisson"]) - target) < 0.024
    assert pd.read_csv(tmp_path / "ranked.csv")["run"].tolist() == table["run"].tolist()
    assert (tmp_path / "sweep.png").stat().st_size > 10_000


def test_bad_sweep_tables_are_one_line(tmp_path, capsys):
    (tmp_path / "a.csv").write_text("run,repose\nr1,x.liggghts\n")
    assert main(["sweep", str(tmp_path / "a.csv"), "--target-angle", "30"]) == 1
    assert "no numeric parameter" in capsys.readouterr().err
    (tmp_path / "b.csv").write_text("run,mu,angle_deg\nr1,0.1,30\nr2,0.1,31\nr3,0.1,32\n")
    with pytest.raises(SandtrackError, match="one value in every run"):
        run_sweep(*read_runs(tmp_path / "b.csv"), target_angle_deg=30)
    (tmp_path / "c.csv").write_text("run,mu,angle_deg\nr1,0.1,30\nr2,0.2,31\n")
    assert main(["sweep", str(tmp_path / "c.csv")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nothing to rank" in err[0]


def test_sweep_ranks_by_chi2_given_the_experiment_uncertainty(synthetic_sweep, capsys):
    runs_csv, _truth, _target = synthetic_sweep
    folder = runs_csv.parent
    traj_only = folder / "runs_trajectories.csv"
    pd.read_csv(runs_csv).drop(columns=["repose"]).to_csv(traj_only, index=False)
    base = ["sweep", str(traj_only), "--experiment", str(folder / "experiment.csv"), "--dem-units", "mm", "--json"]
    assert main([*base, "--metric", "chi2_reduced"]) == 1  # the experiment file has no sd columns
    err = capsys.readouterr().err
    assert "--exp-sd-mm" in err and len(err.strip().splitlines()) == 1
    assert main([*base, "--metric", "chi2_reduced", "--exp-sd-mm", "0.3"]) == 0
    by_chi2 = pd.DataFrame(json.loads(capsys.readouterr().out)["runs"])
    assert main(base) == 0
    by_rmse = pd.DataFrame(json.loads(capsys.readouterr().out)["runs"])
    # the same noise everywhere: χ² per dof orders the runs as the RMSE does, and says which are consistent
    assert by_chi2["run"].tolist()[:3] == by_rmse["run"].tolist()[:3]
    assert (np.diff(by_chi2["chi2_reduced"]) >= 0).all() and by_chi2["consistent"].iloc[-1] == False  # noqa: E712
