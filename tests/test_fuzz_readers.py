"""Fuzzing the file readers: board files, calibration files (ours and Caliscope's), points tables,
seed files, model files and project files.

Every reader must either return something usable or raise SandtrackError with a one-line
message; nothing else may escape (the CLI would print a traceback), and a failed read writes
nothing. DEM, DaVinci and DLTdv readers are fuzzed in test_dem_readers.py / test_export_import.py.
"""

from __future__ import annotations

import datetime as dt
import functools
import math
import os
import shutil
import sqlite3
import tempfile
from contextlib import closing, suppress
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import tomli_w
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from conftest import examples
from sandtrack_tui.board import BoardSpec, board_from_dict, load_board
from sandtrack_tui.calibration.caliscope import export_caliscope, import_caliscope
from sandtrack_tui.calibration.from_points import calibrate_from_points, read_points_table
from sandtrack_tui.camera import Calibration
from sandtrack_tui.cli import main
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.regression.dataset import POINT_COLUMNS, check_points, load_points
from sandtrack_tui.regression.synthetic import calibration_points, study_rig
from sandtrack_tui.store import Project

# `make fuzz` runs these FUZZ_FACTOR times deeper with fresh random examples; SANDTRACK_FUZZ_EXAMPLES sets the count.
EXAMPLES = int(os.environ.get("SANDTRACK_FUZZ_EXAMPLES", examples(60)))
PHASES = [Phase.explicit, Phase.reuse, Phase.generate] + ([] if os.environ.get("SANDTRACK_FUZZ_NO_SHRINK") else
                                                           [Phase.shrink])
FUZZ = settings(max_examples=EXAMPLES, phases=PHASES,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def fresh(scratch: Path, name: str) -> Path:
    """A path in a folder of its own: no example sees a file (or an SQLite -wal/-shm) of an earlier one."""
    return Path(tempfile.mkdtemp(dir=scratch)) / name


def read_or_error(fn, *args, **kw):
    """Call a reader: its result, or None after checking the SandtrackError is one non-empty line."""
    try:
        return fn(*args, **kw)
    except SandtrackError as exc:
        msg = str(exc)
        assert msg.strip() and "\n" not in msg and "\r" not in msg, repr(msg)
        return None


# -- value strategies --------------------------------------------------------------------------
SCALARS = st.one_of(
    st.integers(-5, 30), st.integers(), st.floats(), st.text(max_size=10), st.booleans(),
    st.sampled_from([0, 1, 3, 8, 1920, 1080, 0.75, 2.5, 25.0, "DICT_4X4_50", "DICT_6X6_250", "charuco",
                     "chessboard", "pinhole", "fisheye", "", "²", "1e309", float("nan"), float("inf")]),
    st.datetimes(min_value=dt.datetime(1900, 1, 1), max_value=dt.datetime(2100, 1, 1)),
)
VALUES = st.recursive(SCALARS, lambda ch: st.lists(ch, max_size=10) | st.dictionaries(st.text(max_size=6), ch,
                                                                                        max_size=3), max_leaves=12)
FLOATS = st.floats() | st.floats(-1e4, 1e4)


def matrices(rows: int, cols: int):
    good = st.lists(st.lists(st.floats(-2000, 2000), min_size=cols, max_size=cols), min_size=rows, max_size=rows)
    return st.one_of(good, st.lists(st.lists(FLOATS, min_size=cols, max_size=cols), min_size=rows, max_size=rows),
                     VALUES)


def vectors(n: int):
    return st.one_of(st.lists(st.floats(-3, 3), min_size=n, max_size=n),
                     st.lists(FLOATS, min_size=0, max_size=n + 2), VALUES)


def maybe(strategy):
    return st.one_of(strategy, VALUES)


def mutated(text: str):
    """A real file's text, truncated or with a slice replaced by random characters."""
    return st.tuples(st.integers(0, len(text)), st.integers(0, len(text)), st.text(max_size=12)).map(
        lambda t: text[:min(t[0], t[1])] + t[2] + text[max(t[0], t[1]):])


def write(path, content) -> None:
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content, encoding="utf-8", errors="surrogatepass")


