"""The lens choice's own uncertainty, added to the bundle adjustment's parameter covariance.

`--lens auto` keeps the simplest lens model that is not significantly worse than the best on left-out
views (lens_select). When the evidence is mixed (a better-fitting model, the difference not significant),
the kept model may still be the wrong one, and the covariance of its parameters, conditional on it, says
nothing of that: a central board leaves a tangential term and the principal point confounded, and the
simpler model moves the principal point by many of its own sd (a rendered session: cx 58 sd off).

The bundle adjustment is run a second time with the better-fitting model for those cameras, from the
kept solution and with the same weights. δ, the change of every camera's parameters (the better model's
extra terms join as parameters whose kept value is 0) that moves the kept solution's pixels of every
observation where the better one puts them, to first order (least squares through the Jacobian, the
board poses free), estimates the kept model's bias, and δδᵀ joins the covariance: Σ_kept + δδᵀ, whose
expectation for nested models is about the better model's own covariance plus the kept model's squared
bias. The two solutions' own parameter difference is not used: two models can trade terms along
directions that move no pixel (a tilted sensor against the principal point: on a real target 40 times
the held-out error), which a first-order propagation would take for real. Where the kept model is the
best on the left-out data, nothing is added.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import Camera, CameraUncertainty
from ..lens import LENSES
from .bundle import BundleState, Observations, bundle_adjust, first_order_change, project_all
from .point_uncertainty import parameter_names, pixel_jacobian


@dataclass
class ModelChoiceSpread:
    labels: list[tuple[int, str]]  # the covariance's parameters, the better models' extra terms appended
    covariance: np.ndarray  # Σ_kept + δδᵀ over `labels`
    state: BundleState  # the kept solution, distortion vectors long enough for the extra terms
    report: dict  # per camera: kept, better-fitting, the bundle's RMSE of both, the largest shifts in sd


def lens_choice_spread(state: BundleState, obs: Observations, labels: list[tuple[int, str]], covariance: np.ndarray,
                       better: dict[int, str], names: list[str], weights: np.ndarray | None = None,
                       kept: dict[int, str] | None = None) -> ModelChoiceSpread:
    """Σ_kept + δδᵀ (module docstring). better: camera index -> the better-fitting lens name of the
    cameras whose choice kept a simpler model; labels / covariance: `bundle.parameter_covariance`'s."""
    kept_state = state.copy()
    kept_state.dist_free = [state.free_mask(c) for c in range(len(state.models))]
    alt = kept_state.copy()
    for c, name in better.items():
        lens = LENSES[name]
        n = max(len(state.dist[c]), lens.length)
        kept_state.dist[c] = np.pad(state.dist[c], (0, n - len(state.dist[c])))
        kept_state.dist_free[c] = np.pad(kept_state.dist_free[c], (0, n - len(state.dist[c])))
        alt.dist_free[c] = np.pad(lens.free, (0, n - lens.length))
        alt.dist[c] = np.where(alt.dist_free[c], kept_state.dist[c], 0.0)
    alt, info = bundle_adjust(alt, obs, free_intrinsics=True, weights=weights)
    union = kept_state.copy()
    union.dist_free = [kept_state.free_mask(c) | (alt.free_mask(c) if c in better else False)
                       for c in range(len(state.models))]
    change = first_order_change(union, obs, project_all(alt, obs), weights)
    all_labels = list(labels) + [p for p in change if p not in set(labels)]
    delta = np.array([change.get(p, 0.0) for p in all_labels])
    if not np.isfinite(delta).all():
        raise ValueError("the better model's fit gave no finite change")
    report = {}
    for c, name in better.items():
        mine = [i for i, (ci, _) in enumerate(all_labels) if ci == c]  # its kept parameters first
        variance = np.diag(covariance)[[i for i in mine if i < len(labels)]]
        report[names[c]] = {"kept": (kept or {}).get(c), "better_fitting": name,
                            "bundle_rmse_px_better_fitting": info["rmse_px"],
                            "shift_of_better_fitting": shifts([all_labels[i][1] for i in mine], delta[mine], variance)}
    return ModelChoiceSpread(all_labels, with_spread(covariance, delta), kept_state, report)


def with_spread(covariance: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Σ (its parameters first, the extra ones at zero variance) + δδᵀ."""
    k = len(covariance)
    out = np.outer(delta, delta)
    out[:k, :k] += covariance
    return out


def shifts(names: list[str], delta: np.ndarray, variance: np.ndarray) -> dict:
    """The camera matrix's change from the kept model to the better-fitting one, in px and in the kept
    model's own sd (variance: of the first len(variance) names)."""
    out = {}
    for i, p in enumerate(names):
        if p in ("fx", "fy", "cx", "cy"):
            sd = float(np.sqrt(variance[i])) if i < len(variance) and variance[i] > 0 else None
            out[p] = {"value": round(float(delta[i]), 4), "in_kept_sd": None if sd is None else
                      round(float(delta[i]) / sd, 2)}
    return out


def spread_line(kept: str | None, better: str, moved: dict) -> str:
    """One line for the calibration's report: what the XYZ sd now holds, and how far apart the two were."""
    far = max(((p, v) for p, v in moved.items() if v.get("in_kept_sd") is not None),
              key=lambda pv: abs(pv[1]["in_kept_sd"]), default=None)
    apart = (f"; {far[0]} {far[1]['value']:+.2f} px apart ({abs(far[1]['in_kept_sd']):.1f} of the kept model's sd)"
             if far else "")
    return (f"the XYZ sd holds the lens choice's spread: {better} fitted the left-out data better than the kept "
            f"{kept or 'model'}, not significantly{apart}")


def point_fit_spread(unc: CameraUncertainty, cam: Camera, better: Camera,
                     X: np.ndarray) -> tuple[CameraUncertainty, dict]:
    """The same for a camera fitted to known points X (`from_points`): `unc` of the kept camera `cam` plus
    δδᵀ over the parameters of both (pose world -> camera, camera matrix, lens terms), δ the change of
    `cam`'s parameters that moves its pixels of X, to first order, where `better` puts them (least squares
    through d(pixel) / d(parameters)): the two models' parameters themselves can differ along directions
    that move no pixel (a tilted sensor against the principal point), which a first-order propagation of
    their difference would take for real. `cam`'s distortion vector is lengthened in place (zeros) to hold
    the better model's extra terms. Returns it with the camera matrix's `shifts`."""
    names = list(unc.parameters) + [p for p in parameter_names(better) if p not in set(unc.parameters)]
    n = max(len(cam.distortion), len(better.distortion))
    cam.distortion = np.pad(cam.distortion, (0, n - len(cam.distortion)))
    X = X[np.isfinite(X).all(axis=1)]
    moved = (better.project(X) - cam.project(X)).ravel()
    ok = np.isfinite(moved)
    delta = np.linalg.lstsq(pixel_jacobian(cam, names, X)[ok], moved[ok], rcond=None)[0]
    if not np.isfinite(delta).all():
        raise ValueError("the better model's fit gave no finite change")
    spread = CameraUncertainty(names, with_spread(unc.covariance, delta), unc.sigma_px, unc.noise_px,
                               better_lens=better.lens)
    return spread, shifts(names, delta, np.diag(unc.covariance))
