"""Trajectory export (tidy CSV, Parquet, DLTdv/Argus CSVs) and pixel-track import (DaVinci Resolve, DLTdv).

Export
    The tidy table has one row per frame of the first camera (the reference: side in a side/front
    project), marker and method: ``frame, time_s, marker``, ``status_<camera>`` for each camera,
    each camera's pixels (``xs, ys`` side, ``xf, yf`` front, ``x_<camera>, y_<camera>`` any other),
    ``X_mm, Y_mm, Z_mm``, their 1-sigma ``sd_X_mm, sd_Y_mm, sd_Z_mm``, ``method, residual_px``,
    ``xyz_source`` ("interpolated", or "nearest_frame" where a camera had only one of the two frames
    around the reference time), ``calibrated_region`` ("outside" where a camera's pixel lies beyond the
    image region its calibration covered, "inside", "" not known), ``network_check`` (the MLP rows' check
    against triangulation: "ok", "inconsistent", "unchecked") and ``bias_X_mm, bias_Y_mm, bias_Z_mm``
    (a checked MLP row's error as the triangulation measures it) (see `xyz.py`: the other cameras' tracks are
    interpolated to the reference frame's time through the sync offset; pixels in the OpenCV
    convention, origin at the top-left pixel's centre, y down).

    Pixels always leave: where no method gives millimetres (one camera without a scale, cameras
    without a calibration or network), `export_table` gives the pixel trajectories (method
    ``pixels``, the mm columns empty) and says why.

    DLTdv/Argus (``PREFIX-xypts.csv``, ``-xyzpts.csv``, ``-xyzres.csv``, ``-offsets.csv``): one row
    per reference frame (row 1 = frame 0), NaN where missing; ``ptN_camM_X/Y`` with camM = the M-th
    camera of the table (cam1 = side, cam2 = front in a side/front project), point N = the N-th
    marker (sorted by id); y is flipped to DLTdv's bottom-left origin (``y_dltdv = height - y_px``).
    The other cameras' columns are already resampled to the reference frames, so every camera
    offset is 0.

Import
    DaVinci Resolve / Fusion tracker export: ``frame, x, y``; normalised, origin bottom-left, y up.
    ``x_px = x * width - 0.5``; y either in image heights (point controls: ``y_px = (1 - y) *
    height - 0.5``) or in image widths (paths/polylines: 0-0.5625 for 16:9, ``y_px = height - y *
    width - 0.5``): the choice is explicit (``y_units``). DLTdv ``xypts``: the inverse of the export.
    Imported points get status "imported"; markers and points are written in ONE transaction and
    ONE undoable edit, after the whole file has been validated: a bad file changes nothing.
"""

from __future__ import annotations

import csv
import json
import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import SandtrackError
from .xyz import BIAS_COLUMNS, COV_COLUMNS, SD_COLUMNS, XYZ_COLUMNS, NoXYZ, pixel_columns, xyz_columns

TIDY_COLUMNS = XYZ_COLUMNS  # a side/front project's; others: xyz.xyz_columns(cameras)
FORMATS = ("csv", "parquet", "dltdv")
DEFAULT_HEIGHT = 1080  # px, for the DLTdv y flip of a camera whose image height is not given
MAX_ROWS = 50_000_000


# -- export ---------------------------------------------------------------------------------------
def trajectory_table(project, method: str = "both", covariance: bool = False) -> pd.DataFrame:
    """The project's tidy XYZ table (see module docstring), via `xyz.compute_xyz`; `covariance`: with the
    triangulation's covariances between the axes (``cov_XY_mm2, cov_XZ_mm2, cov_YZ_mm2`` after the sd)."""
    try:
        from .xyz import compute_xyz
    except ImportError:
        raise SandtrackError("3D positions are not available in this version yet (no xyz module)") from None
    df = compute_xyz(project, method=method, covariance=covariance)
    return check_tidy(df)


def export_table(project, method: str = "both", covariance: bool = False) -> tuple[pd.DataFrame, str | None]:
    """The table to export, and None, or, when no method can give millimetres and `method` is "both" or
    "all", the pixel trajectories (method "pixels", X_mm, Y_mm, Z_mm empty) and one line saying why."""
    try:
        return trajectory_table(project, method, covariance), None
    except NoXYZ as exc:
        if method not in ("both", "all"):
            raise
        from .xyz import compute_pixels

        why = f"pixel trajectories only (x, y in px; X_mm, Y_mm, Z_mm empty): {exc}"
        return check_tidy(compute_pixels(project)), why


