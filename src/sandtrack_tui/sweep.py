"""DEM parameter sweep (Design of Experiments): every run against the experiment, ranked, and a
quadratic response surface that suggests the best parameter set.

RUNS.csv, one row per DEM run
    ``run`` (a name; default the row number), the parameter columns (every numeric column not named
    below, or those given), and per run any of: ``angle_deg`` (its angle of repose, already
    measured), ``repose`` (a file `repose.measure_path` reads: dump, exchange CSV, photo, video,
    saved JSON result), ``trajectories`` (its tracer trajectories, compared with the experiment by
    `compare.compare`). Paths are relative to the CSV's folder.

Agreement of a run
    angle error = run angle - experiment angle (deg); trajectory metric (default the overall 3D
    RMSE, mm; or ``chi2_reduced``: the run's χ² per degree of freedom against the experiment's
    uncertainty, see `compare`, for which the experiment needs sd columns or an assumed sd).
    Score = sum over the criteria of weight x |error| / (median |error| over the runs), so each
    criterion's typical error counts one; runs are ranked by score, lowest first.

Response surface
    Parameters are coded to [-1, 1] over the range the runs span (the DoE's box). Each response
    (the angle; each trajectory metric) is fitted by least squares with a full quadratic: constant,
    linear, square (only for parameters with three or more levels) and two-parameter interaction
    terms; fewer terms when there are too few runs. Reported: coefficients (coded units, so they
    compare as effects), R², adjusted R², the leave-one-out Q² (from the hat matrix) and the RMSE.

Suggested parameters
    The point of the box minimising sum weight x ((prediction - target) / scale)², targets: the
    experiment's angle, zero for trajectory metrics; scale as for the score. When the angle is the
    only criterion a whole surface of parameter sets hits it: the one nearest the best-ranked run is
    given (a small pull towards it breaks the tie). Searched on a dense grid over the box, then by
    Nelder-Mead from its best points.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import SandtrackError

RESERVED = {"run", "name", "angle_deg", "repose", "trajectories", "notes", "comment"}
TRAJ_METRICS = ("rmse_3d_mm_all", "frechet_mm_median", "dtw_norm_mm_median", "final_error_mm_median", "chi2_reduced")
TIE_PULL = 1e-3
GRID_POINTS = 20000  # points of the box tried before the local search


def read_runs(path: str | Path, params: list[str] | None = None) -> tuple[pd.DataFrame, list[str]]:
    """The runs table and its parameter columns; path columns made absolute."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"file not found: {p}")
    try:
        df = pd.read_csv(p, skipinitialspace=True, comment="#")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        raise SandtrackError(f"{p}: not a readable CSV ({str(exc).splitlines()[0][:100] or 'empty'})") from None
    df.columns = [str(c).strip() for c in df.columns]
    if df.empty:
        raise SandtrackError(f"{p}: no runs")
    lower = {c.lower(): c for c in df.columns}
    df = df.rename(columns={lower[k]: k for k in RESERVED if k in lower})
    if "run" not in df.columns:
        df.insert(0, "run", df["name"] if "name" in df.columns else [f"run{i + 1}" for i in range(len(df))])
    df["run"] = df["run"].astype(str)
    if df["run"].duplicated().any():
        raise SandtrackError(f"{p}: run names repeat ({df.loc[df['run'].duplicated(), 'run'].iloc[0]})")
    if not ({"angle_deg", "repose", "trajectories"} & set(df.columns)):
        raise SandtrackError(f"{p}: needs a column angle_deg, repose or trajectories (found: {', '.join(df.columns)})")
    for col in ("repose", "trajectories"):
        if col in df.columns:
            df[col] = [None if pd.isna(v) or not str(v).strip() else str(_resolve(p.parent, str(v).strip()))
                       for v in df[col]]
    if params is None:
        params = [c for c in df.columns if c not in RESERVED and pd.api.types.is_numeric_dtype(df[c])]
    else:
        missing = [c for c in params if c not in df.columns]
        if missing:
            raise SandtrackError(f"{p}: no parameter column {', '.join(missing)}")
    if not params:
        raise SandtrackError(f"{p}: no numeric parameter column (columns: {', '.join(df.columns)})")
    for c in params:
        v = pd.to_numeric(df[c], errors="coerce")
        if v.isna().any():
            raise SandtrackError(f"{p}: parameter {c!r} has a missing or non-numeric value in run "
                                 f"{df.loc[v.isna(), 'run'].iloc[0]}")
        df[c] = v.astype(float)
    return df, list(params)


