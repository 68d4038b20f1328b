"""Lens model selection by cross-validation over whole groups of observations.

A group is what must be left out together: a board pose (one camera's view of the board in one
frame), a depth plane of a 3D target, a frame of a points table, or a block of neighbouring points.
Every candidate model is fitted with some groups left out and scored on them (pixel error of the
left-out observations), fold by fold, and fitted once on everything for its training error.

The choice keeps the *simplest* candidate (first in `lens.LENSES` order) that is not worse than the
best one beyond noise (`excess_over`). "Worse" is compared group by group (both models are scored on
the same left-out groups, so the groups' own spread in difficulty cancels), as the log ratio of their
mean squared errors, with its standard error taken over the groups: observations of one group share
their errors, so groups, not points, are the independent units.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import t as student_t

from ..errors import SandtrackError
from ..lens import AUTO_LENSES, LENSES

FitFn = Callable[[str, np.ndarray], object]  # (lens name, training group ids) -> fitted model
ScoreFn = Callable[[object, np.ndarray], tuple[np.ndarray, np.ndarray]]  # -> (sse, count) per group


@dataclass
class Candidate:
    lens: str
    parameters: int
    train_rmse_px: float | None = None
    cv_rmse_px: float | None = None
    sse: np.ndarray | None = None  # per left-out group: sum of squared pixel errors
    count: np.ndarray | None = None  # per left-out group: observations
    excluded: str | None = None  # why the candidate was not considered
    within_noise: bool = False
    chosen: bool = False
    fitted: object = field(default=None, repr=False)

    def row(self) -> dict:
        out = {"lens": self.lens, "parameters": self.parameters, "train_rmse_px": self.train_rmse_px,
               "cv_rmse_px": self.cv_rmse_px, "within_noise": self.within_noise, "chosen": self.chosen}
        if self.excluded:
            out["excluded"] = self.excluded
        return out


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
    """Mark and return the simplest candidate within noise of the best (see the module docstring)."""
    scored = [c for c in candidates if c.cv_rmse_px is not None]
    if not scored:
        reasons = "; ".join(f"{c.lens}: {c.excluded}" for c in candidates)
        raise SandtrackError(f"no lens model could be fitted ({reasons})")
    best = min(scored, key=lambda c: c.cv_rmse_px)
    for c in scored:
        excess, limit = excess_over(c, best)
        c.within_noise = excess <= limit
    chosen = next(c for c in sorted(scored, key=lambda c: list(LENSES).index(c.lens)) if c.within_noise)
    chosen.chosen = True
    return chosen


def excess_over(c: Candidate, best: Candidate) -> tuple[float, float]:
    """How much worse c is than best on the left-out groups, and the most that still counts as noise,
    both as log ratios of mean squared errors.

    The excess is the mean over groups (weighted by their observations) of the log ratio of the two
    models' mean squared errors: logs, because a model's misfit grows by factors from one group to the
    next (a view reaching into the image corner), which would swamp a plain mean and its spread. The
    limit is the larger of the paired difference's standard error times Student's t (97.5 %, groups - 1
    degrees of freedom; about 2 for many groups) and 1/sqrt(N), the sampling noise of a mean squared
    error over N left-out observations: a difference that small is not resolved however consistent."""
    n = np.asarray(best.count, dtype=float)
    keep = n > 0
    n = n[keep]
    mse_c = np.asarray(c.sse, dtype=float)[keep] / n
    mse_b = np.asarray(best.sse, dtype=float)[keep] / n
    floor = 1e-12 + 1e-6 * float(np.mean(mse_b))
    delta = np.log((mse_c + floor) / (mse_b + floor))
    w = n / n.sum()
    mean = float(np.sum(w * delta))
    g = len(delta)
    resolution = 1.0 / np.sqrt(n.sum())
    if g < 2:
        return mean, resolution
    se = float(np.sqrt(g / (g - 1) * np.sum((w * (delta - mean)) ** 2)))
    return mean, max(float(student_t.ppf(0.975, g - 1)) * se, resolution)


def report(candidates: list[Candidate], groups_kind: str, n_groups: int, n_folds: int) -> dict:
    chosen = next((c.lens for c in candidates if c.chosen), None)
    return {"chosen": chosen, "cross_validation": f"{n_folds} folds of whole {groups_kind} ({n_groups} in all)",
            "rule": "simplest model not worse than the best beyond noise: t(97.5 %) standard errors of the "
                    "paired log ratio of mean squared errors over the left-out groups, at least 1/sqrt(points)",
            "candidates": [c.row() for c in candidates]}