def table_cameras(df: pd.DataFrame) -> list[str]:
    """The cameras of a tidy table, in its order (from its ``status_<camera>`` columns)."""
    return [c[len("status_"):] for c in df.columns if str(c).startswith("status_")]


def check_tidy(df: pd.DataFrame) -> pd.DataFrame:
    cameras = table_cameras(df)
    columns = xyz_columns(cameras, covariance=all(c in df.columns for c in COV_COLUMNS))
    absent_sd = [c for c in SD_COLUMNS if c not in df.columns]
    if absent_sd:  # a table made without uncertainties: unknown, not zero
        df = df.assign(**{c: np.nan for c in absent_sd})
    if "xyz_source" not in df.columns:  # a table from before nearest-frame rows: all interpolated
        df = df.assign(xyz_source="interpolated")
    if "network_check" not in df.columns:  # a table from before the network's check
        df = df.assign(network_check="")
    if "calibrated_region" not in df.columns:  # a table from before regions were kept: not known
        df = df.assign(calibrated_region="")
    absent_bias = [c for c in BIAS_COLUMNS if c not in df.columns]
    if absent_bias:  # a table from before the network's bias was kept
        df = df.assign(**{c: np.nan for c in absent_bias})
    missing = [c for c in columns if c not in df.columns] if cameras else ["status_<camera>"]
    if missing:
        raise SandtrackError(f"trajectory table lacks columns: {', '.join(missing)}")
    if df.empty:
        raise SandtrackError("nothing to export: no tracked points with 3D positions yet")
    return df[columns].sort_values(["method", "marker", "frame"], kind="stable").reset_index(drop=True)


def _atomic_write(path: Path, writer: Callable[[Path], None]) -> None:
    """Write through a temporary file in the same folder, then rename: never a half-written file."""
    path = Path(path)
    if not path.parent.exists():
        raise SandtrackError(f"folder does not exist: {path.parent}")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    os.close(fd)
    try:
        writer(Path(tmp))
        os.replace(tmp, path)
    except OSError as exc:
        raise SandtrackError(f"cannot write {path}: {exc.strerror or exc}") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_csv(df: pd.DataFrame, path: str | Path) -> Path:
    df = check_tidy(df)
    _atomic_write(Path(path), lambda p: df.to_csv(p, index=False, float_format="%.6f"))
    return Path(path)


def write_parquet(df: pd.DataFrame, path: str | Path) -> Path:
    df = check_tidy(df)
    _atomic_write(Path(path), lambda p: df.to_parquet(p, index=False))
    return Path(path)


def dltdv_tables(df: pd.DataFrame, heights: dict[str, float], method: str | None = None) -> dict[str, pd.DataFrame]:
    """The four DLTdv/Argus tables (xypts, xyzpts, xyzres, offsets) for one method."""
    df = check_tidy(df)
    methods = list(dict.fromkeys(df["method"]))
    if method is None:
        method = "triangulation" if "triangulation" in methods else methods[0]
    if method not in methods:
        raise SandtrackError(f"no rows with method {method!r} (have: {', '.join(map(str, methods))})")
    d = df[df["method"] == method]
    markers = sorted(int(m) for m in d["marker"].unique())
    n_rows = int(d["frame"].max()) + 1
    xy, xyz, res = {}, {}, {}
    cameras = table_cameras(d)
    for n, m in enumerate(markers, start=1):
        dm = d[d["marker"] == m]
        f = dm["frame"].to_numpy(int)
        cols = {}
        for k, cam in enumerate(cameras, start=1):
            cx, cy = pixel_columns(cam)
            x = np.full(n_rows, np.nan)
            y = np.full(n_rows, np.nan)
            x[f] = dm[cx].to_numpy(float)
            y[f] = heights.get(cam, DEFAULT_HEIGHT) - dm[cy].to_numpy(float)
            cols[f"pt{n}_cam{k}_X"] = x
            cols[f"pt{n}_cam{k}_Y"] = y
        xy.update(cols)
        for ax in "XYZ":
            v = np.full(n_rows, np.nan)
            v[f] = dm[f"{ax}_mm"].to_numpy(float)
            xyz[f"pt{n}_{ax}"] = v
        r = np.full(n_rows, np.nan)
        r[f] = dm["residual_px"].to_numpy(float)
        res[f"pt{n}_dltres"] = r
    offsets = pd.DataFrame({f"cam{k}_offset": np.zeros(n_rows, int) for k in range(1, len(cameras) + 1)})
    return {"xypts": pd.DataFrame(xy), "xyzpts": pd.DataFrame(xyz), "xyzres": pd.DataFrame(res),
            "offsets": offsets, "markers": pd.DataFrame({"point": range(1, len(markers) + 1), "marker": markers})}


