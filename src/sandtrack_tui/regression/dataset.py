"""Calibration points (`points.csv`) and the split by frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from ..errors import SandtrackError

POINT_COLUMNS = ["frame", "corner_id", "xs", "ys", "xf", "yf", "X_mm", "Y_mm", "Z_mm"]
INPUTS = ["xs", "ys", "xf", "yf"]
TARGETS = ["X_mm", "Y_mm", "Z_mm"]


def load_points(path: str | Path) -> pd.DataFrame:
    """Read and check a points.csv; rows with a missing value are dropped."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"points file not found: {p}")
    try:
        df = pd.read_csv(p)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise SandtrackError(f"{p}: not a readable CSV ({first})") from None
    except OSError as exc:
        raise SandtrackError(f"cannot read {p}: {exc.strerror}") from None
    return check_points(df, str(p))


def check_points(df: pd.DataFrame, source: str = "points") -> pd.DataFrame:
    missing = [c for c in POINT_COLUMNS if c not in df.columns]
    if missing:
        raise SandtrackError(f"{source}: missing column(s) {', '.join(missing)} "
                             f"(expected {', '.join(POINT_COLUMNS)})")
    out = df[POINT_COLUMNS].apply(pd.to_numeric, errors="coerce")
    values = out.to_numpy(dtype=float)
    ok = np.isfinite(values).all(axis=1) & (np.abs(values[:, 0]) < 2**53)
    out = out[ok].reset_index(drop=True)
    if len(out) == 0:
        raise SandtrackError(f"{source}: no complete rows")
    frame = out["frame"].to_numpy(dtype=float)
    if ((frame % 1 != 0) | (np.abs(frame) > 2 ** 53)).any():
        raise SandtrackError(f"{source}: frame must be a whole number on every row")
    out["frame"] = out["frame"].astype(np.int64)
    return out


def split_by_frame(frames: np.ndarray, val_frac: float = 0.15, test_frac: float = 0.15,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boolean masks (train, val, test) over rows, assigning whole frames (board poses) to one
    set, so corners of one pose never sit on both sides of the split."""
    frames = np.asarray(frames)
    unique = np.unique(frames)
    if len(unique) < 3:
        raise SandtrackError(f"need calibration points from at least 3 frames (board poses), got {len(unique)}")
    order = np.random.default_rng(seed).permutation(unique)
    n_test = max(1, int(round(test_frac * len(unique))))
    n_val = max(1, int(round(val_frac * len(unique))))
    test_f, val_f = order[:n_test], order[n_test:n_test + n_val]
    test = np.isin(frames, test_f)
    val = np.isin(frames, val_f)
    return ~(test | val), val, test
