"""Measured (experiment) versus simulated (DEM) particle trajectories.

Inputs: experiment ``marker, time_s, X_mm, Y_mm, Z_mm`` and DEM ``particle_id, time_s, X_mm,
Y_mm, Z_mm`` (see `dem`), both in the rig's world frame. Experiment rows where a camera's status
(``status_<camera>`` of an exported table) is "occluded" or "lost" are left out: their XYZ is built on
the tracker's prediction while the marker was hidden, not on a measurement.

Matching
    "id": marker id = particle id; "nearest": by initial positions (Hungarian assignment on the
    first positions, pairs farther than `max_match_mm` dropped); "auto": id when every marker has a
    particle of the same id, else nearest.

Time alignment
    ``time_shift_s`` = experiment time - DEM time of the same instant (DEM time t shows the state
    seen at experiment time t + shift). First from the motion onset: the tool's onset when tool
    tracks are given (first time it has moved `onset_mm` from its start), else the median over
    matched particles of the difference of their onsets (first time a particle is `onset_mm` from
    its start). Then the shift minimising the RMSE over all matched particles is searched within
    +-`max_lag_s` of that start (grid of one frame, a parabola through the minimum, then a tenth-of-a-frame pass); when
    particles get flagged (below), the shift is searched again without them, so a drifting
    particle cannot pull the alignment towards itself.

Metrics per particle (on the experiment's samples within the common time span, DEM linearly
interpolated): RMSE in 3D and per axis, final position error (at the last common sample), discrete
Fréchet distance, normalised DTW, maximum deviation, error drift (slope of the 3D error over time,
mm/s). A particle is flagged when its RMSE or its drift is an outlier among the particles (above
the median + 4 robust sigmas) and its RMSE exceeds `flag_mm`.

Consistency in units of the measurement's error (`consistency`): when the experiment carries
``sd_X_mm, sd_Y_mm, sd_Z_mm`` (and optionally ``cov_XY_mm2, cov_XZ_mm2, cov_YZ_mm2``), or `exp_sd_mm`
stands in for them, each sample's difference is weighed against the combined covariance (the
experiment's plus `dem_sd_mm`² per axis): χ² per particle and per run with effective degrees of freedom
(the time-shift fit and the samples' correlation along a trajectory accounted for), its p-value, the
share of samples within the 95 % band, and a verdict per run: consistent when p >= `alpha`. Rows whose
sd is NaN (e.g. a network's XYZ outside its training volume) count in the RMSE but not in the χ². A row
with ``bias_X_mm, bias_Y_mm, bias_Z_mm`` (a network's error as the triangulation measured it,
`regression.check`) has an error that is not centred: its sd states the 95 % interval around its XYZ, and
the χ² takes the Gaussian it came from (mean the bias, sd by `interval.gaussian_sd`); the RMSE and the
distances stay those of the XYZ as given; the time alignment (onsets and RMSE) takes the best estimate, XYZ
less the bias.
Without sd columns and without `exp_sd_mm` the χ² part is not computed, and the summary says why.

DTW, pinned here: Euclidean local cost d(i, j); step pattern "symmetric2": D(i, j) = min(D(i-1, j)
+ d, D(i, j-1) + d, D(i-1, j-1) + 2 d), D(0, 0) = 2 d(0, 0), no window; normalised DTW = D(n-1,
m-1) / (n + m), a weighted mean distance in mm (every path has total weight n + m).
Discrete Fréchet (Eiter & Mannila 1994): F(i, j) = max(d(i, j), min(F(i-1, j), F(i, j-1),
F(i-1, j-1))). Both are computed by anti-diagonals (vectorised).
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from . import consistency as K
from .errors import SandtrackError
from .interval import gaussian_sd
from .xyz import BIAS_COLUMNS, COV_COLUMNS, SD_COLUMNS

AXES = ("X_mm", "Y_mm", "Z_mm")
CHI2_KEYS = ("chi2_reduced", "p_value", "within_95_pct", "samples_eff")
UNOBSERVED = ("occluded", "lost")  # point statuses whose pixel is a prediction, not a measurement
METRICS = ["rmse_3d_mm", "rmse_x_mm", "rmse_y_mm", "rmse_z_mm", "final_error_mm", "frechet_mm", "dtw_norm_mm",
           "max_dev_mm", "drift_mm_per_s"]


# -- distances ------------------------------------------------------------------------------------
def _cost(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=2))


def _antidiagonal_dp(d: np.ndarray, combine) -> np.ndarray:
    """DP over anti-diagonals for a batch of cost matrices d (B, n, m):
    combine(d_cells, up, left, diag) -> values; diag is None for the first cell. Returns (B,)."""
    _, n, m = d.shape
    prev2 = None  # diagonal k-2, indexed by row i
    prev1 = None  # diagonal k-1
    for k in range(n + m - 1):
        i = np.arange(max(0, k - m + 1), min(n, k + 1))
        j = k - i
        dc = d[:, i, j]
        if k == 0:
            prev2, prev1 = prev1, combine(dc, None, None, None)
            continue
        shape = dc.shape
        up = np.full(shape, np.inf)  # (i-1, j): diagonal k-1, row i-1
        left = np.full(shape, np.inf)  # (i, j-1): diagonal k-1, row i
        diag = np.full(shape, np.inf)  # (i-1, j-1): diagonal k-2, row i-1
        p0 = max(0, k - m)
        ok = (i - 1 >= p0) & (i - 1 < p0 + prev1.shape[1])
        up[:, ok] = prev1[:, i[ok] - 1 - p0]
        ok = (i >= p0) & (i < p0 + prev1.shape[1]) & (j >= 1)
        left[:, ok] = prev1[:, i[ok] - p0]
        if prev2 is not None:
            q0 = max(0, k - 1 - m)
            ok = (i - 1 >= q0) & (i - 1 < q0 + prev2.shape[1]) & (j >= 1)
            diag[:, ok] = prev2[:, i[ok] - 1 - q0]
        prev2, prev1 = prev1, combine(dc, up, left, diag)
    return prev1[:, -1]


def _dtw_combine(dc, up, left, diag):
    if diag is None:
        return 2 * dc
    return np.minimum(np.minimum(up, left) + dc, diag + 2 * dc)


def _frechet_combine(dc, up, left, diag):
    if diag is None:
        return dc
    return np.maximum(dc, np.minimum(np.minimum(up, left), diag))


def dtw_normalised(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised DTW (symmetric2, Euclidean; see module docstring), mm."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) == 0 or len(b) == 0:
        return float("nan")
    return float(_antidiagonal_dp(_cost(a, b)[None], _dtw_combine)[0]) / (len(a) + len(b))


def discrete_frechet(a: np.ndarray, b: np.ndarray) -> float:
    """Discrete Fréchet distance (Eiter & Mannila), mm."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) == 0 or len(b) == 0:
        return float("nan")
    return float(_antidiagonal_dp(_cost(a, b)[None], _frechet_combine)[0])


