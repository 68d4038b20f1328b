"""Trajectory export (CSV, Parquet, DLTdv) and import (DaVinci Resolve, DLTdv), incl. fuzzed bad input."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).parent))
from conftest import examples
from sandtrack_tui import trajectories as tr  # noqa: E402
from sandtrack_tui.cli import main  # noqa: E402
from sandtrack_tui.errors import SandtrackError  # noqa: E402
from sandtrack_tui.store import Project  # noqa: E402
from sync_media import write_av  # noqa: E402

W, H, N_FRAMES = 64, 48, 30


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    d = tmp_path_factory.mktemp("vids")
    for name in ("side", "front"):
        write_av(d / f"{name}.mp4", n_frames=N_FRAMES, size=(W, H))
    return d / "side.mp4", d / "front.mp4"


@pytest.fixture()
def project(tmp_path, videos):
    p = Project.create(tmp_path / "exp.sandtrack", {"side": videos[0], "front": videos[1]})
    yield p
    p.close()


def fake_xyz(n_frames=10, markers=(3, 7), methods=("triangulation", "mlp")) -> pd.DataFrame:
    rows = []
    for method in methods:
        for m in markers:
            for f in range(n_frames):
                if m == 7 and f == 4:
                    continue  # a gap
                rows.append(dict(frame=f, time_s=f / 50, marker=m, status_side="tracked", status_front="tracked",
                                 xs=10.0 + f + m, ys=20.0 - 0.5 * f, xf=30.0 + 0.25 * f, yf=5.0 + f,
                                 X_mm=m * 10 + f, Y_mm=-f * 0.5, Z_mm=3.0 + (method == "mlp"), method=method,
                                 residual_px=0.1 * f))
    return pd.DataFrame(rows)


def test_csv_and_parquet_roundtrip(tmp_path):
    df = fake_xyz()
    tr.export(df, tmp_path / "t.csv")
    tr.export(df, tmp_path / "t.parquet")
    a = pd.read_csv(tmp_path / "t.csv")
    b = pd.read_parquet(tmp_path / "t.parquet")
    assert list(a.columns) == tr.TIDY_COLUMNS == list(b.columns)
    assert len(a) == len(df) == len(b)
    key = ["method", "marker", "frame"]
    pd.testing.assert_frame_equal(a.sort_values(key).reset_index(drop=True)[["X_mm", "xs"]],
                                  df.sort_values(key).reset_index(drop=True)[["X_mm", "xs"]], check_dtype=False)


def test_dltdv_tables_layout_and_flip():
    df = fake_xyz()
    t = tr.dltdv_tables(df, {"side": H, "front": H})
    xy = t["xypts"]
    assert list(xy.columns[:4]) == ["pt1_cam1_X", "pt1_cam1_Y", "pt1_cam2_X", "pt1_cam2_Y"]
    assert len(xy) == 10
    # point 1 = marker 3; y flipped to a bottom-left origin
    assert xy["pt1_cam1_X"][2] == pytest.approx(10 + 2 + 3)
    assert xy["pt1_cam1_Y"][2] == pytest.approx(H - (20 - 1.0))
    assert np.isnan(xy["pt2_cam1_X"][4])  # marker 7's gap
    assert t["xyzpts"]["pt2_Z"][0] == pytest.approx(3.0)  # triangulation chosen by default
    assert list(t["xyzres"].columns) == ["pt1_dltres", "pt2_dltres"]
    assert (t["offsets"] == 0).all().all()


def test_export_cli_with_fake_xyz(project, tmp_path, monkeypatch, capsys):
    import sandtrack_tui.xyz as xyz

    monkeypatch.setattr(xyz, "compute_xyz", lambda proj, method="both", covariance=False: fake_xyz(
        methods=("triangulation", "mlp") if method == "both" else (method,)))
    project.close()
    assert main(["export", str(project.path), "-o", str(tmp_path / "out.csv"), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["rows"] == len(fake_xyz())
    assert main(["export", str(project.path), "-o", str(tmp_path / "trial"), "--format", "dltdv",
                 "--method", "mlp"]) == 0
    files = sorted(p.name for p in tmp_path.glob("trial-*.csv"))
    assert files == ["trial-markers.csv", "trial-offsets.csv", "trial-xypts.csv", "trial-xyzpts.csv",
                     "trial-xyzres.csv"]
    assert pd.read_csv(tmp_path / "trial-xyzpts.csv")["pt1_Z"][0] == pytest.approx(4.0)
    assert main(["export", str(project.path), "-o", str(tmp_path / "out.xyz")]) == 1  # unknown format


def test_dltdv_roundtrip_into_project(project, tmp_path):
    df = fake_xyz()
    tr.write_dltdv(df, tmp_path / "trial", {"side": H, "front": H})
    pts = tr.read_dltdv_xypts(tmp_path / "trial-xypts.csv", {"side": H, "front": H})
    res = tr.import_points(project, pts.rename(columns={"point": "marker"}), "import")
    assert res["new_markers"] == [1, 2]
    got = project.points(camera="side", marker=1)
    assert (got["status"] == "imported").all()
    src = df[(df["method"] == "triangulation") & (df["marker"] == 3)]
    np.testing.assert_allclose(got["x_px"], src["xs"])
    np.testing.assert_allclose(got["y_px"], src["ys"])
    assert len(project.points(marker=2, camera="side")) == 9
    assert project.undo() is not None  # one edit undoes the whole import
    assert project.points().empty and project.markers().empty


def test_davinci_conventions(tmp_path):
    f = tmp_path / "track.csv"
    f.write_text("Frame,X,Y\n0,0.5,0.5\n1,0.25,0.75\n")
    a = tr.read_davinci(f, W, H, "height")
    np.testing.assert_allclose(a["x_px"], [0.5 * W - 0.5, 0.25 * W - 0.5])
    np.testing.assert_allclose(a["y_px"], [0.5 * H - 0.5, 0.25 * H - 0.5])
    b = tr.read_davinci(f, W, H, "width")  # y in image widths: 0.5 -> H - 0.5 W
    np.testing.assert_allclose(b["y_px"][0], H - 0.5 * W - 0.5)
    g = tmp_path / "noheader.csv"
    g.write_text("5 0.1 0.2\n6 0.1 0.25\n")
    c = tr.read_davinci(g, W, H, "height", frame_offset=5)
    assert list(c["frame"]) == [0, 1]


def test_davinci_cli_import_and_preview(project, tmp_path, capsys):
    f = tmp_path / "track.csv"
    f.write_text("frame,x,y\n" + "".join(f"{i},{0.2 + 0.01 * i},{0.5}\n" for i in range(N_FRAMES)))
    project.close()
    png = tmp_path / "prev.png"
    assert main(["import", str(project.path), str(f), "--format", "davinci", "--camera", "front", "--marker", "4",
                 "--y-units", "height", "--label", "blue4", "--preview", str(png), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["points"] == N_FRAMES and png.is_file()
    with Project.open(project.path) as p:
        assert p.markers().set_index("id")["label"][4] == "blue4"
        assert len(p.points(camera="front", marker=4)) == N_FRAMES
    # missing explicit y units -> clear error, exit 1
    assert main(["import", str(project.path), str(f), "--format", "davinci", "--camera", "front",
                 "--marker", "4"]) == 1
    assert "y-units" in capsys.readouterr().err


@pytest.mark.parametrize("text,msg", [
    ("", "empty"),
    ("frame,x,y\n", "no data"),
    ("a,b,c\n1,2,3\n", "expected columns"),
    ("frame,x,y\n0,nan,nan\n", "no row"),
    ("frame,x,y\n0,0.5,abc\n", "not a number"),
    ("frame,x,y\n0,960,540\n", "look like pixels"),
    ("frame,x,y\n0,0.5,1e300\n", "outside"),
    ("frame,x,y\n0.5,0.5,0.5\n", "whole numbers"),
    ("frame,x,y\n1,0.5,0.5\n1,0.4,0.5\n", "twice"),
])
def test_davinci_bad_files(tmp_path, text, msg):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(SandtrackError, match=msg):
        tr.read_davinci(f, W, H, "height")


def _snapshot(project):
    return (project.points().to_dict("list"), project.markers().to_dict("list"), len(project.history()))


_cells = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12),
                   st.sampled_from(["", "NaN", "x", "1e999", "-0", " 3 "]), st.floats(0, 1))
_names = st.sampled_from(["frame", "x", "y", "Frame", "X", "Y", "z", "time", "pt1_cam1_X", "pt1_cam1_Y",
                          "pt1_cam2_X", "pt1_cam2_Y", "pt2_cam1_X", "pt1_cam3_Y", ""])


@st.composite
def csv_texts(draw):
    cols = draw(st.lists(_names, min_size=0, max_size=6))
    n = draw(st.integers(0, 6))
    lines = [",".join(cols)] if cols or draw(st.booleans()) else []
    for _ in range(n):
        lines.append(",".join(str(draw(_cells)) for _ in range(max(len(cols), draw(st.integers(0, 4))))))
    return "\n".join(lines) + draw(st.sampled_from(["", "\n"]))


@settings(max_examples=examples(120), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=csv_texts(), fmt=st.sampled_from(["davinci", "dltdv"]), y_units=st.sampled_from(["height", "width"]))
def test_fuzz_importers_never_crash_nor_write_half(project, tmp_path, text, fmt, y_units):
    f = tmp_path / "fuzz.csv"
    f.write_text(text)
    before = _snapshot(project)
    try:
        if fmt == "davinci":
            pts = tr.read_davinci(f, W, H, y_units).assign(camera="side", marker=1)
        else:
            pts = tr.read_dltdv_xypts(f, {"side": H, "front": H}).rename(columns={"point": "marker"})
        res = tr.import_points(project, pts, "fuzz")
    except SandtrackError as exc:
        assert str(exc) and "\n" not in str(exc)
        assert _snapshot(project) == before
        return
    assert res["points"] == len(pts)
    assert project.undo() is not None
    assert _snapshot(project)[:2] == before[:2]


@settings(max_examples=examples(40), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(xs=st.lists(st.one_of(st.floats(-1e6, 1e6), st.just(float("nan")), st.just(float("inf"))),
                   min_size=1, max_size=8),
       frames=st.lists(st.integers(-5, N_FRAMES + 5), min_size=1, max_size=8))
def test_fuzz_import_points_validates_ranges(project, xs, frames):
    n = min(len(xs), len(frames))
    rows = pd.DataFrame({"frame": frames[:n], "camera": "side", "marker": 1, "x_px": xs[:n], "y_px": 10.0})
    before = _snapshot(project)
    try:
        tr.import_points(project, rows, "fuzz")
    except SandtrackError:
        assert _snapshot(project) == before
        return
    got = project.points(camera="side", marker=1)
    assert len(got) == rows.drop_duplicates(["frame"]).shape[0]
    assert np.isfinite(got["x_px"]).all() and got["x_px"].between(-0.5 * W, 1.5 * W).all()
    project.undo()


def test_davinci_headerless_ragged_rows(tmp_path):
    f = tmp_path / "ragged.csv"
    f.write_text("0.0,1.0,2.0\n0.0,0.0,0.0,0.0")  # found by the fuzzer
    with pytest.raises(SandtrackError, match="not a readable"):
        tr.read_davinci(f, W, H, "height")