def _resolve(base: Path, value: str) -> Path:
    q = Path(value).expanduser()
    return q if q.is_absolute() else base / q


# -- response surface ---------------------------------------------------------------------------------
@dataclass
class Coding:
    """Real parameter values <-> coded [-1, 1] over the runs' range."""

    names: list[str]
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def from_runs(cls, X: np.ndarray, names: list[str]) -> Coding:
        low, high = X.min(axis=0), X.max(axis=0)
        flat = [n for n, lo, hi in zip(names, low, high, strict=True) if hi <= lo]
        if flat:
            raise SandtrackError(f"parameter {', '.join(flat)} has one value in every run: leave it out (--params)")
        return cls(names, low, high)

    def code(self, X):
        return 2 * (np.asarray(X, float) - self.low) / (self.high - self.low) - 1

    def decode(self, x):
        return self.low + (np.asarray(x, float) + 1) * (self.high - self.low) / 2


@dataclass
class Surface:
    response: str
    terms: list[str]
    powers: list[tuple]  # per term: tuple of parameter indices multiplied (empty = constant)
    coef: np.ndarray
    r2: float
    r2_adj: float
    q2: float
    rmse: float
    n: int
    model: str  # "quadratic" | "linear + interactions" | "linear"

    def design(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        return np.column_stack([np.prod(x[:, list(t)], axis=1) if t else np.ones(len(x)) for t in self.powers])

    def predict(self, x) -> np.ndarray:
        return self.design(x) @ self.coef

    def to_dict(self) -> dict:
        return {"response": self.response, "model": self.model, "n": self.n, "r2": self.r2, "r2_adj": self.r2_adj,
                "q2": self.q2, "rmse": self.rmse,
                "coefficients": dict(zip(self.terms, self.coef.tolist(), strict=True))}


def _terms(names: list[str], levels: list[int], kind: str) -> tuple[list[str], list[tuple]]:
    k = len(names)
    terms, powers = ["1"], [()]
    for i in range(k):
        terms.append(names[i])
        powers.append((i,))
    if kind in ("quadratic", "linear + interactions"):
        for i, j in itertools.combinations(range(k), 2):
            terms.append(f"{names[i]}*{names[j]}")
            powers.append((i, j))
    if kind == "quadratic":
        for i in range(k):
            if levels[i] >= 3:
                terms.append(f"{names[i]}^2")
                powers.append((i, i))
    return terms, powers


def fit_surface(x: np.ndarray, y: np.ndarray, names: list[str], response: str) -> Surface:
    """Least-squares quadratic (or smaller, when the runs are too few) in the coded parameters x."""
    ok = np.isfinite(y)
    x, y = x[ok], y[ok]
    levels = [len(np.unique(np.round(x[:, i], 9))) for i in range(x.shape[1])]
    for kind in ("quadratic", "linear + interactions", "linear"):  # the largest model the runs support
        terms, powers = _terms(names, levels, kind)
        s = Surface(response, terms, powers, np.zeros(len(terms)), 0, 0, 0, 0, len(y), kind)
        A = s.design(x)
        if len(y) >= len(terms) + 2 and np.linalg.matrix_rank(A) == len(terms):
            break
    else:
        raise SandtrackError(f"{response}: {len(y)} runs do not support even a linear fit in {len(names)} "
                             "parameters (too few runs, or parameters that vary together)")
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    sse, sst = float(res @ res), float(((y - y.mean()) ** 2).sum())
    n, p = len(y), len(terms)
    hat = np.einsum("ij,ji->i", A, np.linalg.pinv(A))
    press = float(((res / np.maximum(1 - hat, 1e-9)) ** 2).sum())
    s.coef = coef
    s.r2 = 1 - sse / sst if sst > 0 else 1.0
    s.r2_adj = 1 - (1 - s.r2) * (n - 1) / max(n - p, 1)
    s.q2 = 1 - press / sst if sst > 0 else 1.0
    s.rmse = float(np.sqrt(sse / max(n - p, 1)))
    return s


# -- the sweep ------------------------------------------------------------------------------------------
@dataclass
class Criterion:
    name: str  # a column of the table: "angle_error_deg" or a trajectory metric
    response: str  # the response fitted: "angle_deg" or the metric
    target: float  # the response's target (the experiment's angle, or 0)
    weight: float
    scale: float = 1.0


@dataclass
class SweepResult:
    table: pd.DataFrame
    params: list[str]
    criteria: list[Criterion]
    surfaces: dict[str, Surface]
    suggestion: dict
    target_angle_deg: float | None
    warnings: list[str] = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"params": self.params, "target_angle_deg": self.target_angle_deg,
                "criteria": [c.__dict__ for c in self.criteria],
                "runs": self.table.to_dict("records"),
                "surfaces": {k: s.to_dict() for k, s in self.surfaces.items()},
                "suggestion": self.suggestion, "warnings": self.warnings, "seconds": self.seconds}