def _batch_distances(pairs: list[tuple[np.ndarray, np.ndarray]]) -> list[tuple[float, float]]:
    """(Fréchet, normalised DTW) for many pairs; pairs of equal lengths share one DP pass."""
    out: list[tuple[float, float] | None] = [None] * len(pairs)
    groups: dict[tuple[int, int], list[int]] = {}
    for k, (a, b) in enumerate(pairs):
        groups.setdefault((len(a), len(b)), []).append(k)
    for (n, m), idx in groups.items():
        if n == 0 or m == 0:
            for k in idx:
                out[k] = (float("nan"), float("nan"))
            continue
        d = np.stack([_cost(pairs[k][0], pairs[k][1]) for k in idx])
        fr = _antidiagonal_dp(d, _frechet_combine)
        dt = _antidiagonal_dp(d, _dtw_combine) / (n + m)
        for q, k in enumerate(idx):
            out[k] = (float(fr[q]), float(dt[q]))
    return out  # type: ignore[return-value]


# -- inputs ---------------------------------------------------------------------------------------
def read_experiment(path: str | Path, method: str | None = None) -> pd.DataFrame:
    """Experiment trajectories from a project (via xyz.compute_xyz) or a CSV/Parquet with columns
    marker, time_s, X_mm, Y_mm, Z_mm (an exported tidy table; `method` picks one if several)."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"file not found: {p}")
    with p.open("rb") as fh:
        head = fh.read(16)
    if head == b"SQLite format 3\x00":
        from .store import Project
        from .trajectories import trajectory_table

        with Project.open(p) as proj:
            df = trajectory_table(proj, method=method or "both")
    elif p.suffix.lower() in (".parquet", ".pq"):
        try:
            df = pd.read_parquet(p)
        except Exception as exc:  # noqa: BLE001 - pyarrow raises many types
            raise SandtrackError(f"{p}: not a readable Parquet file ({str(exc)[:100]})") from None
    else:
        try:
            df = pd.read_csv(p, skipinitialspace=True)
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
            raise SandtrackError(f"{p}: not a readable CSV ({str(exc).splitlines()[0][:100] or 'empty'})") from None
    return experiment_table(df, method, str(p))


def experiment_table(df: pd.DataFrame, method: str | None = None, source: str = "experiment") -> pd.DataFrame:
    need = ["marker", "time_s", *AXES]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise SandtrackError(f"{source}: lacks columns {', '.join(missing)} (needs {', '.join(need)})")
    if "method" in df.columns:
        methods = list(dict.fromkeys(df["method"].dropna()))
        if method is None or method == "both":
            method = "triangulation" if "triangulation" in methods else (methods[0] if methods else None)
        if method is not None:
            if method not in methods:
                raise SandtrackError(f"{source}: no rows with method {method!r}")
            df = df[df["method"] == method]
    extra = [c for c in (*SD_COLUMNS, *COV_COLUMNS, *BIAS_COLUMNS) if c in df.columns]
    for group in (SD_COLUMNS, BIAS_COLUMNS):
        if any(c in extra for c in group) and not all(c in extra for c in group):
            raise SandtrackError(f"{source}: give all of {', '.join(group)} or none")
    out = df[need + extra].apply(pd.to_numeric, errors="coerce")
    if "calibrated_region" in df.columns:  # where the lens model extrapolated (xyz.py)
        out["outside_region"] = (df["calibrated_region"] == "outside").to_numpy()
    out = out[np.isfinite(out[need].to_numpy()).all(axis=1) & measured_rows(df)]
    if out.empty:
        raise SandtrackError(f"{source}: no rows with a finite time and a 3D position from observed pixels")
    out["marker"] = out["marker"].astype(np.int64)
    return out.sort_values(["marker", "time_s"], kind="stable").drop_duplicates(["marker", "time_s"]).reset_index(
        drop=True)


def has_sd(exp: pd.DataFrame) -> bool:
    """Whether an experiment table carries per-point uncertainties: sd columns, not all empty (a table
    whose XYZ method gives none is treated as one without them)."""
    return all(c in exp.columns for c in SD_COLUMNS) and bool(np.isfinite(exp[list(SD_COLUMNS)].to_numpy(
        float)).all(axis=1).any())


def measured_rows(df: pd.DataFrame) -> np.ndarray:
    """Rows whose XYZ comes from observed pixels only: a camera's status "occluded" or "lost" (an exported
    table's ``status_<camera>``) means its pixel is the tracker's prediction, not a measurement, and such an
    XYZ lags the particle while it is hidden; it would bias the time alignment and every error metric."""
    keep = np.ones(len(df), bool)
    for col in (c for c in df.columns if str(c).startswith("status_")):
        keep &= ~df[col].isin(UNOBSERVED).to_numpy()
    return keep


def read_tool(path: str | Path) -> pd.DataFrame:
    """A tool track: ``time_s`` and position columns (``X_mm`` or ``tool_X_mm`` or ``x``, per axis;
    a missing axis is taken as constant). Returns DataFrame[time_s, X_mm, Y_mm, Z_mm]."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"file not found: {p}")
    try:
        df = pd.read_csv(p, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError):
        raise SandtrackError(f"{p}: not a readable tool CSV") from None
    cols = {str(c).strip().lower(): c for c in df.columns}
    tcol = cols.get("time_s") or cols.get("time")
    pos = {a: cols.get(f"{a.lower()}_mm") or cols.get(f"tool_{a.lower()}_mm") or cols.get(a.lower()) for a in "XYZ"}
    if tcol is None or all(c is None for c in pos.values()):
        raise SandtrackError(f"{p}: a tool track needs time_s and position columns (X_mm/tool_X_mm, ...)")
    out = pd.DataFrame({"time_s": pd.to_numeric(df[tcol], errors="coerce")})
    for a, c in pos.items():
        out[f"{a}_mm"] = pd.to_numeric(df[c], errors="coerce") if c is not None else 0.0
    out = out.dropna().sort_values("time_s")
    if len(out) < 2:
        raise SandtrackError(f"{p}: the tool track has fewer than two rows")
    return out