# -- board files -------------------------------------------------------------------------------
OUR_BOARD = st.fixed_dictionaries({}, optional={
    "type": maybe(st.sampled_from(["charuco", "chessboard"])), "columns": maybe(st.integers(0, 14)),
    "rows": maybe(st.integers(0, 12)), "square_mm": maybe(st.floats(-5, 60)), "marker_mm": maybe(st.floats(-5, 60)),
    "dictionary": maybe(st.sampled_from(["DICT_4X4_50", "DICT_5X5_100", "DICT_ARUCO_ORIGINAL", "DICT_9X9_1"])),
    "inverted": maybe(st.booleans()), "legacy": maybe(st.booleans())})
CALISCOPE_BOARD = st.fixed_dictionaries({}, optional={
    "columns": maybe(st.integers(0, 14)), "rows": maybe(st.integers(0, 12)), "board_height": maybe(st.floats(0, 20)),
    "board_width": maybe(st.floats(0, 20)), "dictionary": maybe(st.just("DICT_4X4_50")), "units": maybe(st.just("cm")),
    "aruco_scale": maybe(st.floats(-1, 2)), "square_size_override_cm": maybe(st.floats(-1, 10)),
    "inverted": maybe(st.booleans()), "legacy_pattern": maybe(st.booleans())})
BOARD_TEXT = BoardSpec(columns=8, rows=5, square_mm=25.0, marker_mm=18.75).to_toml()


def check_board(spec) -> None:
    if spec is None:
        return
    assert isinstance(spec, BoardSpec)
    assert isinstance(spec.columns, int) and isinstance(spec.rows, int) and spec.columns >= 3 and spec.rows >= 3
    assert math.isfinite(spec.square_mm) and spec.square_mm > 0
    assert 0 < spec.marker_size_mm < spec.square_mm
    if spec.columns * spec.rows <= 400:
        assert np.isfinite(spec.corner_points_mm()).all() and len(spec.corner_points_mm()) == spec.n_corners
        # a board the reader accepted can be built (the detector needs it)
        if spec.type == "charuco":
            read_or_error(spec.cv_board)


@FUZZ
@given(doc=st.one_of(OUR_BOARD, CALISCOPE_BOARD, CALISCOPE_BOARD.map(lambda d: {"charuco": d}),
                     st.dictionaries(st.text(max_size=6), VALUES, max_size=4)))
def test_fuzz_board_documents(scratch, doc):
    path = fresh(scratch, "board.toml")
    write(path, tomli_w.dumps(doc))
    check_board(read_or_error(load_board, path))
    check_board(read_or_error(board_from_dict, doc))


@FUZZ
@given(text=st.one_of(mutated(BOARD_TEXT), st.text(max_size=200)), raw=st.binary(max_size=64))
def test_fuzz_board_text(scratch, text, raw):
    for content in (text, raw):
        path = fresh(scratch, "board.toml")
        write(path, content)
        check_board(read_or_error(load_board, path))


# -- calibration files -------------------------------------------------------------------------
RIG = study_rig()


def camera_entries(valid: dict):
    """A camera table: each field the real one, a near miss, or anything."""
    return st.fixed_dictionaries({}, optional={
        "model": maybe(st.sampled_from(["pinhole", "fisheye"])),
        "size": maybe(st.just(valid["size"]) | st.lists(st.integers(-5, 5000), max_size=3)),
        "matrix": maybe(st.just(valid["matrix"]) | matrices(3, 3)),
        "distortion": maybe(st.just(valid["distortion"]) | vectors(5) | vectors(4)),
        "rotation": maybe(st.just(valid["rotation"]) | vectors(3)),
        "translation_mm": maybe(st.just(valid["translation_mm"]) | vectors(3)),
        "rmse_px": maybe(FLOATS)})


CAMERA_NAMES = st.sampled_from(["side", "front", "cam_0"]) | st.text(max_size=6)
CALIBRATION_DOCS = st.fixed_dictionaries({}, optional={
    "units": VALUES,
    "cameras": maybe(st.dictionaries(CAMERA_NAMES, camera_entries(RIG.cameras["side"].to_dict()), max_size=3)),
    "world": maybe(st.fixed_dictionaries({}, optional={"world_from_rig": maybe(matrices(4, 4))})),
    "report": VALUES})


def check_calibration(cal) -> None:
    """What a reader accepts can be used: finite numbers, points project, and it writes back the same."""
    if cal is None:
        return
    assert isinstance(cal, Calibration) and cal.cameras
    assert np.isfinite(cal.world_from_rig).all()
    for cam in cal.cameras.values():
        assert cam.width > 0 and cam.height > 0
        for a in (cam.matrix, cam.distortion, cam.rvec, cam.tvec):
            assert np.isfinite(a).all()
        cam.project(np.array([[0.0, 0.0, 1000.0], [10.0, -5.0, 800.0]]))
    again = Calibration.from_toml(cal.to_toml())
    assert again.names == cal.names
    for n in cal.names:
        np.testing.assert_array_equal(again.cameras[n].matrix, cal.cameras[n].matrix)