def write_dltdv(df: pd.DataFrame, prefix: str | Path, heights: dict[str, float],
                method: str | None = None) -> list[Path]:
    """Write PREFIX-xypts.csv, -xyzpts.csv, -xyzres.csv, -offsets.csv (and -markers.csv: point -> marker id)."""
    prefix = Path(prefix)
    name = re.sub(r"(-xypts)?\.csv$", "", prefix.name)
    tables = dltdv_tables(df, heights, method)
    out = []
    for kind, table in tables.items():
        p = prefix.parent / f"{name}-{kind}.csv"
        _atomic_write(p, lambda tmp, t=table: t.to_csv(tmp, index=False, na_rep="NaN", float_format="%.6f"))
        out.append(p)
    return out


def export(df: pd.DataFrame, path: str | Path, fmt: str | None = None, heights: dict[str, float] | None = None,
           method: str | None = None) -> list[Path]:
    """Write the tidy table in `fmt` (csv, parquet, dltdv; default from the file suffix)."""
    path = Path(path)
    fmt = fmt or {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}.get(path.suffix.lower())
    if fmt not in FORMATS:
        raise SandtrackError(f"unknown export format for {path.name}: give --format ({', '.join(FORMATS)})")
    if method is not None and fmt != "dltdv":
        df = df[df["method"] == method]
    if fmt == "csv":
        return [write_csv(df, path)]
    if fmt == "parquet":
        return [write_parquet(df, path)]
    return write_dltdv(df, path, heights or {}, method)


# -- import: readers ------------------------------------------------------------------------------
def _read_table(path: str | Path, what: str) -> pd.DataFrame:
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"file not found: {p}")
    if p.stat().st_size == 0:
        raise SandtrackError(f"{p}: empty file")
    sep = _delimiter(p)
    try:
        df = pd.read_csv(p, sep=sep, engine="python", skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError, csv.Error) as exc:
        msg = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise SandtrackError(f"{p}: not a readable {what} CSV ({msg})") from None
    if df.empty:
        raise SandtrackError(f"{p}: no data rows")
    if len(df) > MAX_ROWS:
        raise SandtrackError(f"{p}: too many rows ({len(df)})")
    df.columns = [str(c).strip() for c in df.columns]
    return df