def _measure_angle(path: str, repose_kw: dict) -> tuple[float, float]:
    from .repose import measure_path, result_angle

    return result_angle(measure_path(path, **repose_kw))


def _compare_run(path: str, exp: pd.DataFrame, dem_kw: dict, cmp_kw: dict) -> dict:
    from .compare import compare
    from .dem import read_dem

    cmp = compare(exp, read_dem(path, **dem_kw), name=Path(path).stem, **cmp_kw)
    out = {m: float(cmp.summary.get(m, float("nan"))) for m in TRAJ_METRICS} | {
        "time_shift_s": cmp.time_shift_s, "flagged": len(cmp.summary["flagged_markers"])}
    if cmp.summary.get("consistent") is not None:
        out |= {"p_value": float(cmp.summary["p_value"]), "consistent": bool(cmp.summary["consistent"])}
    return out


def _run_one(args) -> tuple[int, dict, str | None]:
    i, repose_path, traj_path, exp, repose_kw, dem_kw, cmp_kw = args
    out: dict = {}
    try:
        if repose_path:
            out["angle_deg"], out["angle_sigma_deg"] = _measure_angle(repose_path, repose_kw)
        if traj_path is not None and exp is not None:
            out |= _compare_run(traj_path, exp, dem_kw, cmp_kw)
    except SandtrackError as exc:
        return i, out, str(exc)
    return i, out, None


