"""DEM readers: exchange CSV (units, axis mapping) and LIGGGHTS/LAMMPS dumps; fuzzed bad input."""

from __future__ import annotations

import gzip

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import examples
from sandtrack_tui import dem
from sandtrack_tui.errors import SandtrackError


def test_exchange_csv_units_axes_offset(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("particle_id,time_s,x,y,z\n2,0.0,0.1,0.2,0.3\n1,0.0,0.01,0.02,0.03\n1,0.01,0.011,0.02,0.03\n")
    d = dem.read_exchange_csv(f, units="m", axes="x,-z,y", offset_mm=(1, 2, 3), time_offset_s=0.5)
    assert list(d.columns) == dem.DEM_COLUMNS
    assert list(d["particle_id"]) == [1, 1, 2]  # sorted
    np.testing.assert_allclose(d.iloc[0][["X_mm", "Y_mm", "Z_mm"]], [10 + 1, -30 + 2, 20 + 3])
    np.testing.assert_allclose(d["time_s"], [0.5, 0.51, 0.5])
    # unit from the column names
    g = tmp_path / "q.csv"
    g.write_text("particle_id,time_s,x_mm,y_mm,z_mm\n1,0,5,6,7\n")
    np.testing.assert_allclose(dem.read_exchange_csv(g).iloc[0][["X_mm", "Y_mm", "Z_mm"]], [5, 6, 7])


def test_exchange_roundtrip(tmp_path):
    df = pd.DataFrame({"particle_id": [1, 1, 2], "time_s": [0, 0.1, 0], "X_mm": [1.5, 2, 3], "Y_mm": [0, 1, 2],
                       "Z_mm": [-1, -2, -3]})
    dem.write_exchange_csv(df, tmp_path / "x.csv", units="m")
    back = dem.read_exchange_csv(tmp_path / "x.csv", units="m")
    np.testing.assert_allclose(back[["X_mm", "Y_mm", "Z_mm"]], df[["X_mm", "Y_mm", "Z_mm"]])


def _dump_block(step, atoms, header="id type x y z", time=None, box=((0, 1), (0, 1), (0, 1))):
    lines = ["ITEM: TIMESTEP", str(step)]
    if time is not None:
        lines += ["ITEM: TIME", str(time)]
    lines += ["ITEM: NUMBER OF ATOMS", str(len(atoms)), "ITEM: BOX BOUNDS ff ff ff"]
    lines += [f"{a} {b}" for a, b in box]
    lines += [f"ITEM: ATOMS {header}"] + [" ".join(map(str, a)) for a in atoms]
    return "\n".join(lines) + "\n"


def test_lammps_dump_unsorted_scaled_and_dt(tmp_path):
    f = tmp_path / "dump.liggghts"
    f.write_text(_dump_block(0, [(2, 1, 0.2, 0.2, 0.2), (1, 1, 0.1, 0.1, 0.1)]) +
                 _dump_block(1000, [(1, 1, 0.15, 0.1, 0.1), (2, 1, 0.2, 0.25, 0.2)]))
    d = dem.read_lammps_dump(f, dt=1e-5)
    assert list(d["particle_id"]) == [1, 1, 2, 2]
    np.testing.assert_allclose(d["time_s"], [0, 0.01, 0, 0.01])
    np.testing.assert_allclose(d[d.particle_id == 1]["X_mm"], [100, 150])
    with pytest.raises(SandtrackError, match="--dt"):
        dem.read_lammps_dump(f)
    # scaled coordinates through the box bounds, ITEM: TIME, gz, selected ids
    g = tmp_path / "dump.gz"
    with gzip.open(g, "wt") as fh:
        fh.write(_dump_block(5, [(7, 1, 0.5, 0.5, 0.5), (8, 1, 0, 0, 0)], "id type xs ys zs", time=0.25,
                             box=((-0.1, 0.1), (0, 0.2), (0, 1))))
    e = dem.read_lammps_dump(g, particle_ids=[7])
    assert list(e["particle_id"]) == [7]
    np.testing.assert_allclose(e.iloc[0][["time_s", "X_mm", "Y_mm", "Z_mm"]], [0.25, 0, 100, 500])


def test_per_step_dump_files_by_glob_and_read_dem(tmp_path):
    for k, step in enumerate([0, 200, 1000]):  # natural order: dump.200 before dump.1000
        (tmp_path / f"dump.{step}").write_text(_dump_block(step, [(1, 1, 0.001 * k, 0, 0)], time=step * 1e-4))
    d = dem.read_dem(str(tmp_path / "dump.*"))
    np.testing.assert_allclose(d["time_s"], [0, 0.02, 0.1])
    np.testing.assert_allclose(d["X_mm"], [0, 1, 2])


@pytest.mark.parametrize("text,msg", [
    ("", "empty"),
    ("a,b,c\n1,2,3\n", "expected columns"),
    ("particle_id,time_s,x,y,z\n", "no data rows"),
    ("particle_id,time_s,x,y,z\n1,0,abc,0,0\n", "not a number"),
    ("particle_id,time_s,x,y,z\n1,0,1e9,0,0\n", "wrong length unit"),
    ("particle_id,time_s,x,y,z\n1.5,0,1,0,0\n", "whole numbers"),
    ("particle_id,time_s,x,y,z\n1,0,nan,0,0\n", "finite"),
    ("particle_id,time_s,x,y,z\n1,0,1,0,0\n1,0,2,0,0\n", "twice"),
])
def test_exchange_bad_files(tmp_path, text, msg):
    f = tmp_path / "bad.csv"
    f.write_text(text)
    with pytest.raises(SandtrackError, match=msg):
        dem.read_exchange_csv(f)


@pytest.mark.parametrize("spec", ["x,y", "x,x,y", "a,b,c", "x,y,-w"])
def test_bad_axes(spec):
    with pytest.raises(SandtrackError, match="axis mapping"):
        dem.parse_axes(spec)


_cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**20, 10**20),
                  st.sampled_from(["", "x", "NaN", "1e400"]))