# -- onset, matching, alignment -------------------------------------------------------------------
def motion_onset(t: np.ndarray, xyz: np.ndarray, threshold_mm: float) -> float | None:
    """First time the position is `threshold_mm` from its start (median of the first samples),
    interpolated between samples."""
    if len(t) < 3:
        return None
    start = np.median(xyz[: max(3, min(10, len(t) // 10))], axis=0)
    dist = np.linalg.norm(xyz - start, axis=1)
    above = np.nonzero(dist >= threshold_mm)[0]
    if len(above) == 0 or above[0] == 0:
        return None
    k = int(above[0])
    f = (threshold_mm - dist[k - 1]) / max(dist[k] - dist[k - 1], 1e-12)
    return float(t[k - 1] + f * (t[k] - t[k - 1]))


def match_particles(exp: pd.DataFrame, dem: pd.DataFrame, how: str = "auto",
                    max_match_mm: float = 50.0) -> dict[int, int]:
    """marker -> particle_id."""
    markers = sorted(exp["marker"].unique().tolist())
    pids = set(dem["particle_id"].unique().tolist())
    if how == "auto":
        how = "id" if all(m in pids for m in markers) else "nearest"
    if how == "id":
        pairs = {int(m): int(m) for m in markers if m in pids}
    elif how == "nearest":
        from scipy.optimize import linear_sum_assignment

        e0 = exp.groupby("marker")[list(AXES)].first()
        d0 = dem.groupby("particle_id")[list(AXES)].first()
        cost = _cost(e0.to_numpy(), d0.to_numpy())
        r, c = linear_sum_assignment(cost)
        pairs = {int(e0.index[i]): int(d0.index[j]) for i, j in zip(r, c, strict=True) if cost[i, j] <= max_match_mm}
    else:
        raise SandtrackError(f"unknown matching {how!r} (auto, id, nearest)")
    if not pairs:
        raise SandtrackError("no experiment marker matches a DEM particle (ids differ and no particle starts "
                             f"within {max_match_mm:g} mm of a marker)")
    return pairs


class _Pairs:
    """Per matched pair: experiment samples and the DEM track, ready for fast shifted interpolation."""

    def __init__(self, exp: pd.DataFrame, dem: pd.DataFrame, pairs: dict[int, int], exp_sd_mm: float | None = None,
                 dem_sd_mm: float = 0.0):
        self.items = []
        self.covs: dict[int, np.ndarray] = {}  # marker -> (n, 3, 3) combined covariance of its samples
        self.bias: dict[int, np.ndarray] = {}  # marker -> (n, 3) the mean of its samples' error (0: centred)
        eg = dict(tuple(exp.groupby("marker")))
        dg = dict(tuple(dem.groupby("particle_id")))
        for m, pid in sorted(pairs.items()):
            e, d = eg[m], dg[pid]
            if len(e) < 2 or len(d) < 2:
                continue
            self.items.append((m, pid, e["time_s"].to_numpy(), e[list(AXES)].to_numpy(),
                               d["time_s"].to_numpy(), d[list(AXES)].to_numpy()))
            if exp_sd_mm is not None:
                self.covs[m] = K.covariances(np.full((len(e), 3), float(exp_sd_mm)), None, dem_sd_mm)
            elif all(c in e.columns for c in SD_COLUMNS):
                cov = e[list(COV_COLUMNS)].to_numpy(float) if all(c in e.columns for c in COV_COLUMNS) else None
                sd = e[list(SD_COLUMNS)].to_numpy(float, copy=True)
                if all(c in e.columns for c in BIAS_COLUMNS):
                    bias = e[list(BIAS_COLUMNS)].to_numpy(float)
                    shifted = np.isfinite(bias).any(axis=1)
                    sd[shifted] = gaussian_sd(sd[shifted], bias[shifted])
                    self.bias[m] = np.nan_to_num(bias)
                self.covs[m] = K.covariances(sd, cov, dem_sd_mm)
        if not self.items:
            raise SandtrackError("matched particles have fewer than two samples each")

    def aligned(self, shift: float, item):
        """Experiment samples within the DEM's span (shifted) and the DEM interpolated there."""
        t, xe, xi, _ = self._aligned(shift, item)
        return t, xe, xi

    def aligned_cov(self, shift: float, item):
        """As `aligned`, plus the samples' combined covariance (n, 3, 3) and their error's mean (n, 3), or
        None, None without uncertainties."""
        t, xe, xi, ok = self._aligned(shift, item)
        cov = self.covs.get(item[0])
        if cov is None:
            return t, xe, xi, None, None
        bias = self.bias.get(item[0])
        return t, xe, xi, cov[ok], np.zeros((int(ok.sum()), 3)) if bias is None else bias[ok]

    def _aligned(self, shift: float, item):
        m, pid, te, xe, td, xd = item
        tq = te - shift
        ok = (tq >= td[0]) & (tq <= td[-1])
        if ok.sum() < 2:
            return te[ok], xe[ok], np.zeros((ok.sum(), 3)), ok
        xi = np.column_stack([np.interp(tq[ok], td, xd[:, k]) for k in range(3)])
        return te[ok], xe[ok], xi, ok

    def best(self, item) -> np.ndarray:
        """The experiment's best estimates of a pair's positions: XYZ less its bias, where it has one."""
        bias = self.bias.get(item[0])
        return item[3] if bias is None else item[3] - bias

    def rmse(self, shift: float) -> float:
        """RMS distance of the experiment's best estimates (XYZ less its bias, where it has one) to the DEM,
        the time alignment's cost."""
        sq, n = 0.0, 0
        for item in self.items:
            _, _, xi, ok = self._aligned(shift, item)
            xe = self.best(item)[ok]
            if len(xe) >= 2:
                sq += float(((xe - xi) ** 2).sum())
                n += len(xe)
        return float(np.sqrt(sq / n)) if n else float("inf")


def align_time(pairs: _Pairs, start_shift: float, max_lag_s: float, step_s: float) -> tuple[float, float]:
    """Shift (s) minimising the RMSE within start +- max_lag; returns (shift, rmse)."""
    grid = start_shift + np.arange(-max_lag_s, max_lag_s + step_s / 2, step_s)
    vals = np.array([pairs.rmse(s) for s in grid])
    if not np.isfinite(vals).any():
        raise SandtrackError("the experiment and DEM trajectories do not overlap in time")
    k = int(np.nanargmin(vals))
    shift = float(grid[k])
    if 0 < k < len(grid) - 1 and np.isfinite(vals[k - 1:k + 2]).all():
        a, b, c = vals[k - 1], vals[k], vals[k + 1]
        den = a - 2 * b + c
        if den > 0:
            shift += 0.5 * (a - c) / den * step_s
    # one finer pass around the grid minimum
    fine = shift + np.linspace(-step_s, step_s, 21)
    fv = np.array([pairs.rmse(s) for s in fine])
    j = int(np.argmin(fv))
    return float(fine[j]), float(fv[j])


# -- comparison -------------------------------------------------------------------------------------
@dataclass
class Comparison:
    name: str
    time_shift_s: float
    onset: dict
    pairs: dict[int, int]
    per_particle: pd.DataFrame
    summary: dict
    errors: dict = field(default_factory=dict)  # marker -> DataFrame[time_s, err_3d_mm, exp X.., dem X..]

    def to_dict(self) -> dict:
        return {"name": self.name, "time_shift_s": self.time_shift_s, "onset": self.onset,
                "pairs": {str(k): v for k, v in self.pairs.items()}, "summary": self.summary,
                "per_particle": self.per_particle.to_dict("records")}


def compare(exp: pd.DataFrame, dem: pd.DataFrame, name: str = "dem", match: str = "auto", fps: float = 50.0,
            max_lag_s: float = 0.5, onset_mm: float = 3.0, exp_tool: pd.DataFrame | None = None,
            dem_tool: pd.DataFrame | None = None, time_shift_s: float | None = None, flag_mm: float = 2.0,
            max_match_mm: float = 50.0, exp_onset_s: float | None = None,
            dem_onset_s: float | None = None, dem_sd_mm: float = 0.0, exp_sd_mm: float | None = None,
            alpha: float = 0.05) -> Comparison:
    """Align and compare (see module docstring). `time_shift_s` given: no alignment search.
    The tool's onset on each side: `*_onset_s` if given, else from `*_tool` tracks. Uncertainty: the
    experiment's sd columns, else `exp_sd_mm` per axis (None: no χ²), plus `dem_sd_mm` per axis."""
    for label, v in (("DEM sd", dem_sd_mm), ("experiment sd", exp_sd_mm)):
        if v is not None and not (np.isfinite(v) and v >= 0):
            raise SandtrackError(f"{label} must be a number >= 0 mm, got {v}")
    if not 0 < alpha < 1:
        raise SandtrackError(f"the consistency level must lie between 0 and 1, got {alpha}")
    exp = experiment_table(exp)
    pairs_map = match_particles(exp, dem, match, max_match_mm)
    with_sd = has_sd(exp)
    if not with_sd and exp_sd_mm is None:
        exp = exp.drop(columns=[c for c in (*SD_COLUMNS, *COV_COLUMNS, *BIAS_COLUMNS) if c in exp.columns])
    pairs = _Pairs(exp, dem, pairs_map, None if with_sd else exp_sd_mm, dem_sd_mm)
    onset: dict = {"source": None}
    if time_shift_s is None:
        start = None
        oe, od = exp_onset_s, dem_onset_s
        if oe is None and exp_tool is not None:
            oe = motion_onset(exp_tool["time_s"].to_numpy(), exp_tool[list(AXES)].to_numpy(), onset_mm)
        if od is None and dem_tool is not None:
            od = motion_onset(dem_tool["time_s"].to_numpy(), dem_tool[list(AXES)].to_numpy(), onset_mm)
        if oe is not None and od is not None:
            start = oe - od
            onset = {"source": "tool", "experiment_s": oe, "dem_s": od}
        if start is None:
            diffs = []
            for item in pairs.items:
                te, td, xd = item[2], item[4], item[5]
                oe, od = motion_onset(te, pairs.best(item), onset_mm), motion_onset(td, xd, onset_mm)
                if oe is not None and od is not None:
                    diffs.append(oe - od)
            if diffs:
                start = float(np.median(diffs))
                onset = {"source": "particles", "particles_used": len(diffs)}
            else:
                start = 0.0
                onset = {"source": "none (no particle moved)"}
        onset["initial_shift_s"] = start
        shift, _ = align_time(pairs, start, max_lag_s, 1.0 / fps)
    else:
        shift = float(time_shift_s)
        onset = {"source": "given"}

    per, errors, _ = _metrics(pairs, shift, flag_mm, distances=False)
    if time_shift_s is None and per["flagged"].any() and (~per["flagged"]).sum() >= 1:
        # Re-align without the outliers: a drifting particle would pull the shift towards itself.
        keep = set(per.loc[~per["flagged"], "marker"].astype(int))
        clean = _Pairs.__new__(_Pairs)
        clean.items, clean.covs, clean.bias = [it for it in pairs.items if it[0] in keep], pairs.covs, pairs.bias
        shift, _ = align_time(clean, shift, min(max_lag_s, 3.0 / fps), 1.0 / fps)
        onset["realigned_without"] = sorted(set(pairs_map) - keep)
    per, errors, parts = _metrics(pairs, shift, flag_mm, fps=fps, shift_fitted=time_shift_s is None)
    summary = {"particles": len(per), "time_shift_s": shift, "time_shift_frames": shift * fps,
               "flagged_markers": per.loc[per["flagged"], "marker"].astype(int).tolist()}
    for col in METRICS:
        summary[f"{col}_median"] = float(per[col].median())
        summary[f"{col}_mean"] = float(per[col].mean())
        summary[f"{col}_max"] = float(per[col].max())
    all_sq = sum(float((e["err_3d_mm"] ** 2).sum()) for e in errors.values())
    summary["rmse_3d_mm_all"] = float(np.sqrt(all_sq / sum(len(e) for e in errors.values())))
    summary.update(_run_consistency(per, parts, exp, with_sd, exp_sd_mm, dem_sd_mm, alpha))
    return Comparison(name, shift, onset, pairs_map, per, summary, errors)


def _run_consistency(per: pd.DataFrame, parts: list[K.Chi2], exp: pd.DataFrame, with_sd: bool,
                     exp_sd_mm: float | None, dem_sd_mm: float, alpha: float) -> dict:
    """The run's χ² over its particles (independent of each other), its verdict and what it rests on."""
    out: dict = {"alpha": alpha, "dem_sd_mm": dem_sd_mm}
    if with_sd and exp_sd_mm is not None:
        out["note"] = f"the experiment's own sd columns were used, not the assumed {exp_sd_mm:g} mm"
    if with_sd:
        out["uncertainty"] = "the experiment's sd columns" + (" and covariances" if all(
            c in exp.columns for c in COV_COLUMNS) else "")
    elif exp_sd_mm is not None:
        out["uncertainty"] = f"an assumed experiment sd of {exp_sd_mm:g} mm per axis (the table has no sd columns)"
    else:
        out.update({"uncertainty": None, "chi2_reduced": float("nan"), "consistent": None,
                    "verdict": "no χ²: the experiment carries no sd columns (an export from before uncertainties?); "
                               "give an assumed sd per axis (--exp-sd-mm) to test consistency"})
        return out
    if dem_sd_mm > 0:
        out["uncertainty"] += f" and a DEM sd of {dem_sd_mm:g} mm per axis"
    run = K.combine(parts)
    out.update(run.to_dict())
    out["samples_without_sd"] = int(per["samples"].sum() - run.samples)
    if run.samples == 0:
        out.update({"consistent": None, "verdict": "no χ²: no sample has a finite uncertainty"})
        return out
    out["consistent"] = bool(run.p_value >= alpha)
    word = "consistent" if out["consistent"] else "NOT consistent"
    out["verdict"] = (f"{word} with the experiment at the {100 * alpha:g} % level: χ²/dof {run.reduced:.2f}, "
                      f"p = {run.p_value:.2g} ({run.samples} samples, as {run.dof_eff / 3:.1f} independent ones); "
                      f"{100 * run.within / run.samples:.1f} % within the 95 % band")
    if "outside_region" in exp.columns:
        outside = int(exp.loc[exp["marker"].isin(per["marker"]), "outside_region"].sum())
        out["samples_outside_calibrated_region"] = outside
        if outside:
            out["verdict"] += (f"; {outside} of the experiment's samples lie beyond the calibrated image region "
                               "(their sd leaves out the lens model's error there)")
    return out


def _metrics(pairs: _Pairs, shift: float, flag_mm: float, distances: bool = True, fps: float = 50.0,
             shift_fitted: bool = True) -> tuple[pd.DataFrame, dict, list[K.Chi2]]:
    """Per-particle metrics, the aligned samples per marker, and the particles' χ² (with uncertainties)."""
    rows, errors, parts = [], {}, []
    usable = [it for it in pairs.items if len(pairs.aligned(shift, it)[0]) >= 2]
    share = 1.0 / max(sum(it[0] in pairs.covs for it in usable), 1) if shift_fitted else 0.0
    for item in usable:
        m, pid = item[0], item[1]
        t, xe, xi, cov, bias = pairs.aligned_cov(shift, item)
        diff = xe - xi
        err = np.linalg.norm(diff, axis=1)
        slope = float(np.polyfit(t - t[0], err, 1)[0]) if t[-1] > t[0] else 0.0
        rows.append({
            "marker": m, "particle_id": pid, "samples": len(t), "t_start_s": float(t[0]), "t_end_s": float(t[-1]),
            "rmse_3d_mm": float(np.sqrt(np.mean(err ** 2))),
            "rmse_x_mm": float(np.sqrt(np.mean(diff[:, 0] ** 2))),
            "rmse_y_mm": float(np.sqrt(np.mean(diff[:, 1] ** 2))),
            "rmse_z_mm": float(np.sqrt(np.mean(diff[:, 2] ** 2))),
            "final_error_mm": float(err[-1]),
            "frechet_mm": np.nan,
            "dtw_norm_mm": np.nan,
            "max_dev_mm": float(err.max()),
            "drift_mm_per_s": slope,
        })
        errors[m] = pd.DataFrame({"time_s": t, "err_3d_mm": err, "exp_X_mm": xe[:, 0], "exp_Y_mm": xe[:, 1],
                                  "exp_Z_mm": xe[:, 2], "dem_X_mm": xi[:, 0], "dem_Y_mm": xi[:, 1],
                                  "dem_Z_mm": xi[:, 2]})
        if cov is not None:
            w, _ = K.whiten(diff - bias, cov)
            part = K.chi2_of_track(np.rint((t - t[0]) * fps), w, share)
            parts.append(part)
            rows[-1].update({k: part.to_dict()[k] for k in ("chi2", "chi2_dof", "chi2_reduced", "dof_eff",
                                                            "samples_eff", "p_value", "within_95_pct")})
            sd = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
            errors[m] = errors[m].assign(sd_X_mm=sd[:, 0], sd_Y_mm=sd[:, 1], sd_Z_mm=sd[:, 2],
                                         bias_X_mm=bias[:, 0], bias_Y_mm=bias[:, 1], bias_Z_mm=bias[:, 2],
                                         norm_dist=np.sqrt((w ** 2).sum(axis=1)))
    if not rows:
        raise SandtrackError("the experiment and DEM trajectories do not overlap in time after alignment")
    per = pd.DataFrame(rows)
    if distances:
        dist = _batch_distances([(errors[m][["exp_X_mm", "exp_Y_mm", "exp_Z_mm"]].to_numpy(),
                                  errors[m][["dem_X_mm", "dem_Y_mm", "dem_Z_mm"]].to_numpy()) for m in per["marker"]])
        per["frechet_mm"] = [f for f, _ in dist]
        per["dtw_norm_mm"] = [d for _, d in dist]
    per["flagged"] = _flags(per, flag_mm)
    return per, errors, parts


def _flags(per: pd.DataFrame, flag_mm: float) -> np.ndarray:
    out = np.zeros(len(per), bool)
    for col in ("rmse_3d_mm", "drift_mm_per_s"):
        v = per[col].to_numpy(float)
        med = float(np.median(v))
        sigma = 1.4826 * float(np.median(np.abs(v - med)))
        sigma = max(sigma, 0.05 * abs(med), 1e-9)
        out |= v > med + 4 * sigma
    return out & (per["rmse_3d_mm"].to_numpy(float) > flag_mm)


def rank(comparisons: list[Comparison], by: str = "auto") -> pd.DataFrame:
    """DEM runs ranked by agreement (lower is better). by "chi2_reduced": the χ² per degree of freedom
    (the differences in units of their uncertainty); "rmse_3d_mm_all": the overall RMSE (then the median
    Fréchet breaks ties); "auto": χ² when every run has one, else RMSE. Both ranks are given
    (`rank` by the criterion used, `rank_rmse` by RMSE)."""
    rows = [{"rank": 0, "name": c.name, "chi2_reduced": c.summary.get("chi2_reduced", float("nan")),
             "p_value": c.summary.get("p_value", float("nan")), "consistent": c.summary.get("consistent"),
             "within_95_pct": c.summary.get("within_95_pct", float("nan")),
             "rmse_3d_mm_all": c.summary["rmse_3d_mm_all"], "rank_rmse": 0,
             "rmse_3d_mm_median": c.summary["rmse_3d_mm_median"], "frechet_mm_median": c.summary["frechet_mm_median"],
             "dtw_norm_mm_median": c.summary["dtw_norm_mm_median"], "time_shift_s": c.time_shift_s,
             "flagged": len(c.summary["flagged_markers"])} for c in comparisons]
    df = pd.DataFrame(rows)
    if by == "auto":
        by = "chi2_reduced" if len(df) and df["chi2_reduced"].notna().all() else "rmse_3d_mm_all"
    if by not in ("chi2_reduced", "rmse_3d_mm_all"):
        raise SandtrackError(f"unknown ranking {by!r} (chi2_reduced, rmse_3d_mm_all)")
    if df[by].isna().any():
        raise SandtrackError("cannot rank by χ²: a run has no χ² (the experiment carries no sd columns)")
    by_rmse = df.sort_values(["rmse_3d_mm_all", "frechet_mm_median"], kind="stable").index
    df.loc[by_rmse, "rank_rmse"] = np.arange(1, len(df) + 1)
    df = df.sort_values([by, "frechet_mm_median"], kind="stable").reset_index(drop=True)
    df["rank"] = np.arange(1, len(df) + 1)
    df.attrs["ranked_by"] = by
    return df


# -- plots ------------------------------------------------------------------------------------------
def plot_comparison(cmp: Comparison, out_dir: str | Path, max_particles: int = 50) -> list[Path]:
    """PNGs: per particle, experiment vs DEM in the three planes; the 3D error over time of all."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    flagged = set(cmp.summary["flagged_markers"])
    for m in sorted(cmp.errors)[:max_particles]:
        e = cmp.errors[m]
        banded = "sd_X_mm" in e.columns
        fig, grid = plt.subplots(2 if banded else 1, 3, figsize=(12, 7.5 if banded else 4), squeeze=False)
        # a fixed layout: matplotlib's constrained layout took most of a figure's 0.8 s
        fig.subplots_adjust(left=0.07, right=0.98, bottom=0.08 if banded else 0.14, top=0.92 if banded else 0.86,
                            wspace=0.32, hspace=0.3)
        axes = grid[0]
        for ax, (a, b) in zip(axes, (("X", "Y"), ("X", "Z"), ("Y", "Z")), strict=True):
            ax.plot(e[f"exp_{a}_mm"], e[f"exp_{b}_mm"], "-", color="tab:blue", label="experiment")
            ax.plot(e[f"dem_{a}_mm"], e[f"dem_{b}_mm"], "--", color="tab:orange", label="DEM")
            ax.plot(e[f"exp_{a}_mm"].iloc[0], e[f"exp_{b}_mm"].iloc[0], "o", color="k", ms=3)
            ax.set_xlabel(f"{a} (mm)")
            ax.set_ylabel(f"{b} (mm)")
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=8)
        if banded:
            _band_panels(grid[1], e)
        row = cmp.per_particle.set_index("marker").loc[m]
        chi = f"  χ²/dof {row['chi2_reduced']:.2f}, p {row['p_value']:.2g}" if "chi2_reduced" in row and \
            np.isfinite(row["chi2_reduced"]) else ""
        fig.suptitle(f"{cmp.name}: marker {m} vs particle {int(row['particle_id'])}  RMSE {row['rmse_3d_mm']:.2f} mm"
                     f"{chi}{'  FLAGGED' if m in flagged else ''}")
        p = out / f"{_safe(cmp.name)}_marker{m}.png"
        fig.savefig(p, dpi=90)
        plt.close(fig)
        files.append(p)
    banded = any("norm_dist" in e.columns for e in cmp.errors.values())
    fig, axes = plt.subplots(2 if banded else 1, 1, figsize=(9, 8 if banded else 4.5), squeeze=False)
    fig.subplots_adjust(left=0.09, right=0.97, bottom=0.07 if banded else 0.12, top=0.95 if banded else 0.9,
                        hspace=0.38)
    ax = axes[0, 0]
    for m, e in sorted(cmp.errors.items()):
        ax.plot(e["time_s"], e["err_3d_mm"], color="tab:red" if m in flagged else "0.5",
                lw=1.6 if m in flagged else 0.8, label=f"marker {m}" if m in flagged else None)
    ax.set_xlabel("experiment time (s)")
    ax.set_ylabel("3D error (mm)")
    ax.set_title(f"{cmp.name}: error over time (shift {cmp.time_shift_s * 1000:+.1f} ms)")
    ax.grid(alpha=0.3)
    if flagged:
        ax.legend(fontsize=8)
    if banded:
        ax = axes[1, 0]
        for m, e in sorted(cmp.errors.items()):
            if "norm_dist" in e.columns:
                ax.plot(e["time_s"], e["norm_dist"], color="tab:red" if m in flagged else "0.5",
                        lw=1.6 if m in flagged else 0.8)
        ax.axhline(np.sqrt(K.CHI2_95_3D), color="tab:green", lw=1.2, label="95 % band")
        ax.set_xlabel("experiment time (s)")
        ax.set_ylabel("distance in units of its uncertainty")
        ax.set_title(textwrap.fill(cmp.summary.get("verdict", ""), 110), fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    p = out / f"{_safe(cmp.name)}_error_over_time.png"
    fig.savefig(p, dpi=90)
    plt.close(fig)
    files.append(p)
    return files


def _band_panels(axes, e: pd.DataFrame) -> None:
    """Per axis: DEM minus experiment over time, and the 95 % band of the combined uncertainty (around
    minus the experiment's bias, where it has one)."""
    for ax, a in zip(axes, "XYZ", strict=True):
        t, band = e["time_s"].to_numpy(), K.Z95 * e[f"sd_{a}_mm"].to_numpy()
        centre = -e[f"bias_{a}_mm"].to_numpy() if f"bias_{a}_mm" in e.columns else np.zeros(len(t))
        ax.fill_between(t, centre - band, centre + band, color="tab:green", alpha=0.25, lw=0, label="95 % band")
        ax.plot(t, e[f"dem_{a}_mm"] - e[f"exp_{a}_mm"], color="tab:orange", lw=1.0, label="DEM - experiment")
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_xlabel("experiment time (s)")
        ax.set_ylabel(f"{a}: DEM - experiment (mm)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)


_BRAILLE_BITS = ((0x01, 0x08), (0x02, 0x10), (0x04, 0x20), (0x40, 0x80))  # [row 0..3][col 0..1]


def text_plot(series: list[tuple[str, np.ndarray, np.ndarray]], width: int = 60, height: int = 12,
              y_label: str = "", x_label: str = "") -> str:
    """A plain-text line plot (Unicode braille, 2x4 dots per cell) for the terminal: one line per
    series drawn over the same axes, then a legend with each series' min/max."""
    width, height = max(width, 10), max(height, 3)
    pts = [(lab, np.asarray(x, float), np.asarray(y, float)) for lab, x, y in series]
    pts = [(lab, x[np.isfinite(x) & np.isfinite(y)], y[np.isfinite(x) & np.isfinite(y)]) for lab, x, y in pts]
    pts = [p for p in pts if len(p[1])]
    if not pts:
        return "(no data)"
    x0 = min(p[1].min() for p in pts)
    x1 = max(p[1].max() for p in pts)
    y0 = min(p[2].min() for p in pts)
    y1 = max(p[2].max() for p in pts)
    if x1 == x0:
        x1 = x0 + 1
    if y1 == y0:
        y1 = y0 + 1
    W, H = width * 2, height * 4
    grid = np.zeros((height, width), np.int32)
    for _lab, x, y in pts:
        # dense sampling along the polyline so lines are continuous
        fx = np.interp(np.linspace(0, len(x) - 1, max(len(x), W * 2)), np.arange(len(x)), x)
        fy = np.interp(np.linspace(0, len(y) - 1, max(len(y), W * 2)), np.arange(len(y)), y)
        cx = np.clip(((fx - x0) / (x1 - x0) * (W - 1)).round().astype(int), 0, W - 1)
        cy = np.clip(((y1 - fy) / (y1 - y0) * (H - 1)).round().astype(int), 0, H - 1)
        for px, py in set(zip(cx.tolist(), cy.tolist(), strict=True)):
            grid[py // 4, px // 2] |= _BRAILLE_BITS[py % 4][px % 2]
    lab_w = max(len(f"{y1:.3g}"), len(f"{y0:.3g}"))
    lines = []
    for r in range(height):
        tick = f"{y1:.3g}" if r == 0 else (f"{y0:.3g}" if r == height - 1 else "")
        lines.append(f"{tick:>{lab_w}} ┤" + "".join(chr(0x2800 + v) if v else " " for v in grid[r]))
    lines.append(" " * lab_w + " └" + "─" * width)
    lines.append(" " * (lab_w + 2) + f"{x0:.3g}".ljust(width - len(f"{x1:.3g}")) + f"{x1:.3g}")
    if x_label or y_label:
        lines.append(" " * (lab_w + 2) + f"x: {x_label}   y: {y_label}".strip())
    for lab, _x, y in pts:
        lines.append(f"  {lab}: {y.min():.3g} .. {y.max():.3g}")
    return "\n".join(lines)


def error_text_plot(cmp: Comparison, width: int = 60, height: int = 10, markers: list[int] | None = None) -> str:
    """Terminal plot over time of the flagged markers (else the three worst): with uncertainties, their
    distance from the DEM in units of its uncertainty against the 95 % band's edge; else the 3D error."""
    per = cmp.per_particle
    banded = "chi2_reduced" in per.columns and per["chi2_reduced"].notna().any()
    if markers is None:
        worst = per.nlargest(3, "chi2_reduced" if banded else "rmse_3d_mm")["marker"].tolist()
        markers = cmp.summary["flagged_markers"] or worst
    if not banded:
        series = [(f"marker {m}", cmp.errors[m]["time_s"].to_numpy(), cmp.errors[m]["err_3d_mm"].to_numpy())
                  for m in markers if m in cmp.errors]
        return text_plot(series, width, height, y_label="3D error (mm)", x_label="time (s)")
    series = [(f"marker {m}", cmp.errors[m]["time_s"].to_numpy(), cmp.errors[m]["norm_dist"].to_numpy())
              for m in markers if m in cmp.errors and "norm_dist" in cmp.errors[m].columns]
    if series:
        t = np.concatenate([x for _, x, _ in series])
        edge = np.sqrt(K.CHI2_95_3D)
        series.append(("95 % band edge", np.array([t.min(), t.max()]), np.array([edge, edge])))
    return text_plot(series, width, height, y_label="distance / its uncertainty (above the band edge: outside "
                     "the 95 % band)", x_label="time (s)")
