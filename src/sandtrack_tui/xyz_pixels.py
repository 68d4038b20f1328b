"""World XYZ (mm) of any table of pixels: `sandtrack xyz PIXELS.csv`.

A pixels table has one row per point and the pixels of each camera in two columns: ``xs, ys``
(side) and ``xf, yf`` (front), or ``x_NAME, y_NAME`` for a camera NAME of the calibration, any number
of cameras, NaN (an empty field) where a camera did not see the point. Every other column is passed
through. The result adds ``X_mm, Y_mm, Z_mm, sd_X_mm, sd_Y_mm, sd_Z_mm, method, residual_px,
calibrated_region, network_check, bias_X_mm, bias_Y_mm, bias_Z_mm`` (see `xyz.py` for their meaning);
with several methods each input row appears once per method, in input order. Triangulation uses every
camera that saw a point (two or more); the network and its residual variant read the side and front
pixels, as they were trained.

Each pixel's sd (px, 1 sigma) may be given: ``sd_px`` for every camera, ``sd_px_NAME`` for camera NAME
(side, front or any other); an empty field or no column: the camera's calibration RMSE.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .errors import SandtrackError
from .xyz import (
    BIAS_COLUMNS,
    COV_COLUMNS,
    NETWORK_CAMERAS,
    SD_COLUMNS,
    check_choices,
    network_rows,
    pixel_columns,
    pixel_sd,
    resolve_methods,
    wanted_methods,
)

RESULT_COLUMNS = ["X_mm", "Y_mm", "Z_mm", *SD_COLUMNS, "method", "residual_px", "calibrated_region", "network_check",
                  *BIAS_COLUMNS]
COMMAND_LINE_NEEDS = {
    "calibration": "triangulation needs --calibration CAL.toml",
    "model": "the {method} method needs --model MODEL.pt (sandtrack train)",
    "nothing": "nothing to compute XYZ with: give --calibration CAL.toml and/or --model MODEL.pt",
}


def camera_columns(columns) -> dict[str, tuple[str, str]]:
    """{camera: (x column, y column)}: xs/ys = side, xf/yf = front, x_NAME/y_NAME = NAME."""
    cols = set(columns)
    cams = {n: pixel_columns(n) for n in NETWORK_CAMERAS if set(pixel_columns(n)) <= cols}
    for c in columns:
        if c.startswith("x_") and len(c) > 2 and f"y_{c[2:]}" in cols and c[2:] not in cams:
            cams[c[2:]] = (c, f"y_{c[2:]}")
    return cams


def read_pixels(path: str | Path) -> tuple[pd.DataFrame, dict[str, tuple[str, str]]]:
    """The table and its camera columns; pixel columns as floats (text, inf -> NaN)."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"pixels file not found: {p}")
    try:
        df = pd.read_csv(p, engine="pyarrow")
    except Exception as exc:  # pyarrow raises its own error types for malformed CSV
        try:
            df = pd.read_csv(p)
        except (pd.errors.ParserError, UnicodeDecodeError, pd.errors.EmptyDataError, ValueError):
            raise SandtrackError(f"{p}: not a readable CSV ({str(exc).strip().splitlines()[0]})") from None
    df.columns = [str(c) for c in df.columns]
    cams = camera_columns(df.columns)
    if not cams:
        raise SandtrackError(f"{p}: no pixel columns (xs, ys / xf, yf, or x_NAME, y_NAME for each camera)")
    for xy in cams.values():
        for c in xy:
            v = pd.to_numeric(df[c], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
            df[c] = np.where(np.isfinite(v), v, np.nan)
    return df, cams


def xyz_from_pixels(df: pd.DataFrame, cams: dict[str, tuple[str, str]], calibration=None, model=None,
                    method: str = "both", outside: str = "flag", refine: bool = True,
                    covariance: bool = False) -> tuple[pd.DataFrame, list[str]]:
    """The table with XYZ by each method, and notes for the user (renamed columns); `covariance`: the
    triangulated rows' covariances between the axes after the sd (COV_COLUMNS; NaN on the other rows)."""
    check_choices(method, outside)
    from .triangulation_sd import pixel_sd_axes, sd_holds
    from .xyz import check_network_rows, triangulate_with_sd

    if calibration is not None and "triangulation" in wanted_methods(method):
        unknown = [c for c in cams if c not in calibration.cameras]
        if unknown:
            raise SandtrackError(
                f"the pixels name camera(s) {', '.join(unknown)} that the calibration does not have "
                f"({', '.join(calibration.names)}); name the columns x_NAME, y_NAME after its cameras")
    methods = resolve_methods(method, calibration, model, cams, COMMAND_LINE_NEEDS)
    notes = []
    clash = [c for c in (*RESULT_COLUMNS, *(COV_COLUMNS if covariance else ())) if c in df.columns]
    base = df
    if clash:
        base = df.rename(columns={c: f"{c}_input" for c in clash})
        notes.append(f"input columns {', '.join(clash)} are kept as {', '.join(c + '_input' for c in clash)}")
    pix = {n: df[list(xy)].to_numpy(float) for n, xy in cams.items()}
    n = len(df)
    psd = {c: pixel_sd(given_sd(df, c), np.zeros(n), calibration, c) for c in cams} \
        if set(methods) - {"triangulation"} else {}
    blocks, tri = [], None
    tri_cams = [c for c in pix if calibration is not None and c in calibration.cameras]
    tsd = {c: pixel_sd_axes(given_sd(df, c), np.zeros(n), calibration, c) for c in tri_cams}
    if "triangulation" in methods:
        given = any(np.isfinite(given_sd(df, c)).any() for c in tri_cams)
        own = ("each row's sd_px (else its camera's noise)",) if given else ()
        notes.append(sd_holds(calibration, tri_cams, *own))
    if "mlp" in methods and len(tri_cams) < 2:
        notes.append("the MLP's sd is its spread alone: no triangulation to check it against "
                     "(--calibration with two of the table's cameras)")
    from .calibration.region import LABELS, outside_note, region_codes

    region = pd.Categorical.from_codes(region_codes(calibration, pix, n), LABELS)
    for m in methods:
        bias, cov = np.full((n, 3), np.nan), np.full((n, 3), np.nan) if covariance else None
        if m == "triangulation" and n:
            used = {c: pix[c] for c in tri_cams}
            xyz, res, sd = triangulate_with_sd(calibration, used, {c: tsd[c] for c in used}, refine, covariance)
            if covariance:
                sd, cov = sd[:, :3], sd[:, 3:]
        else:
            xyz, res, sd = np.full((n, 3), np.nan), np.full(n, np.nan), np.full((n, 3), np.nan)
        if m == "triangulation":
            tri = (xyz, sd)
            # one label for every row: as categories, not a million strings (written alike)
            label = pd.Categorical.from_codes(np.zeros(n, np.int8), [m])
            check = pd.Categorical.from_codes(np.zeros(n, np.int8), [""])
        else:
            label, check = np.full(n, m, dtype=object), np.full(n, "", dtype=object)
            network_rows(m, model, calibration, np.hstack([pix[c] for c in NETWORK_CAMERAS]), outside, xyz, res,
                         label, sd, np.repeat(np.stack([psd[c] for c in NETWORK_CAMERAS], axis=1), 2, axis=1))
            if m == "mlp":
                check, bias = check_network_rows(calibration, {c: pix[c] for c in tri_cams}, tsd, refine, xyz, sd,
                                                 tri)
        added = {"X_mm": xyz[:, 0], "Y_mm": xyz[:, 1], "Z_mm": xyz[:, 2],
                 **{c: sd[:, k] for k, c in enumerate(SD_COLUMNS)},
                 **({c: cov[:, k] for k, c in enumerate(COV_COLUMNS)} if covariance else {}),
                 "method": label, "residual_px": res,
                 "calibrated_region": region, "network_check": check,
                 **{c: bias[:, k] for k, c in enumerate(BIAS_COLUMNS)}}
        blocks.append(pd.concat([base.reset_index(drop=True), pd.DataFrame(added)], axis=1))
    if (note := outside_note(blocks[0])) is not None:
        notes.append(note)
    if len(blocks) == 1:
        return blocks[0].reset_index(drop=True), notes
    table = pd.concat(blocks, ignore_index=True)
    order = np.argsort(np.tile(np.arange(n), len(blocks)), kind="stable")
    return table.iloc[order].reset_index(drop=True), notes


def given_sd(df: pd.DataFrame, camera: str) -> np.ndarray:
    """The pixel sd (px) the table gives for a camera (``sd_px_NAME``, else ``sd_px``); NaN where none."""
    for col in (f"sd_px_{camera}", "sd_px"):
        if col in df.columns:
            v = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
            return np.where(np.isfinite(v) & (v >= 0), v, np.nan)
    return np.full(len(df), np.nan)


def write_table(table: pd.DataFrame, path: str | Path | None) -> None:
    """CSV with XYZ and residuals rounded to 0.1 um / 0.0001 px; to stdout when path is None.

    Written by pyarrow, the two halves of the rows formatted in parallel (1 M rows: 0.5 s of wall
    time on two cores; pandas' own writer took several seconds)."""
    import sys
    from concurrent.futures import ThreadPoolExecutor

    import pyarrow as pa
    import pyarrow.csv as pacsv

    out = table.assign(**{c: table[c].round(4) for c in ("X_mm", "Y_mm", "Z_mm", *SD_COLUMNS, "residual_px")})
    out = out.assign(**{c: table[c].round(6) for c in COV_COLUMNS if c in table.columns})  # mm²: to 1e-6
    for c in out.columns:
        if out[c].dtype == object:  # mixed text columns: as text
            out[c] = out[c].astype("string")
    data = pa.Table.from_pandas(out, preserve_index=False)
    half = (data.num_rows + 1) // 2
    parts = [data.slice(0, half), data.slice(half)]

    def encode(k: int) -> bytes:
        buf = pa.BufferOutputStream()
        options = pacsv.WriteOptions(include_header=k == 0, quoting_style="needed")
        pacsv.write_csv(parts[k], buf, write_options=options)
        return buf.getvalue().to_pybytes()

    try:
        with ThreadPoolExecutor(max_workers=2) as pool:
            chunks = list(pool.map(encode, range(2)))
        if path is None:
            for chunk in chunks:
                sys.stdout.buffer.write(chunk)
            sys.stdout.buffer.flush()
        else:
            with open(path, "wb") as fh:
                for chunk in chunks:
                    fh.write(chunk)
    except (OSError, pa.ArrowException) as exc:
        raise SandtrackError(f"cannot write {path or 'the table'}: {exc}") from None