@settings(max_examples=examples(80))
@given(cols=st.lists(st.sampled_from(["particle_id", "time_s", "x", "y", "z", "x_mm", "id", "t", "q"]),
                     max_size=6),
       rows=st.lists(st.lists(_cell, min_size=0, max_size=6), max_size=5),
       units=st.sampled_from([None, "m", "mm", "cm"]))
def test_fuzz_exchange_csv(tmp_path_factory, cols, rows, units):
    f = tmp_path_factory.mktemp("fz") / "f.csv"
    f.write_text("\n".join([",".join(cols)] + [",".join(map(str, r)) for r in rows]))
    try:
        d = dem.read_exchange_csv(f, units=units)
    except SandtrackError as exc:
        assert str(exc) and "\n" not in str(exc)
        return
    assert list(d.columns) == dem.DEM_COLUMNS
    assert np.isfinite(d[["time_s", "X_mm", "Y_mm", "Z_mm"]].to_numpy()).all()
    assert np.abs(d[["X_mm", "Y_mm", "Z_mm"]].to_numpy()).max() <= dem.MAX_ABS_MM


@settings(max_examples=examples(60))
@given(text=st.lists(st.sampled_from(["ITEM: TIMESTEP", "0", "100", "ITEM: TIME", "0.5", "ITEM: NUMBER OF ATOMS",
                                      "ITEM: BOX BOUNDS pp pp pp", "0 1", "ITEM: ATOMS id type x y z",
                                      "ITEM: ATOMS id xs ys zs", "1 1 0.1 0.2 0.3", "2 1 nan 0 0", "3 1 0.1",
                                      "x y z", "1e999 1 0 0 0", ""]), max_size=14))
def test_fuzz_dump(tmp_path_factory, text):
    f = tmp_path_factory.mktemp("fd") / "dump.txt"
    f.write_text("\n".join(text))
    try:
        d = dem.read_lammps_dump(f, dt=1e-4)
    except SandtrackError as exc:
        assert str(exc) and "\n" not in str(exc)
        return
    assert np.isfinite(d[["time_s", "X_mm", "Y_mm", "Z_mm"]].to_numpy()).all()


def test_unit_guess_from_extent(tmp_path):
    f = tmp_path / "mm.csv"
    f.write_text("particle_id,time_s,x,y,z\n1,0,120.5,-40,10\n1,0.01,180.0,-38,12\n")
    d = dem.read_exchange_csv(f)
    assert d.attrs["units_guessed"] == "mm"
    assert d["X_mm"].iloc[1] == pytest.approx(180.0)
    g = tmp_path / "m.csv"
    g.write_text("particle_id,time_s,x,y,z\n1,0,0.1205,-0.04,0.01\n1,0.01,0.18,-0.038,0.012\n")
    e = dem.read_exchange_csv(g)
    assert e.attrs["units_guessed"] == "m"
    assert e["X_mm"].iloc[1] == pytest.approx(180.0)
    assert "units_guessed" not in dem.read_exchange_csv(g, units="m").attrs
