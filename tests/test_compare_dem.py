"""Experiment vs DEM comparison: alignment, drift flags, ranking, pinned DTW/Fréchet, plots, CLI."""

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
from sandtrack_tui import dem as D  # noqa: E402
from sandtrack_tui.cli import main  # noqa: E402

FPS = 50.0


def _dtw_ref(a, b):
    n, m = len(a), len(b)
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    g = np.full((n + 1, m + 1), np.inf)
    g[0, 0] = 0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            if i == 1 and j == 1:
                g[i, j] = 2 * d[0, 0]
            else:
                g[i, j] = min(g[i - 1, j] + d[i - 1, j - 1], g[i, j - 1] + d[i - 1, j - 1],
                              g[i - 1, j - 1] + 2 * d[i - 1, j - 1])
    return g[n, m] / (n + m)


def _frechet_ref(a, b):
    n, m = len(a), len(b)
    d = np.linalg.norm(a[:, None] - b[None], axis=2)
    f = np.full((n + 1, m + 1), np.inf)
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            prev = 0.0 if i == j == 1 else min(f[i - 1, j], f[i, j - 1], f[i - 1, j - 1])
            f[i, j] = max(d[i - 1, j - 1], prev)
    return f[n, m]


@pytest.mark.parametrize("n,m", [(1, 1), (1, 4), (6, 2), (9, 13), (25, 17)])
def test_dtw_and_frechet_match_reference_dp(n, m):
    rng = np.random.default_rng(n * 100 + m)
    a, b = rng.standard_normal((n, 3)), rng.standard_normal((m, 3))
    assert C.dtw_normalised(a, b) == pytest.approx(_dtw_ref(a, b))
    assert C.discrete_frechet(a, b) == pytest.approx(_frechet_ref(a, b))


def test_distances_known_values():
    a = np.zeros((5, 3))
    b = np.zeros((5, 3))
    b[:, 2] = 2.0  # constant 2 mm apart
    assert C.dtw_normalised(a, b) == pytest.approx(2.0)
    assert C.discrete_frechet(a, b) == pytest.approx(2.0)
    b[3, 0] = 10.0  # one outlier sample: Fréchet sees it, normalised DTW averages it
    assert C.discrete_frechet(a, b) == pytest.approx(np.hypot(10, 2))
    assert C.dtw_normalised(a, b) < 4.0


@pytest.mark.parametrize("shift,drift,seed", [(0.137, {3: 6.0, 7: 4.0}, 0), (-0.31, {5: 3.0}, 3), (0.0, {}, 5)])
def test_recovers_shift_and_flags_drifting_particles(shift, drift, seed):
    exp, dem = make_case(shift_s=shift, drift=drift, seed=seed)
    c = C.compare(exp, dem, fps=FPS)
    assert abs(c.time_shift_s - shift) < 0.00065  # s; measured up to 0.00043 s (0.02 frame)
    assert sorted(c.summary["flagged_markers"]) == sorted(drift)
    ok = c.per_particle[~c.per_particle["flagged"]]
    assert ok["rmse_3d_mm"].max() < 0.81  # the others agree to the experiment's noise (measured 0.54 mm)
    if drift:
        worst = max(drift, key=drift.get)
        rate = c.per_particle.set_index("marker").loc[worst, "drift_mm_per_s"]
        assert rate == pytest.approx(drift[worst], rel=0.16)  # measured within 11 %


def test_rows_built_on_predictions_are_left_out():
    """An exported table holds XYZ for frames where a camera's status is "occluded": the tracker's held
    position while the marker was hidden, lagging the moving particle. Those rows must not pull the time
    alignment nor count in the errors (kept, they flag good particles as drifting)."""
    exp, dem = make_case(shift_s=0.137, seed=0)
    exp["status_side"], exp["status_front"] = "tracked", "tracked"
    for m, g in exp.groupby("marker"):  # each marker hidden for 0.4 s while it moves, frozen where it vanished
        hidden = g.index[(g["time_s"] > 2.0 + 0.2 * m) & (g["time_s"] < 2.4 + 0.2 * m)]
        exp.loc[hidden, list(C.AXES)] = exp.loc[hidden[0] - 1, list(C.AXES)].to_numpy(float)
        exp.loc[hidden, "status_side"] = "occluded" if m % 2 else "lost"
    kept_all = C.compare(exp.drop(columns=["status_side", "status_front"]), dem, fps=FPS)
    assert kept_all.summary["flagged_markers"] and kept_all.per_particle["rmse_3d_mm"].max() > 2.0
    c = C.compare(exp, dem, fps=FPS)
    assert abs(c.time_shift_s - 0.137) < 0.00054  # measured 0.00036 s
    assert c.per_particle["rmse_3d_mm"].max() < 0.81 and not c.summary["flagged_markers"]  # 0.54 mm


def test_matching_by_nearest_start_and_tool_onset():
    exp, dem = make_case(shift_s=0.2, seed=1)
    dem = dem.assign(particle_id=dem["particle_id"] + 100)  # ids differ: match by start position
    tool_t = np.arange(0, 6, 0.02)
    exp_tool = pd.DataFrame({"time_s": tool_t, "X_mm": 200 * np.clip(tool_t - 1.0, 0, None), "Y_mm": 0, "Z_mm": 0})
    dem_tool = exp_tool.assign(time_s=exp_tool["time_s"] - 0.2)
    c = C.compare(exp, dem, fps=FPS, exp_tool=exp_tool, dem_tool=dem_tool)
    assert c.onset["source"] == "tool"
    assert abs(c.onset["initial_shift_s"] - 0.2) < 1e-6
    assert c.pairs == {m: m + 100 for m in range(1, 11)}
    assert abs(c.time_shift_s - 0.2) < 0.0001  # measured 0.00004 s