def run_sweep(runs: pd.DataFrame, params: list[str], target_angle_deg: float | None = None,
              experiment: pd.DataFrame | None = None, metric: str = "rmse_3d_mm_all",
              weights: dict | None = None, repose_kw: dict | None = None, dem_kw: dict | None = None,
              cmp_kw: dict | None = None, workers: int = 1, progress=None) -> SweepResult:
    """Measure, rank and fit a sweep (see module docstring)."""
    import time

    cpu0 = time.process_time()
    if metric not in TRAJ_METRICS:
        raise SandtrackError(f"unknown trajectory metric {metric!r} ({', '.join(TRAJ_METRICS)})")
    if metric == "chi2_reduced" and experiment is not None and (cmp_kw or {}).get("exp_sd_mm") is None:
        from .compare import has_sd

        if not has_sd(experiment):
            raise SandtrackError("ranking by chi2_reduced needs the experiment's uncertainty: its table has no sd "
                                 "columns (an older export); give an assumed sd per axis (--exp-sd-mm)")
    t0 = time.perf_counter()
    weights = {"angle": 1.0, "trajectory": 1.0} | (weights or {})
    table = runs.copy()
    warnings: list[str] = []
    jobs = []
    for i, row in table.reset_index(drop=True).iterrows():
        need_angle = "repose" in table.columns and row.get("repose") and not (
            "angle_deg" in table.columns and pd.notna(row.get("angle_deg")))
        traj = row.get("trajectories") if "trajectories" in table.columns else None
        if need_angle or (traj and experiment is not None):
            jobs.append((i, row["repose"] if need_angle else None, traj, experiment, repose_kw or {}, dem_kw or {},
                         cmp_kw or {}))
    if "trajectories" in table.columns and table["trajectories"].notna().any() and experiment is None:
        warnings.append("trajectory files given but no experiment (--experiment): trajectories not compared")
    results = _map(jobs, workers, progress)
    table = table.reset_index(drop=True)
    for i, out, err in results:
        for k, v in out.items():
            table.loc[i, k] = v
        if err:
            table.loc[i, "error"] = err
            warnings.append(f"run {table.loc[i, 'run']}: {err}")
    t_measure, cpu_measure = time.perf_counter() - t0, time.process_time() - cpu0
    criteria: list[Criterion] = []
    if "angle_deg" in table.columns and table["angle_deg"].notna().any():
        table["angle_deg"] = pd.to_numeric(table["angle_deg"], errors="coerce")
        if target_angle_deg is not None:
            table["angle_error_deg"] = table["angle_deg"] - target_angle_deg
            criteria.append(Criterion("angle_error_deg", "angle_deg", float(target_angle_deg), weights["angle"]))
        else:
            warnings.append("no experiment angle (--target-angle or --experiment-repose): angles fitted, not ranked")
    if metric in table.columns and table[metric].notna().any():
        criteria.append(Criterion(metric, metric, 0.0, weights["trajectory"]))
    if not criteria:
        raise SandtrackError("nothing to rank: give the experiment's angle (--target-angle, --experiment-repose) "
                             "and/or the experiment's trajectories (--experiment) with trajectory files")
    for c in criteria:
        err = np.abs(table[c.name].to_numpy(float))
        med = float(np.nanmedian(err)) if np.isfinite(err).any() else 1.0
        c.scale = med if med > 1e-12 else 1.0
    score = sum(c.weight * np.abs(table[c.name].to_numpy(float)) / c.scale for c in criteria)
    table["score"] = score
    table = table.sort_values("score", kind="stable", na_position="last").reset_index(drop=True)
    table.insert(0, "rank", np.where(table["score"].notna(), np.arange(1, len(table) + 1), np.nan))
    # response surfaces
    coding = Coding.from_runs(table[params].to_numpy(float), params)
    x = coding.code(table[params].to_numpy(float))
    surfaces: dict[str, Surface] = {}
    responses = ["angle_deg"] if "angle_deg" in table.columns else []
    responses += [c.response for c in criteria if c.response != "angle_deg"]
    for r in responses:
        y = table[r].to_numpy(float)
        if np.isfinite(y).sum() >= len(params) + 3:
            surfaces[r] = fit_surface(x, y, params, r)
            if surfaces[r].r2 < 0.8:
                warnings.append(f"{r}: the {surfaces[r].model} surface explains only R² = {surfaces[r].r2:.2f} of the "
                                "runs' variation: trust the ranking more than the suggestion")
        else:
            warnings.append(f"{r}: too few measured runs for a response surface")
    best_x = x[0] if np.isfinite(table["score"].iloc[0]) else np.zeros(len(params))
    suggestion = _suggest(surfaces, criteria, coding, x, best_x)
    t_all, cpu_all = time.perf_counter() - t0, time.process_time() - cpu0
    return SweepResult(table, params, criteria, surfaces, suggestion, target_angle_deg, warnings,
                       {"measure": round(t_measure, 3), "rank_and_fit": round(t_all - t_measure, 3),
                        "total": round(t_all, 3), "measure_cpu": round(cpu_measure, 3),
                        "rank_and_fit_cpu": round(cpu_all - cpu_measure, 3)})


