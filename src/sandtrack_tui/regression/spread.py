"""The network's honest spread: a standard deviation per world axis (mm) for every prediction of the
MLP and of its residual variant.

How it is made (`fit_spread`, once the predictor is trained): a small network (`SPREAD_HIDDEN`) on the
same standardised pixels learns the log standard deviation per axis by a Gaussian negative
log-likelihood on the errors of the trained, frozen predictor on its training rows. Those rows are the
ones the predictor fitted, so their errors are smaller than on board poses it never saw: the spread
takes its shape over the volume from them and its level from the validation split (whole board poses,
never trained on): each axis is scaled so that ±1.96 sd holds 95 % of the validation errors. The test
split, untouched by both, measures the result (`coverage`, in `train`'s metrics).

What it includes: the network's error on board poses it never saw: approximation and interpolation
between poses, the calibration points' pixel noise as it entered the training points, and for the
residual variant the calibration's own errors that the correction did not learn. With each pixel's sd
(`predict_with_sd`'s `pixel_sd`), the pixel noise becomes the query's own: the calibration points' share
is taken out of the spread and the query's added, both through the predictor's Jacobian. That share is
their reprojection RMSE per image axis (`pixel_sd`: the 2-D RMSE over √2) propagated, but never more
than the spread itself: where the spread is smaller, the points reached the errors less noisy than the
RMSE says (it also holds the calibration's misfit), and the rest of the spread is left whole. A pixel as
noisy as the calibration points (the default when no sd is known) gets the spread as measured on the
held-out poses. What it leaves out: anything the calibration points cannot show. A query outside the
training volume gets no sd (NaN: the network extrapolates, and nothing measured its error there); near
the volume's faces, inside the tolerance `outside_training` allows, the network's extrapolation error is
not in it (the held-out poses lie between training poses, not beyond). Where a calibration gives a
triangulation of the same pixels, `check` tests the MLP against it and gives the sd of both sources of
evidence together (outside the training volume, of the disagreement alone).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .model import MLP, SPREAD_HIDDEN, Z95, RegressionModel, Spread, _inputs, outside_training, predict

SPREAD_EPOCHS = 40
SPREAD_BATCH = 1024
JACOBIAN_STEP_PX = 0.5


def fit_spread(x_std: np.ndarray, err: np.ndarray, train: np.ndarray, val: np.ndarray, seed: int = 0,
               pixel_sd=None, epochs: int = SPREAD_EPOCHS) -> Spread | None:
    """The spread of a predictor from its errors `err` (N, 3) mm = prediction - truth on every row of
    `x_std` (standardised pixels), `train` / `val` masks (see module docstring). None when either split
    has too few finite rows to learn or to scale it."""
    ok = np.isfinite(err).all(axis=1) & np.isfinite(x_std).all(axis=1)
    tr, va = train & ok, val & ok
    if tr.sum() < 20 or va.sum() < 20:
        return None
    err_scale = np.sqrt(np.mean(err[tr] ** 2, axis=0))
    err_scale = np.where(err_scale > 1e-12, err_scale, 1.0)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = MLP(hidden=SPREAD_HIDDEN, dropout=0.0)
        last = net.layers[-1]
        torch.nn.init.zeros_(last.bias)  # start at the training RMS everywhere
        with torch.no_grad():
            last.weight.mul_(0.1)
        _fit_nll(net, x_std[tr], err[tr] / err_scale, epochs, seed)
    spread = Spread(net, err_scale, np.ones(3), np.zeros(4) if pixel_sd is None else np.asarray(pixel_sd, float))
    z = np.abs(err[va]) / spread.sd(x_std[va])
    spread.scale = np.quantile(z, 0.95, axis=0) / Z95
    return spread


def _fit_nll(net: MLP, x: np.ndarray, e: np.ndarray, epochs: int, seed: int) -> None:
    """Adam with cosine decay on the Gaussian negative log-likelihood of e given log sd = net(x):
    mean(2 log sd + e² / sd²) (constants dropped)."""
    xt = torch.as_tensor(x, dtype=torch.float32)
    et = torch.as_tensor(e, dtype=torch.float32)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    steps = max(1, math.ceil(len(xt) / SPREAD_BATCH))
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * steps, eta_min=3e-5)
    gen = torch.Generator().manual_seed(seed)
    net.train()
    for _ in range(epochs):
        perm = torch.randperm(len(xt), generator=gen)
        for b in range(steps):
            idx = perm[b * SPREAD_BATCH:(b + 1) * SPREAD_BATCH]
            log_sd = net(xt[idx])
            loss = torch.mean(2 * log_sd + (et[idx] * torch.exp(-log_sd)) ** 2)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
    net.eval()


def coverage(err: np.ndarray, sd: np.ndarray, k: float = Z95) -> np.ndarray:
    """Fraction (per axis) of errors within ±k sd, over rows where both are finite (NaN: none)."""
    err, sd = np.asarray(err, float).reshape(-1, 3), np.asarray(sd, float).reshape(-1, 3)
    ok = np.isfinite(err).all(axis=1) & np.isfinite(sd).all(axis=1)
    if not ok.any():
        return np.full(3, np.nan)
    return (np.abs(err[ok]) <= k * sd[ok]).mean(axis=0)


def pixel_variance(pixel_sd, n: int) -> np.ndarray:
    """Per-row pixel variances (n, 4) from a scalar, a (4,) or an (n, 4) array of sd in px."""
    sd = np.asarray(pixel_sd, dtype=np.float64)
    return np.broadcast_to(sd ** 2, (n, 4)) if sd.ndim < 2 else (sd.reshape(n, 4) ** 2)


def predict_with_sd(model: RegressionModel, pixels, method: str = "mlp",
                    pixel_sd=None) -> tuple[np.ndarray, np.ndarray]:
    """World XYZ (N, 3) mm and its sd per axis (N, 3) mm for pixels (N, 4: xs, ys, xf, yf), by the
    network ("mlp") or its residual variant. The sd is the method's spread (see module docstring);
    with `pixel_sd` (px: a scalar, per input (4,), or per row (N, 4); NaN: the calibration points' own)
    the pixel noise is the query's own, through the predictor's Jacobian (forward differences of
    JACOBIAN_STEP_PX). sd is NaN where the XYZ is, where the model has no spread for the method (a
    model file from before spreads), and outside the training volume (`outside_training`)."""
    x = _inputs(pixels)
    xyz = predict(model, x, method=method)
    sd = np.full_like(xyz, np.nan)
    spread = model.spreads.get(method)
    ok = np.isfinite(x).all(axis=1) & np.isfinite(xyz).all(axis=1)
    if spread is None or not ok.any():
        return xyz, sd
    var = spread.sd((x[ok] - model.in_mean) / model.in_std) ** 2
    if pixel_sd is not None:
        own = pixel_variance(pixel_sd, len(x))[ok]
        own = np.where(np.isfinite(own), own, spread.pixel_sd ** 2)  # unknown: the calibration points' noise
        # as noisy as the calibration points: the spread as measured on the held-out poses
        rows = ~np.isclose(own, spread.pixel_sd ** 2, rtol=1e-3, atol=0).all(axis=1)
        if rows.any():
            jac2 = jacobian(model, x[ok][rows], xyz[ok][rows], method) ** 2
            inside = np.minimum(var[rows], np.einsum("nak,k->na", jac2, spread.pixel_sd ** 2))
            var[rows] += np.einsum("nak,nk->na", jac2, own[rows]) - inside
    sd[ok] = np.sqrt(var)
    sd[outside_training(model, x, xyz)] = np.nan
    return xyz, sd


def jacobian(model: RegressionModel, x: np.ndarray, xyz: np.ndarray, method: str) -> np.ndarray:
    """d XYZ / d pixel (N, 3, 4) mm/px by forward differences, all four steps in one prediction."""
    n = len(x)
    steps = np.repeat(x[None], 4, axis=0)
    for k in range(4):
        steps[k, :, k] += JACOBIAN_STEP_PX
    moved = predict(model, steps.reshape(-1, 4), method=method).reshape(4, n, 3)
    return ((moved - xyz[None]) / JACOBIAN_STEP_PX).transpose(1, 2, 0)