def test_ranking_prefers_the_closer_run():
    exp, good = make_case(shift_s=0.1, seed=2)
    _, bad = make_case(shift_s=0.1, seed=2, dem_scale=1.3)  # 30 % more displacement
    _, worse = make_case(shift_s=0.1, seed=2, dem_scale=1.6)
    runs = [C.compare(exp, d, name=n, fps=FPS) for n, d in (("worse", worse), ("good", good), ("bad", bad))]
    r = C.rank(runs)
    assert list(r["name"]) == ["good", "bad", "worse"]
    assert list(r["rank"]) == [1, 2, 3]


def test_text_plot_draws_lines():
    t = np.linspace(0, 1, 50)
    out = C.text_plot([("rise", t, t)], width=20, height=5)
    rows = out.splitlines()[:5]
    # a rising line: the top row is drawn at the right, the bottom row at the left
    top, bottom = rows[0].split("┤")[1], rows[4].split("┤")[1]
    assert top.rstrip()[-1] != " " and top[:5].strip() == ""
    assert bottom[:3].strip() != "" and bottom[-5:].strip() == ""
    assert C.text_plot([]) == "(no data)"


def test_cli_compare_csv_dump_plots_json(tmp_path, capsys):
    exp, dem = make_case(shift_s=0.137, drift={3: 6.0}, seed=0, n=6)
    exp.to_csv(tmp_path / "exp.csv", index=False)
    D.write_exchange_csv(dem, tmp_path / "run_a.csv", units="m")
    _, dem_b = make_case(shift_s=0.137, seed=0, dem_scale=1.4, n=6)
    # run b as a LIGGGHTS dump (metres, with ITEM: TIME), axes swapped: DEM y = rig Z, DEM z = -rig Y
    with open(tmp_path / "run_b.dump", "w") as fh:
        for t, g in dem_b.groupby("time_s"):
            fh.write(f"ITEM: TIMESTEP\n{int(round((t + 1) * 1e5))}\nITEM: TIME\n{t}\nITEM: NUMBER OF ATOMS\n{len(g)}\n"
                     "ITEM: BOX BOUNDS ff ff ff\n-1 1\n-1 1\n-1 1\nITEM: ATOMS id type x y z\n")
            for r in g.itertuples():
                fh.write(f"{r.particle_id} 1 {r.X_mm / 1000} {r.Z_mm / 1000} {-r.Y_mm / 1000}\n")
    plots = tmp_path / "plots"
    rc = main(["compare", str(tmp_path / "exp.csv"), str(tmp_path / "run_a.csv"), "--json", "--plots", str(plots)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    run = out["runs"][0]
    assert abs(run["time_shift_s"] - 0.137) < 0.0016  # measured 0.0011 s
    assert run["summary"]["flagged_markers"] == [3]
    assert (plots / "run_a_error_over_time.png").is_file() and (plots / "run_a_marker3.png").is_file()
    # run b: only with the right axis mapping do the small vertical motions agree
    z_rmse = {}
    for axes in ("x,y,z", "x,-z,y"):
        rc = main(["compare", str(tmp_path / "exp.csv"), str(tmp_path / "run_b.dump"), "--axes", axes,
                   "--time-shift", "0.137", "--json"])
        assert rc == 0
        z_rmse[axes] = json.loads(capsys.readouterr().out)["runs"][0]["summary"]["rmse_z_mm_median"]
    assert z_rmse["x,-z,y"] < 5 < 20 < z_rmse["x,y,z"]
    # text output with the ranking of two runs
    assert main(["compare", str(tmp_path / "exp.csv"), str(tmp_path / "run_a.csv"), str(tmp_path / "run_a.csv")]) == 0
    assert "ranking" in capsys.readouterr().out


def test_cli_compare_bad_input(tmp_path, capsys):
    (tmp_path / "e.csv").write_text("a,b\n1,2\n")
    (tmp_path / "d.csv").write_text("particle_id,time_s,x,y,z\n1,0,0,0,0\n")
    assert main(["compare", str(tmp_path / "e.csv"), str(tmp_path / "d.csv")]) == 1
    assert "lacks columns" in capsys.readouterr().err
    assert main(["compare", str(tmp_path / "missing.csv"), str(tmp_path / "d.csv")]) == 1


def test_tool_file_columns_and_explicit_dem_onset(tmp_path):
    exp, dem = make_case(shift_s=0.25, seed=4, n=5)
    t = np.arange(0, 6, 0.02)
    f = tmp_path / "tool.csv"
    pd.DataFrame({"frame": np.arange(len(t)), "time_s": t, "tool_X_mm": 250.0,
                  "tool_Z_mm": 150 + 200 * np.clip(t - 1.0, 0, None)}).to_csv(f, index=False)
    tool = C.read_tool(f)
    assert list(tool.columns) == ["time_s", "X_mm", "Y_mm", "Z_mm"] and (tool["Y_mm"] == 0).all()
    # DEM clock: the tool starts at DEM time 1.0 - 0.25
    c = C.compare(exp, dem, fps=FPS, exp_tool=tool, dem_onset_s=0.75)
    assert c.onset["source"] == "tool" and abs(c.onset["initial_shift_s"] - 0.25) < 0.02
    assert abs(c.time_shift_s - 0.25) < 0.00075  # measured 0.0005 s
    (tmp_path / "bad.csv").write_text("time_s,speed\n0,1\n")
    with pytest.raises(Exception, match="position columns"):
        C.read_tool(tmp_path / "bad.csv")