def _map(jobs, workers: int, progress):
    if not jobs:
        return []
    out = []
    if workers > 1 and len(jobs) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as ex:
            for f in as_completed([ex.submit(_run_one, j) for j in jobs]):
                out.append(f.result())
                if progress is not None:
                    progress(len(out), len(jobs))
    else:
        for j in jobs:
            out.append(_run_one(j))
            if progress is not None:
                progress(len(out), len(jobs))
    return sorted(out, key=lambda r: r[0])


def _suggest(surfaces: dict[str, Surface], criteria: list[Criterion], coding: Coding, x_runs: np.ndarray,
             best_x: np.ndarray) -> dict:
    from scipy.optimize import minimize

    usable = [c for c in criteria if c.response in surfaces]
    if not usable:
        return {}
    only_angle = [c.response for c in usable] == ["angle_deg"]

    def objective(xv):  # xv: (n, k) points -> (n,) values
        xv = np.atleast_2d(xv)
        v = TIE_PULL * ((xv - best_x) ** 2).sum(axis=1)
        for c in usable:
            pred = surfaces[c.response].predict(xv)
            if c.response != "angle_deg":
                pred = np.maximum(pred, 0.0)
            v = v + c.weight * ((pred - c.target) / c.scale) ** 2
        return v

    # a dense grid over the box (vectorised), then Nelder-Mead from its best points
    k = x_runs.shape[1]
    n = int(np.clip(round(GRID_POINTS ** (1.0 / k)), 3, 41))
    axes = [np.linspace(-1.0, 1.0, n)] * k
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, k)
    grid = np.vstack([grid, x_runs, best_x])
    vals = objective(grid)
    best_val, best_pt = np.inf, grid[int(np.argmin(vals))]
    for start in grid[np.argsort(vals)[:4]]:
        r = minimize(lambda xv: float(objective(xv)[0]), start, method="Nelder-Mead", bounds=[(-1.0, 1.0)] * k,
                     options={"xatol": 1e-7, "fatol": 1e-12, "maxiter": 2000})
        if r.fun < best_val:
            best_val, best_pt = float(r.fun), np.clip(r.x, -1.0, 1.0)
    xs = best_pt
    real = coding.decode(xs)
    pred = {key: float(sf.predict(xs)[0]) for key, sf in surfaces.items()}
    note = ("the angle alone: many parameter sets give it; this one is nearest the best-ranked run"
            if only_angle else "minimises the weighted criteria on the fitted surfaces")
    return {"params": dict(zip(coding.names, real.tolist(), strict=True)),
            "coded": dict(zip(coding.names, xs.tolist(), strict=True)),
            "predicted": pred, "objective": best_val, "note": note,
            "on_box_edge": [nm for nm, v in zip(coding.names, xs, strict=True) if abs(abs(v) - 1) < 1e-6]}