@FUZZ
@given(doc=CALIBRATION_DOCS)
def test_fuzz_calibration_documents(scratch, doc):
    path = fresh(scratch, "calibration.toml")
    write(path, tomli_w.dumps(doc))
    check_calibration(read_or_error(Calibration.load, path))


@FUZZ
@given(text=mutated(RIG.to_toml()), raw=st.binary(max_size=64))
def test_fuzz_calibration_text(scratch, text, raw):
    for content in (text, raw, b"\xff\xfe" + text.encode()):
        path = fresh(scratch, "calibration.toml")
        write(path, content)
        check_calibration(read_or_error(Calibration.load, path))


def caliscope_entries():
    return st.fixed_dictionaries({}, optional={
        "cam_id": maybe(st.integers(0, 4)), "size": maybe(st.just([1920, 1080]) | st.lists(st.integers(-5, 5000),
                                                                                           max_size=3)),
        "resolution": maybe(st.just([1920, 1080])), "rotation_count": VALUES, "error": maybe(FLOATS),
        "matrix": maybe(st.just(RIG.cameras["side"].matrix.tolist()) | matrices(3, 3)),
        "distortions": maybe(vectors(5) | vectors(4)), "translation": maybe(vectors(3)),
        "rotation": maybe(vectors(3) | matrices(3, 3)), "ignore": maybe(st.booleans()),
        "fisheye": maybe(st.booleans())})


CALISCOPE_IDS = st.sampled_from(["0", "1", "2", "²", "x", "10"])
CALISCOPE_DOCS = st.one_of(
    st.fixed_dictionaries({"cameras": st.dictionaries(CALISCOPE_IDS, caliscope_entries(), max_size=3)}),
    st.dictionaries(CALISCOPE_IDS.map(lambda k: f"cam_{k}"), caliscope_entries(), max_size=3),
    st.dictionaries(st.text(max_size=6), VALUES, max_size=3))


@FUZZ
@given(doc=CALISCOPE_DOCS, names=st.none() | st.lists(st.sampled_from(["side", "front", "top"]), min_size=1,
                                                       max_size=3, unique=True))
def test_fuzz_caliscope_documents(scratch, doc, names):
    path = fresh(scratch, "camera_array.toml")
    write(path, tomli_w.dumps(doc))
    cal = read_or_error(import_caliscope, path, names)
    check_calibration(cal)
    if cal is not None and names:
        assert cal.names == names[:len(cal.names)]


@FUZZ
@given(data=st.data(), raw=st.binary(max_size=64))
def test_fuzz_caliscope_text(scratch, data, raw):
    exported = fresh(scratch, "exported.toml")
    if not exported.exists():
        export_caliscope(RIG, exported)
    text = data.draw(mutated(exported.read_text()))
    for content in (text, raw):
        path = fresh(scratch, "camera_array.toml")
        write(path, content)
        check_calibration(read_or_error(import_caliscope, path))


# -- points tables -----------------------------------------------------------------------------
CELLS = st.one_of(st.integers(-3, 3000).map(str), st.floats().map(repr), st.sampled_from(["", "nan", "inf", "-inf",
                  "1e309", "x", '"', "1,5", " 7 ", "0x10", "None"]), st.text(max_size=5))


def csv_texts(columns: list[str]):
    header = st.lists(st.sampled_from([*columns, "junk", "x_top", "y_top", ""]), min_size=0, max_size=len(columns) + 2)
    full = st.permutations(columns).map(list)
    return st.tuples(st.one_of(header, full), st.integers(0, 14), st.data()).map(lambda t: t) \
        .flatmap(lambda t: st.lists(st.lists(CELLS, min_size=max(len(t[0]) - 1, 0), max_size=len(t[0]) + 1),
                                    min_size=t[1], max_size=t[1]).map(
            lambda rows, head=t[0]: "\n".join([",".join(head), *(",".join(r) for r in rows)]) + "\n"))


def check_points_table(df) -> None:
    if df is None:
        return
    assert list(df.columns) == POINT_COLUMNS and len(df) > 0
    assert np.isfinite(df.to_numpy(dtype=float)).all()
    assert df["frame"].dtype == np.int64


