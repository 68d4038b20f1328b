"""`sandtrack xyz PIXELS.csv`: XYZ of any pixels table, against known points."""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.cli import main
from sandtrack_tui.regression import TrainConfig, train
from sandtrack_tui.regression.synthetic import calibration_points, study_rig

sys.path.insert(0, str(Path(__file__).parent))
from test_lens_models import POINTS, rig  # noqa: E402


@pytest.fixture(scope="module")
def stereo(tmp_path_factory):
    """The study's two cameras, a small trained model (with its residual variant) and known points."""
    folder = tmp_path_factory.mktemp("pixels")
    cal = study_rig()
    cal.save(folder / "calibration.toml")
    pts = calibration_points(cal, n_points=1200, seed=3, noise_px=0.0)
    cfg = TrainConfig.fast(epochs=1, residual_epochs=1, hidden=(32, 32), residual_hidden=(16,), seed=1)
    train(pts, cfg, calibration=cal).save(folder / "model.pt")
    return folder, cal, pts


def test_two_cameras_with_pass_through_columns(stereo, tmp_path, capsys):
    folder, cal, pts = stereo
    table = pts.head(300).copy()
    table["note"] = [f"p{i}" for i in range(len(table))]
    table.loc[10:19, ["xf", "yf"]] = np.nan  # not seen by the front camera
    csv = tmp_path / "pixels.csv"
    table.to_csv(csv, index=False)
    out = tmp_path / "xyz.csv"
    assert main(["xyz", str(csv), "--calibration", str(folder / "calibration.toml"), "--method", "triangulation",
                 "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["rows"] == 300 and summary["methods"]["triangulation"] == {"rows": 300, "with_xyz": 290}
    assert any("X_mm_input" in n for n in summary["notes"])
    res = pd.read_csv(out)
    assert list(res.columns[: len(table.columns)]) == [c if c not in ("X_mm", "Y_mm", "Z_mm") else f"{c}_input"
                                                       for c in table.columns]
    assert list(res["note"]) == list(table["note"]) and set(res["method"]) == {"triangulation"}
    err = np.linalg.norm(res[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - table[["X_mm", "Y_mm", "Z_mm"]].to_numpy(), axis=1)
    seen = table["xf"].notna().to_numpy()
    assert err[seen].max() < 1.2e-4 and res["residual_px"][seen].max() < 1e-6  # measured 7.8e-5 mm, 0 px
    assert res.loc[~seen, "X_mm"].isna().all()
    # without -o the table goes to stdout
    assert main(["xyz", str(csv), "--calibration", str(folder / "calibration.toml"), "--method",
                 "triangulation"]) == 0
    streamed = pd.read_csv(io.StringIO(capsys.readouterr().out))
    assert len(streamed) == 300 and np.allclose(streamed["X_mm"], res["X_mm"], equal_nan=True)


def test_network_methods_one_row_per_method(stereo, tmp_path, capsys):
    folder, cal, pts = stereo
    table = pts.head(50)[["xs", "ys", "xf", "yf"]].copy()
    table.loc[len(table)] = [5.0, 5.0, 1900.0, 1070.0]  # far outside what the network was trained on
    csv = tmp_path / "pixels.csv"
    table.to_csv(csv, index=False)
    out = tmp_path / "xyz.csv"
    assert main(["xyz", str(csv), "--calibration", str(folder / "calibration.toml"), "--model",
                 str(folder / "model.pt"), "--method", "all", "-o", str(out)]) == 0
    capsys.readouterr()
    res = pd.read_csv(out)
    assert len(res) == 3 * len(table)
    assert list(res["method"][:3]) == ["triangulation", "mlp", "residual"]
    assert np.allclose(res["xs"].to_numpy()[::3], table["xs"])  # input order, methods side by side
    assert res["method"].iloc[-2] == "mlp_outside"
    truth = pts.head(50)[["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    for m in ("triangulation", "residual"):
        got = res[res["method"] == m][["X_mm", "Y_mm", "Z_mm"]].to_numpy()[:50]
        assert np.linalg.norm(got - truth, axis=1).mean() < (1e-3 if m == "triangulation" else 5.0)


def test_any_number_of_cameras_named_after_the_calibration(tmp_path, capsys):
    cal = rig("full", 3)
    cal.save(tmp_path / "cal.toml")
    px = {n: c.project(POINTS) for n, c in cal.cameras.items()}
    table = pd.DataFrame({"point": np.arange(len(POINTS))})
    for n, p in px.items():
        table[f"x_{n}"], table[f"y_{n}"] = p[:, 0], p[:, 1]
    table.loc[:99, ["x_c2", "y_c2"]] = np.nan  # two cameras
    table.loc[100:149, ["x_c0", "y_c0", "x_c1", "y_c1"]] = np.nan  # one camera: no point
    csv = tmp_path / "pixels.csv"
    table.to_csv(csv, index=False)
    assert main(["xyz", str(csv), "--calibration", str(tmp_path / "cal.toml"), "-o", str(tmp_path / "o.csv")]) == 0
    capsys.readouterr()
    res = pd.read_csv(tmp_path / "o.csv")
    err = np.linalg.norm(res[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - POINTS, axis=1)
    # written to 0.1 um (measured 8e-5 mm); the rows without a second camera empty, the others all solved
    assert np.nanmax(err) < 1.2e-4 and np.isnan(err[100:150]).all() and np.isfinite(err[150:]).all()


def test_bad_input_one_line(stereo, tmp_path, capsys):
    folder, cal, pts = stereo
    csv = tmp_path / "pixels.csv"
    pts.head(5).to_csv(csv, index=False)
    odd = tmp_path / "odd.csv"
    pd.DataFrame({"x_top": [1.0], "y_top": [2.0], "xs": [3.0], "ys": [4.0]}).to_csv(odd, index=False)
    calib = str(folder / "calibration.toml")
    cases = [([str(csv)], "nothing to compute"),
             ([str(csv), "--method", "mlp", "--calibration", calib], "needs --model"),
             ([str(csv), "--calibration", calib, "--frame", "3"], "--frame goes with a project"),
             ([str(odd), "--calibration", calib], "does not have"),
             ([str(tmp_path / "none.csv"), "--calibration", calib], "not found"),
             ([str(folder / "model.pt"), "--calibration", calib], "")]
    for args, msg in cases:
        assert main(["xyz", *args, "-o", str(tmp_path / "o.csv")]) == 1
        err = capsys.readouterr().err
        assert msg in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