# -- output ---------------------------------------------------------------------------------------------
def sweep_text(res: SweepResult, max_rows: int = 60) -> str:
    cols = ["rank", "run", *res.params]
    for c in ("angle_deg", "angle_error_deg", *TRAJ_METRICS[:2], "score"):
        if c in res.table.columns and c not in cols:
            cols.append(c)
    lines = []
    if res.target_angle_deg is not None:
        lines.append(f"experiment angle of repose: {res.target_angle_deg:.2f} deg")
    lines.append("criteria: " + "; ".join(f"{c.name} (weight {c.weight:g}, scale {c.scale:.3g})" for c in res.criteria))
    lines.append(f"== runs ranked (best first), {len(res.table)} runs")
    lines.append(res.table[cols].head(max_rows).to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    for s in res.surfaces.values():
        eff = sorted(((t, c) for t, c in zip(s.terms, s.coef, strict=True) if t != "1"), key=lambda tc: -abs(tc[1]))
        lines.append(f"== {s.response}: {s.model} surface, R² {s.r2:.4f} (adjusted {s.r2_adj:.4f}, leave-one-out Q² "
                     f"{s.q2:.4f}), RMSE {s.rmse:.3g}, {s.n} runs")
        lines.append("   effects (coded units): " + ", ".join(f"{t} {c:+.3g}" for t, c in eff[:8]))
    sg = res.suggestion
    if sg:
        lines.append("== suggested parameters: " + ", ".join(f"{k} = {v:.4g}" for k, v in sg["params"].items()))
        lines.append("   predicted: " + ", ".join(f"{k} {v:.3f}" for k, v in sg["predicted"].items())
                     + f" ({sg['note']})")
        if sg["on_box_edge"]:
            lines.append(f"   at the edge of the runs' range for {', '.join(sg['on_box_edge'])}: the best may lie "
                         "beyond it (extend the sweep)")
    lines += [f"! {w}" for w in res.warnings]
    return "\n".join(lines)


def plot_sweep(res: SweepResult, path: str | Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5), constrained_layout=True)
    t = res.table.dropna(subset=["score"]).head(20)
    axes[0, 0].barh(t["run"][::-1], t["score"][::-1], color="tab:blue")
    axes[0, 0].set_xlabel("score (lower is better)")
    axes[0, 0].set_title("best runs")
    ax = axes[0, 1]
    coding = Coding.from_runs(res.table[res.params].to_numpy(float), res.params)
    x = coding.code(res.table[res.params].to_numpy(float))
    for name, s in res.surfaces.items():
        y = res.table[name].to_numpy(float)
        ok = np.isfinite(y)
        ax.plot(y[ok], s.predict(x[ok]), "o", ms=4, label=f"{name}: R² {s.r2:.3f}")
    lim = ax.get_xlim()
    ax.plot(lim, lim, "k-", lw=0.8)
    ax.set_xlabel("measured")
    ax.set_ylabel("response surface")
    ax.legend(fontsize=8)
    ax.set_title("fit of the response surfaces")
    ax = axes[1, 0]
    name = "angle_deg" if "angle_deg" in res.surfaces else next(iter(res.surfaces), None)
    if name and res.suggestion:
        s = res.surfaces[name]
        xs = np.array(list(res.suggestion["coded"].values()))
        grid = np.linspace(-1, 1, 41)
        for i, pname in enumerate(res.params):
            xx = np.tile(xs, (len(grid), 1))
            xx[:, i] = grid
            ax.plot(grid, s.predict(xx), label=pname)
        if name == "angle_deg" and res.target_angle_deg is not None:
            ax.axhline(res.target_angle_deg, color="k", lw=0.8, ls="--", label="experiment")
        ax.set_xlabel("parameter (coded, -1 .. 1 over the runs' range)")
        ax.set_ylabel(name)
        ax.set_title("effects around the suggested set")
        ax.legend(fontsize=8)
    ax = axes[1, 1]
    if "angle_error_deg" in res.table.columns:
        s = res.surfaces.get("angle_deg")
        k = int(np.argmax(np.abs(s.coef[1:1 + len(res.params)]))) if s is not None else 0
        ax.scatter(res.table[res.params[k]], res.table["angle_error_deg"], c=res.table["score"], cmap="viridis_r")
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xlabel(res.params[k])
        ax.set_ylabel("angle error (deg)")
        ax.set_title("angle error against the strongest parameter")
    out = Path(path)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