@FUZZ
@given(text=csv_texts(POINT_COLUMNS), raw=st.binary(max_size=64))
def test_fuzz_points_csv(scratch, text, raw):
    for content in (text, raw):
        path = fresh(scratch, "points.csv")
        write(path, content)
        check_points_table(read_or_error(load_points, path))


@FUZZ
@given(frame=st.lists(st.one_of(st.integers(), st.floats(), st.text(max_size=3)), min_size=1, max_size=5))
def test_fuzz_check_points_values(frame):
    df = pd.DataFrame({c: [1.0] * len(frame) for c in POINT_COLUMNS}).astype(object)
    df["frame"] = frame
    check_points_table(read_or_error(check_points, df))


FROM_POINTS_COLUMNS = ["xs", "ys", "xf", "yf", "X_mm", "Y_mm", "Z_mm"]
TRUE_POINTS = calibration_points(n_points=200, seed=5)


@settings(max_examples=max(EXAMPLES // 3, 10), phases=PHASES,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(text=st.one_of(csv_texts(FROM_POINTS_COLUMNS), mutated(TRUE_POINTS.to_csv(index=False))),
       raw=st.binary(max_size=64))
def test_fuzz_from_points_csv(scratch, text, raw):
    """The reader behind `sandtrack calibrate --from-points`, through to the fitted cameras."""
    def read_and_fit(path):
        df, cams = read_points_table(path)
        if len(cams) < 2:
            raise SandtrackError("pixel columns of at least two cameras are needed")
        return calibrate_from_points(df, cams)

    for content in (text, raw):
        path = fresh(scratch, "known.csv")
        write(path, content)
        cal = read_or_error(read_and_fit, path)
        if cal is not None:
            assert np.isfinite(cal.world_from_rig).all()
            for cam in cal.cameras.values():
                assert np.isfinite(cam.matrix).all()


SEED_COLUMNS = ["frame", "camera", "marker", "x", "y", "w", "h"]


@FUZZ
@given(text=csv_texts(SEED_COLUMNS), raw=st.binary(max_size=64))
def test_fuzz_seeds_csv(scratch, text, raw):
    from sandtrack_tui.cli.cmd_track import read_seeds_csv

    for content in (text, raw):
        path = fresh(scratch, "seeds.csv")
        write(path, content)
        seeds = read_or_error(read_seeds_csv, path)
        if seeds is not None:
            assert len(seeds) and np.isfinite(seeds[["x_px", "y_px"]].to_numpy()).all()


# -- model files -------------------------------------------------------------------------------
@functools.cache
def model_bytes() -> bytes:
    from sandtrack_tui.regression.train import TrainConfig, train

    pts = calibration_points(n_points=300, seed=1)
    model = train(pts, TrainConfig.fast(epochs=1, residual=False, hidden=(8, 8), threads=1))
    path = Path(tempfile.mkdtemp(prefix="sandtrack-fuzz-")) / "model.pt"
    model.save(path)
    data = path.read_bytes()
    shutil.rmtree(path.parent)
    return data


@settings(max_examples=max(EXAMPLES // 3, 10), phases=PHASES,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(cut=st.floats(0, 1), flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=8),
       raw=st.binary(max_size=64))
def test_fuzz_model_file(scratch, cut, flips, raw):
    from sandtrack_tui.regression.model import load_model, predict

    real = model_bytes()
    damaged = bytearray(real[: int(cut * len(real))])
    for pos, value in flips:
        if damaged:
            damaged[int(pos * (len(damaged) - 1))] = value
    for content in (bytes(damaged), raw):
        path = fresh(scratch, "model.pt")
        write(path, content)
        model = read_or_error(load_model, path)
        if model is not None:  # a flip the format cannot notice (e.g. inside a weight) still gives a model
            read_or_error(predict, model, np.array([[900.0, 500.0, 1000.0, 600.0]]))


# -- project files -----------------------------------------------------------------------------
@functools.cache
def project_bytes() -> bytes:
    """A real project (markers, points, settings, an edit history), closed (WAL merged)."""
    path = Path(tempfile.mkdtemp(prefix="sandtrack-fuzz-")) / "real.sandtrack"
    with Project.create(path) as proj:
        proj.set_calibration(RIG)
        proj.set("board", BoardSpec().to_json_dict())
        for m in range(1, 4):
            proj.add_marker(f"m{m}")
            proj.set_points(pd.DataFrame({"frame": range(60), "camera": "side", "marker": m, "x_px": 10.0 * m,
                                          "y_px": np.arange(60.0), "status": "tracked"}), f"track {m}")
        proj.undo()
    data = path.read_bytes()
    shutil.rmtree(path.parent)
    return data


def use_project(path) -> None:
    """Open a project and call its reading and editing API: each call works or gives one line."""
    proj = read_or_error(Project.open, path)
    if proj is None:
        return
    with proj:
        for call in (proj.videos, proj.cameras, proj.markers, proj.points, proj.history, proj.board,
                     proj.calibration, lambda: proj.get("model"), proj.undo, proj.redo,
                     lambda: proj.set_points([(0, "side", 1, 1.0, 2.0, "manual")], "fuzz edit"), proj.undo):
            read_or_error(call)


@FUZZ
@given(cut=st.floats(0, 1), flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=12))
def test_fuzz_damaged_project_file(scratch, cut, flips):
    real = project_bytes()
    data = bytearray(real[: int(cut * len(real))])
    for pos, value in flips:
        if len(data) > 100:
            data[100 + int(pos * (len(data) - 101))] = value  # past the header, into pages and rows
    path = fresh(scratch, "damaged.sandtrack")
    write(path, bytes(data))
    use_project(path)
    shutil.rmtree(path.parent)


@FUZZ
@given(raw=st.binary(max_size=300), header=st.booleans())
def test_fuzz_random_bytes_as_project(scratch, raw, header):
    path = fresh(scratch, "random.sandtrack")
    write(path, (b"SQLite format 3\x00" if header else b"") + raw)
    use_project(path)
    shutil.rmtree(path.parent)


SQL_VALUES = st.one_of(st.none(), st.integers(-2 ** 63, 2 ** 63 - 1), st.floats(), st.text(max_size=12),
                       st.binary(max_size=8), st.sampled_from(["{", "[1, 2]", '"x"', "5", "null", "tracked",
                                                               '[0, "side", 1]', "[1.0, 2.0, \"lost\"]"]))
GARBAGE = st.sampled_from([
    "UPDATE settings SET value=? WHERE key='calibration'", "UPDATE settings SET value=? WHERE key='board'",
    "UPDATE meta SET value=? WHERE key='schema_version'", "INSERT INTO points VALUES (?, 'side', 1, ?, ?, ?, 0, 0, 0)",
    "UPDATE points SET status=? WHERE frame < 5", "UPDATE points SET x_px=?", "UPDATE edit_rows SET before=?",
    "UPDATE edit_rows SET after=?", "UPDATE edit_rows SET key=?", "UPDATE edits SET undone=?",
    "INSERT INTO videos VALUES (?, ?, ?, ?, ?, ?, ?)", "UPDATE markers SET label=?", "DROP TABLE points",
    "DROP TABLE edit_rows", "DROP TABLE videos", "DROP TABLE settings", "ALTER TABLE videos DROP COLUMN frames",
    "DELETE FROM meta"])


@FUZZ
@given(changes=st.lists(st.tuples(GARBAGE, st.lists(SQL_VALUES, min_size=7, max_size=7)), min_size=1, max_size=4))
def test_fuzz_wrong_schema_and_garbage_rows(scratch, changes):
    path = fresh(scratch, "garbage.sandtrack")
    write(path, project_bytes())
    with closing(sqlite3.connect(path)) as conn:
        for sql, values in changes:
            with suppress(sqlite3.Error):  # e.g. the table was dropped by an earlier change
                conn.execute(sql, values[: sql.count("?")])
        conn.commit()
    use_project(path)
    shutil.rmtree(path.parent)


# -- the same bad files through the CLI ----------------------------------------------------------
def _bad_files(folder: Path) -> dict[str, Path]:
    files = {
        "board.toml": "columns = inf\nrows = 5\nsquare_size_override_cm = 2.5\n",
        "camera_array.toml": '[cameras."²"]\nrotation = [[1e300, 0, 0], [0, 1, 0], [0, 0, 1]]\n'
                             'translation = [0, 0, 0]\nmatrix = [[900, 0, 960], [0, 900, 540], [0, 0, 1]]\n'
                             'size = [1920, 1080]\n',
        "calibration.toml": '[cameras."a\\nb"]\nsize = [1920, 1080]\nmatrix = [[nan, 0, 1], [0, 1, 1], [0, 0, 1]]\n',
        "known.csv": "xs,ys,xf,yf,X_mm,Y_mm,Z_mm\n" + "1,2,3,4,5,6,7\n" * 20,
        "points.csv": ",".join(POINT_COLUMNS) + "\n" + "1.5,1,1,1,1,1,1,1,1\n",
    }
    out = {}
    for name, text in files.items():
        out[name] = folder / name
        out[name].write_text(text)
    damaged = folder / "damaged.sandtrack"
    damaged.write_bytes(project_bytes()[: len(project_bytes()) // 2])
    out["damaged.sandtrack"] = damaged
    return out


CLI_CASES = [
    (["calibrate", "--import-caliscope", "{camera_array.toml}", "-o", "{out}"], "out"),
    (["calibrate", "--from-points", "{known.csv}", "-o", "{out}"], "out"),
    (["calibrate", "--calibration", "{calibration.toml}", "-o", "{out}"], "out"),
    (["train", "{points.csv}", "-o", "{out}"], "out"),
    (["track", "{damaged.sandtrack}", "--auto-seed"], None),
    (["xyz", "{damaged.sandtrack}", "-o", "{out}"], "out"),
    (["export", "{damaged.sandtrack}", "-o", "{out}"], "out"),
]


@pytest.mark.parametrize(("argv", "output"), CLI_CASES, ids=[" ".join(c[0][:2]) for c in CLI_CASES])
def test_cli_bad_files_one_line_and_nothing_written(tmp_path, capsys, argv, output):
    files = {k: str(v) for k, v in _bad_files(tmp_path).items()}
    files["out"] = str(tmp_path / "out.file")
    args = [files[a[1:-1]] if a.startswith("{") else a for a in argv]
    assert main(args) == 1
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert "Traceback" not in err and len([ln for ln in lines if "error:" in ln]) == 1, err
    if output:
        assert not (tmp_path / "out.file").exists()


def test_new_with_bad_board_writes_no_project(tmp_path, capsys):
    from conftest import write_clip

    clip = write_clip(tmp_path / "side.mp4", n_frames=3)
    files = _bad_files(tmp_path)
    assert main(["new", str(tmp_path / "e.sandtrack"), "--side", str(clip), "--board", str(files["board.toml"])]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and "board" in err
    assert not (tmp_path / "e.sandtrack").exists()


def _open_descriptors() -> int:
    return len(os.listdir("/proc/self/fd"))


def _damaged_variants(real: bytes, count: int):
    """`count` damaged copies of a real project: cut short, bytes flipped, schema rows changed, random pages."""
    rng = np.random.default_rng(5)
    schema_edits = ["UPDATE meta SET value='999' WHERE key='schema_version'", "DELETE FROM meta",
                    "UPDATE meta SET value='x' WHERE key='schema_version'", "DROP TABLE meta",
                    "UPDATE meta SET value='0' WHERE key='schema_version'"]
    for i in range(count):
        kind = i % 4
        if kind == 0:
            yield real[: int(rng.integers(17, len(real)))], None
        elif kind == 1:
            data = bytearray(real)
            for pos in rng.integers(100, len(real), int(rng.integers(1, 40))):
                data[pos] = int(rng.integers(0, 256))
            yield bytes(data), None
        elif kind == 2:
            yield real, schema_edits[(i // 4) % len(schema_edits)]
        else:
            yield b"SQLite format 3\x00" + rng.bytes(int(rng.integers(0, 5000))), None


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="needs /proc/self/fd to count open descriptors")
def test_a_thousand_damaged_projects_leave_no_descriptor_open(tmp_path):
    """Project.open closes its connection on every failure path: 1,000 failed or used opens in one process leave
    the process's open descriptors where they were."""
    real = project_bytes()
    use_project(fresh(tmp_path, "warm-up.sandtrack"))  # imports and caches made before counting
    before = _open_descriptors()
    refused = 0
    for k, (data, sql) in enumerate(_damaged_variants(real, 1000)):
        path = tmp_path / f"{k}.sandtrack"
        path.write_bytes(data)
        if sql:
            with closing(sqlite3.connect(path)) as conn:
                conn.execute(sql)
                conn.commit()
        try:
            Project.open(path).close()
        except SandtrackError as exc:
            assert "\n" not in str(exc)
            refused += 1
    assert refused >= 500  # most variants are refused: the failure paths are what this counts
    assert _open_descriptors() == before
