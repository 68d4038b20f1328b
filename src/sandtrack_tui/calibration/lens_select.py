"""Lens model selection by cross-validation over whole groups of observations, the candidates compared
pairwise on the same left-out points.

A group is what must be left out together: a board pose (one camera's view of the board in one
frame), a depth plane of a 3D target, a frame of a points table, or a block of neighbouring points.
Every candidate model is fitted with some groups left out and scored on them (pixel error of the
left-out observations), fold by fold, and fitted once on everything for its training error.

Scores are kept per *unit*: a left-out board view, or a block of neighbouring points of a left-out
plane or frame (the score function decides). Every candidate is scored on the same units, so two
models are compared unit by unit (paired): the spread of the units in difficulty cancels. A unit is a
block, never a point: a model's misfit varies smoothly over the image, so neighbouring points share it
and only blocks come near to independent. Blocks within a left-out group give enough units to resolve
a real difference when the groups are few (three depth planes give about 27 blocks, where three
groups could never show any difference significant).

The choice keeps the *simplest* candidate (first in `lens.LENSES` order) that is not significantly
worse than the best (`compare`): Wilcoxon's signed-rank test, one-sided at 5 %, on the units'
differences of squared error sums (ranks: one unit where a model misfits by a factor of hundreds
counts as one unit, not as the whole sample), and a difference too small for the left-out points to
resolve (a mean squared error ratio below exp(1/sqrt(N)), N points) is noise however consistent. The
size of the difference is the ratio of the left-out mean squared errors with a 95 % interval from the
units' spread (a ratio estimator, linearised).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import t as student_t
from scipy.stats import wilcoxon

from ..errors import SandtrackError
from ..lens import AUTO_LENSES, LENSES

FitFn = Callable[[str, np.ndarray], object]  # (lens name, training group ids) -> fitted model
# -> (sse, count) per left-out unit: the same units, in the same order, for every model
ScoreFn = Callable[[object, np.ndarray], tuple[np.ndarray, np.ndarray]]
ALPHA = 0.05  # one-sided level of the paired test


@dataclass
class Candidate:
    lens: str
    parameters: int
    train_rmse_px: float | None = None
    cv_rmse_px: float | None = None
    sse: np.ndarray | None = None  # per left-out unit: sum of squared pixel errors
    count: np.ndarray | None = None  # per left-out unit: observations
    excluded: str | None = None  # why the candidate was not considered
    within_noise: bool = False
    chosen: bool = False
    versus_best: Comparison | None = None
    fitted: object = field(default=None, repr=False)

    def row(self) -> dict:
        out = {"lens": self.lens, "parameters": self.parameters, "train_rmse_px": self.train_rmse_px,
               "cv_rmse_px": self.cv_rmse_px, "within_noise": self.within_noise, "chosen": self.chosen}
        if self.versus_best is not None:
            out["versus_best"] = self.versus_best.row()
        if self.excluded:
            out["excluded"] = self.excluded
        return out


@dataclass
class Comparison:
    """A candidate against the best one on the same left-out units: its left-out RMSE in % above the
    best's (weighted mean over the units, with a 95 % interval from their spread), the units that
    favour it / the best, and the one-sided p-value of "worse than the best"."""
    units: int
    points: int
    excess_pct: float
    interval_pct: tuple[float, float]
    better_in: int
    worse_in: int
    p_value: float
    resolved: bool  # larger than the left-out points can resolve
    significant: bool

    def row(self) -> dict:
        return {"units": self.units, "points": self.points, "rmse_excess_pct": round(self.excess_pct, 2),
                "interval_pct": [round(v, 2) for v in self.interval_pct], "units_better": self.better_in,
                "units_worse": self.worse_in, "p_value": float(f"{self.p_value:.3g}"), "resolved": self.resolved,
                "significant": self.significant}


def folds_of(groups: Sequence, n_folds: int) -> list[np.ndarray]:
    """Groups (in their given order, e.g. time) cut into `n_folds` contiguous runs."""
    g = np.asarray(list(groups))
    return [f for f in np.array_split(g, min(n_folds, len(g))) if len(f)]


def cross_validate(lenses: Sequence[str], groups: Sequence, fit: FitFn, score: ScoreFn, n_folds: int = 5,
                   check: Callable[[str, object], str | None] | None = None) -> list[Candidate]:
    """Fit and score every lens: `fit(lens, training groups)` returns a fitted model (or raises
    SandtrackError / a numerical error when it cannot), `score(model, groups)` the squared error sum and
    count per given group. `check(lens, model fitted on everything)` may exclude a candidate (a reason)."""
    all_groups = np.asarray(list(groups))
    folds = folds_of(all_groups, n_folds)
    out: list[Candidate] = []
    for name in lenses:
        cand = Candidate(lens=name, parameters=LENSES[name].parameters)
        out.append(cand)
        try:
            cand.fitted = fit(name, all_groups)
            sse, cnt = score(cand.fitted, all_groups)
            cand.train_rmse_px = float(np.sqrt(np.sum(sse) / max(np.sum(cnt), 1)))
            reason = check(name, cand.fitted) if check else None
            if reason:
                cand.excluded = reason
                continue
            sse_cv, cnt_cv = [], []
            for test in folds:
                model = fit(name, np.setdiff1d(all_groups, test))
                s, c = score(model, test)
                sse_cv.append(s)
                cnt_cv.append(c)
        except (SandtrackError, np.linalg.LinAlgError, ValueError, FloatingPointError) as exc:
            cand.excluded = f"cannot be fitted ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
            continue
        cand.sse, cand.count = np.concatenate(sse_cv), np.concatenate(cnt_cv)
        if not np.isfinite(cand.sse).all():
            cand.excluded = "left-out points project to no finite pixel"
            continue
        cand.cv_rmse_px = float(np.sqrt(np.sum(cand.sse) / max(np.sum(cand.count), 1)))
    return out


def select_lens(groups: Sequence, fit: FitFn, score: ScoreFn, n_folds: int = 5,
                check: Callable[[str, object], str | None] | None = None,
                lenses: Sequence[str] = AUTO_LENSES) -> tuple[list[Candidate], Candidate]:
    """Cross-validate the candidates and choose one. The combined models (rational-prism, full) are
    tried only when each of the extensions they combine (rational, prism, tilted) did better than
    the standard model on its own; otherwise they are listed as not tried."""
    single = [n for n in lenses if not _combined(n)]
    cands = cross_validate(single, groups, fit, score, n_folds, check)
    by_name = {c.lens: c for c in cands}
    base = by_name.get("standard")
    combos = [n for n in lenses if _combined(n)]
    tried = []
    for name in combos:
        parts = [by_name.get(e) for e in _extensions_of(name)]
        if base is not None and base.cv_rmse_px is not None and all(
                p is not None and p.cv_rmse_px is not None and p.cv_rmse_px < base.cv_rmse_px for p in parts):
            tried.append(name)
    cands += cross_validate(tried, groups, fit, score, n_folds, check)
    for name in combos:
        if name not in tried:
            cands.append(Candidate(lens=name, parameters=LENSES[name].parameters,
                                   excluded="not tried: the extensions it combines did not beat standard"))
    order = list(LENSES)
    cands.sort(key=lambda c: order.index(c.lens))
    return cands, choose(cands)


_EXTENSIONS = ("tilted", "rational", "prism")


def _extensions_of(name: str) -> list[str]:
    terms = set(LENSES[name].terms)
    return [e for e in _EXTENSIONS if set(LENSES[e].terms) <= terms]


def _combined(name: str) -> bool:
    return len(_extensions_of(name)) > 1


def choose(candidates: list[Candidate]) -> Candidate:
    """Mark and return the simplest candidate not significantly worse than the best (module docstring)."""
    scored = [c for c in candidates if c.cv_rmse_px is not None]
    if not scored:
        reasons = "; ".join(f"{c.lens}: {c.excluded}" for c in candidates)
        raise SandtrackError(f"no lens model could be fitted ({reasons})")
    best = best_of(scored)
    for c in scored:
        c.versus_best = compare(c, best)
        c.within_noise = not c.versus_best.significant
    chosen = next(c for c in sorted(scored, key=lambda c: list(LENSES).index(c.lens)) if c.within_noise)
    chosen.chosen = True
    return chosen


def best_of(candidates: list[Candidate]) -> Candidate:
    """The candidate with the smallest left-out RMSE (of those scored)."""
    return min((c for c in candidates if c.cv_rmse_px is not None), key=lambda c: c.cv_rmse_px)


def compare(c: Candidate, best: Candidate) -> Comparison:
    """c against best, unit by unit (see the module docstring and `Comparison`)."""
    n = np.asarray(best.count, dtype=float)
    keep = n > 0
    sse_c = np.asarray(c.sse, dtype=float)[keep]
    sse_b = np.asarray(best.sse, dtype=float)[keep]
    n = n[keep]
    g = len(n)
    ratio = float(sse_c.sum() / max(sse_b.sum(), 1e-300))  # of the left-out mean squared errors
    if g >= 2:  # linearised ratio estimator, its standard error over the units (clusters)
        z = sse_c - ratio * sse_b
        se = float(np.sqrt(g / (g - 1) * np.sum(z ** 2)) / max(sse_b.sum(), 1e-300))
        half = float(student_t.ppf(0.975, g - 1)) * se
    else:
        half = np.inf
    diff = sse_c - sse_b
    tiny = 1e-9 * max(float(np.max(np.abs(sse_b))), 1e-300)
    moved = np.abs(diff) > tiny
    p = 1.0 if c is best or not moved.any() else float(wilcoxon(diff[moved], alternative="greater").pvalue)
    resolved = bool(np.log(max(ratio, 1e-300)) > 1.0 / np.sqrt(n.sum()))

    def pct(r: float) -> float:  # mean squared error ratio -> RMSE in % above the best's
        return 100.0 * (np.sqrt(max(r, 0.0)) - 1.0)

    return Comparison(units=g, points=int(n.sum()), excess_pct=pct(ratio),
                      interval_pct=(pct(ratio - half), pct(ratio + half)), better_in=int(np.sum(diff < -tiny)),
                      worse_in=int(np.sum(diff > tiny)), p_value=p, resolved=resolved,
                      significant=bool(p < ALPHA and resolved))


def report(candidates: list[Candidate], groups_kind: str, n_groups: int, n_folds: int, units_kind: str) -> dict:
    """The selection for the calibration report: how it cross-validated, what it compared (the units),
    the rule, every candidate (with its comparison against the best) and why the chosen one won."""
    chosen = next((c for c in candidates if c.chosen), None)
    some = next((c.versus_best for c in candidates if c.versus_best is not None), None)
    units = f"{some.units} {units_kind} ({some.points} points)" if some else units_kind
    return {"chosen": chosen.lens if chosen else None,
            "cross_validation": f"{n_folds} folds of whole {groups_kind} ({n_groups} in all)",
            "compared": f"paired on the same left-out units: {units}",
            "rule": "simplest model not significantly worse than the best: Wilcoxon signed-rank test, one-sided "
                    f"{100 * ALPHA:g} %, on the units' squared error differences, and a ratio of mean squared errors "
                    "above exp(1/sqrt(points))",
            "why": why(chosen, candidates) if chosen else "", "alpha": ALPHA,
            "candidates": [c.row() for c in candidates]}


def why(chosen: Candidate, candidates: list[Candidate]) -> str:
    """One sentence: against what the chosen model won."""
    order = list(LENSES)
    best = best_of(candidates)
    if chosen is best:
        simpler = [c for c in candidates
                   if c.versus_best is not None and order.index(c.lens) < order.index(chosen.lens)]
        if not simpler:
            return f"{chosen.lens}: the best on the left-out units and the simplest candidate"
        near = min(simpler, key=lambda c: c.versus_best.excess_pct)
        return (f"{chosen.lens}: the best on the left-out units; every simpler model is significantly worse, the "
                f"nearest {near.lens} by {_said(near.versus_best)}")
    return (f"{chosen.lens}: the simplest model not significantly worse than the best, {best.lens} "
            f"({_said(chosen.versus_best)})")


def _said(v: Comparison) -> str:
    return (f"{v.excess_pct:+.1f} % RMSE, 95 % interval {v.interval_pct[0]:+.1f} to {v.interval_pct[1]:+.1f} %, "
            f"worse in {v.worse_in} and better in {v.better_in} of {v.units} units, p = {v.p_value:.2g}")