def _delimiter(p: Path) -> str:
    """Comma, semicolon or tab as found on the first non-empty line; otherwise runs of spaces."""
    try:
        with p.open("r", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if line.strip():
                    for sep in (",", ";", "\t"):
                        if sep in line:
                            return sep
                    return r"\s+"
    except OSError as exc:
        raise SandtrackError(f"cannot read {p}: {exc.strerror}") from None
    raise SandtrackError(f"{p}: no data rows")


def _numeric(df: pd.DataFrame, col: str, path) -> np.ndarray:
    v = pd.to_numeric(df[col], errors="coerce").to_numpy(float)
    bad = np.nonzero(~np.isfinite(v) & df[col].notna().to_numpy())[0]
    if len(bad):
        raise SandtrackError(f"{path}: column {col!r} row {bad[0] + 2}: {df[col].iloc[bad[0]]!r} is not a number")
    return v


def read_davinci(path: str | Path, width: int, height: int, y_units: str = "height",
                 frame_offset: int = 0) -> pd.DataFrame:
    """A DaVinci Resolve/Fusion tracker export (frame, x, y normalised, origin bottom-left) ->
    DataFrame[frame, x_px, y_px] in OpenCV pixels. `frame_offset` is subtracted from the frame numbers."""
    if y_units not in ("height", "width"):
        raise SandtrackError(f"y units must be 'height' or 'width', not {y_units!r}")
    df = _read_table(path, "DaVinci tracker")
    lower = {c.lower(): c for c in df.columns}
    if not {"frame", "x", "y"} <= set(lower):
        if len(df.columns) == 3 and all(_is_number(c) for c in df.columns):  # no header line
            try:
                df = pd.read_csv(path, sep=_delimiter(Path(path)), engine="python", header=None,
                                 names=["frame", "x", "y"])
            except (pd.errors.ParserError, ValueError, csv.Error) as exc:
                msg = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
                raise SandtrackError(f"{path}: not a readable DaVinci tracker CSV ({msg})") from None
            lower = {"frame": "frame", "x": "x", "y": "y"}
        else:
            raise SandtrackError(f"{path}: expected columns frame, x, y (found: {', '.join(df.columns[:8])})")
    frame = _numeric(df, lower["frame"], path)
    x = _numeric(df, lower["x"], path)
    y = _numeric(df, lower["y"], path)
    if np.isnan(frame).any():
        raise SandtrackError(f"{path}: a frame number is missing (row {int(np.argmax(np.isnan(frame))) + 2})")
    nan_xy = np.isnan(x) | np.isnan(y)
    if nan_xy.all():
        raise SandtrackError(f"{path}: no row has both x and y")
    if np.any(np.abs(frame - np.round(frame)) > 1e-6):
        raise SandtrackError(f"{path}: frame numbers must be whole numbers")
    ok = ~nan_xy
    y_max = 1.0 if y_units == "height" else height / width
    for name, v, hi in (("x", x[ok], 1.0), ("y", y[ok], y_max)):
        if v.min() < -0.5 * hi or v.max() > 1.5 * hi:
            hint = " (these look like pixels, not normalised 0-1 values)" if np.abs(v).max() > 2 else ""
            if not hint and name == "y" and y_units == "width":
                hint = " (y looks like image-height units: use y units 'height')"
            raise SandtrackError(f"{path}: {name} values {v.min():.4g}..{v.max():.4g} are outside the image "
                                 f"(normalised 0..{hi:.4g}){hint}")
    frames = np.round(frame[ok]).astype(np.int64) - int(frame_offset)
    xp = x[ok] * width - 0.5
    yp = (1.0 - y[ok]) * height - 0.5 if y_units == "height" else height - y[ok] * width - 0.5
    out = pd.DataFrame({"frame": frames, "x_px": xp, "y_px": yp})
    if out["frame"].duplicated().any():
        raise SandtrackError(f"{path}: frame {int(out['frame'][out['frame'].duplicated()].iloc[0])} appears twice")
    return out


def _is_number(s) -> bool:
    try:
        float(s)
        return True
    except (TypeError, ValueError):
        return False


_XY_COL = re.compile(r"^pt(\d+)_cam(\d+)_([XY])$", re.IGNORECASE)


def read_dltdv_xypts(path: str | Path, heights: dict[str, float], cameras: tuple[str, ...] = ("side", "front"),
                     flip_y: bool = True, first_frame: int = 0) -> pd.DataFrame:
    """A DLTdv/Argus ``xypts`` CSV -> DataFrame[frame, camera, point, x_px, y_px] (missing points dropped).
    camM -> cameras[M-1]; row r (0-based) -> frame first_frame + r; y flipped from the bottom-left origin."""
    df = _read_table(path, "DLTdv xypts")
    parsed = {}
    for c in df.columns:
        m = _XY_COL.match(c)
        if not m:
            raise SandtrackError(f"{path}: unexpected column {c!r} (DLTdv xypts columns look like pt1_cam1_X)")
        parsed[c] = (int(m.group(1)), int(m.group(2)), m.group(3).upper())
    keys = {(p, cam) for p, cam, _ in parsed.values()}
    rows = []
    for p, cam in sorted(keys):
        if cam < 1 or cam > len(cameras):
            raise SandtrackError(f"{path}: camera {cam} in the file but only {len(cameras)} camera name(s) given")
        cx = next((c for c, v in parsed.items() if v == (p, cam, "X")), None)
        cy = next((c for c, v in parsed.items() if v == (p, cam, "Y")), None)
        if cx is None or cy is None:
            raise SandtrackError(f"{path}: point {p} camera {cam} lacks its {'X' if cx is None else 'Y'} column")
        x = _numeric(df, cx, path)
        y = _numeric(df, cy, path)
        half = np.isnan(x) != np.isnan(y)
        if half.any():
            raise SandtrackError(f"{path}: row {int(np.argmax(half)) + 2}: pt{p}_cam{cam} has X or Y but not both")
        ok = ~np.isnan(x)
        name = cameras[cam - 1]
        yy = heights[name] - y[ok] if flip_y else y[ok]
        rows.append(pd.DataFrame({"frame": np.nonzero(ok)[0] + first_frame, "camera": name, "point": p,
                                  "x_px": x[ok], "y_px": yy}))
    out = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame()
    if out.empty:
        raise SandtrackError(f"{path}: no digitised points (all NaN)")
    return out


# -- import: into the project -------------------------------------------------------------------
def import_points(project, rows: pd.DataFrame, description: str, labels: dict[int, str] | None = None) -> dict:
    """Validate rows [frame, camera, marker, x_px, y_px] against the project's videos, then write them
    (status "imported") and any new markers in one transaction = one undoable edit.
    Returns {"points": n, "markers": [ids], "new_markers": [ids], "cameras": [...]}."""
    from .store import POINT_COLUMNS

    if rows.empty:
        raise SandtrackError("nothing to import")
    vids = project.videos()
    for cam in rows["camera"].unique():
        if cam not in vids:
            raise SandtrackError(f"the project has no {cam!r} camera (has: {', '.join(vids) or 'none'})")
        ref = vids[cam]
        r = rows[rows["camera"] == cam]
        f = r["frame"].to_numpy()
        if f.min() < 0 or f.max() >= ref.frames:
            raise SandtrackError(f"{cam}: frame numbers {int(f.min())}..{int(f.max())} outside the video "
                                 f"(0..{ref.frames - 1}); check the first frame / frame offset")
        for col, size in (("x_px", ref.width), ("y_px", ref.height)):
            v = r[col].to_numpy(float)
            if not np.isfinite(v).all():
                raise SandtrackError(f"{cam}: {col} holds values that are not finite numbers")
            if v.min() < -0.5 * size or v.max() > 1.5 * size:
                raise SandtrackError(f"{cam}: {col} {v.min():.6g}..{v.max():.6g} is far outside the "
                                     f"{ref.width}x{ref.height} image (wrong units or y convention?)")
    if rows.duplicated(["frame", "camera", "marker"]).any():
        raise SandtrackError("the file gives the same marker twice in one frame")
    existing = set(int(m) for m in project.markers()["id"])
    markers = sorted(int(m) for m in rows["marker"].unique())
    new = [m for m in markers if m not in existing]
    records = [(int(f), str(c), int(m), float(x), float(y), "imported", None, None, None)
               for f, c, m, x, y in rows[["frame", "camera", "marker", "x_px", "y_px"]].itertuples(index=False)]
    conn = project.conn
    value_cols = POINT_COLUMNS[3:]

    def fn():
        eid = project._new_edit("import", description)
        seq = 0
        for m in new:
            label = (labels or {}).get(m, str(m))
            project._log_row(eid, seq, "markers", str(m), None, json.dumps(label))
            conn.execute("INSERT OR REPLACE INTO markers VALUES (?, ?)", (m, label))
            seq += 1
        for rec in records:
            old = conn.execute(f"SELECT {', '.join(value_cols)} FROM points WHERE frame=? AND camera=? AND marker=?",
                               rec[:3]).fetchone()
            project._log_row(eid, seq, "points", json.dumps(list(rec[:3])), json.dumps(list(old)) if old else None,
                             json.dumps(list(rec[3:])))
            seq += 1
        conn.executemany(f"INSERT OR REPLACE INTO points ({', '.join(POINT_COLUMNS)}) VALUES (?,?,?,?,?,?,?,?,?)",
                         records)

    project._write(fn)
    return {"points": len(records), "markers": markers, "new_markers": new,
            "cameras": sorted(rows["camera"].unique().tolist())}


def preview_image(frame_bgr: np.ndarray, points: pd.DataFrame, frame_index: int | None = None) -> np.ndarray:
    """The frame with imported points drawn (the current frame's point as a ring, the path as a line),
    to confirm the coordinate convention (y units, origin) before trusting an import."""
    import cv2

    img = frame_bgr.copy()
    pts = points[["x_px", "y_px"]].to_numpy(float)
    if len(pts) > 1:
        cv2.polylines(img, [np.round(pts).astype(np.int32).reshape(-1, 1, 2)], False, (0, 255, 255), 1, cv2.LINE_AA)
    if frame_index is not None:
        cur = points[points["frame"] == frame_index]
        for x, y in cur[["x_px", "y_px"]].to_numpy(float):
            cv2.circle(img, (int(round(x)), int(round(y))), 12, (0, 0, 255), 2, cv2.LINE_AA)
    return img
