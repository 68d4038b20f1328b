"""Training the pixel -> XYZ MLP (the study's recipe) and measuring it against triangulation.

Recipe: inputs (xs, ys, xf, yf) and outputs (X, Y, Z) standardised with the training set's mean
and SD; MLP 4-512-1024-256-3 with ReLU and dropout; Adam on the mean squared error with a cosine
learning-rate decay; early stopping on the validation set's mean error (mm) once the rate has decayed
to half, keeping the best weights. Train / validation / test sets are split by frame (whole board poses),
so neighbouring corners of one pose never leak from training into the test figures.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
import torch
from scipy.spatial import ConvexHull, QhullError

from ..cores import usable_cores
from ..errors import SandtrackError
from .dataset import INPUTS, TARGETS, check_points, split_by_frame
from .model import MLP, SPREAD_HIDDEN, STUDY_HIDDEN, RegressionModel, hull_distance, outside_training, predict

ProgressFn = Callable[[int, float, float], None]  # (epoch, train loss, validation mean error mm)
StopFn = Callable[[], bool]
# torch's RNG and thread count are process-wide: one training at a time keeps each run reproducible.
_TRAIN_LOCK = threading.Lock()


@dataclass
class TrainConfig:
    hidden: tuple[int, ...] = STUDY_HIDDEN
    dropout: float = 0.01  # measured on 44k points: 0 -> 0.80 mm, 0.01 -> 0.90 mm, 0.05 -> 1.29 mm mean error
    epochs: int = 30
    batch_size: int = 512  # measured on 44k points, 30 epochs: 1024 -> 0.90 mm, 512 -> 0.77 mm, same CPU time
    lr: float = 2e-3
    lr_final_frac: float = 0.01  # cosine decay from lr to lr * lr_final_frac
    weight_decay: float = 0.0
    patience: int = 10  # epochs without a better validation error before stopping (once the rate is at half)
    val_frac: float = 0.15
    test_frac: float = 0.15
    seed: int = 0
    residual: bool = True  # also train the residual variant when a calibration is given
    residual_epochs: int = 20
    residual_hidden: tuple[int, ...] = (256, 256)  # the correction is smooth and small: a light net suffices
    spread_epochs: int = 40  # the spread's small net per method (see spread.py); 0: no spread
    device: str | None = None  # None: CUDA when present, else CPU
    threads: int | None = None  # CPU threads; None: all cores, or 1 when they are busy (see _fastest_threads)

    @classmethod
    def fast(cls, **kw) -> TrainConfig:
        """A quick configuration for tests and previews (same shape, few epochs)."""
        base = {"epochs": 6, "residual_epochs": 3, "patience": 6, "batch_size": 256, "spread_epochs": 15}
        return cls(**{**base, **kw})

    def total_epochs(self, with_residual: bool) -> int:
        return self.epochs + (self.residual_epochs if with_residual and self.residual else 0)


def pick_device(name: str | None = None) -> torch.device:
    if name:
        return torch.device(name)
    if torch.cuda.is_available():
        return torch.device("cuda")
    return torch.device("cpu")


def train(points: pd.DataFrame, config: TrainConfig | None = None, calibration=None,
          progress: ProgressFn | None = None, should_stop: StopFn | None = None) -> RegressionModel:
    """Train on calibration points (points.csv columns). With a calibration, the test figures
    include triangulation on the same rows and (if config.residual) the residual variant.
    `progress(epoch, loss, val_mm)` is called after every epoch (numbered across both phases, see
    TrainConfig.total_epochs); `should_stop()` is polled during training and ends it early,
    keeping the best weights so far (metrics["stopped"] says why training ended)."""
    cfg = config or TrainConfig()
    df = check_points(points)
    t0, cpu0 = time.perf_counter(), time.process_time()
    device = pick_device(cfg.device)
    x = df[INPUTS].to_numpy(np.float64)
    y = df[TARGETS].to_numpy(np.float64)
    tr, va, te = split_by_frame(df["frame"].to_numpy(), cfg.val_frac, cfg.test_frac, cfg.seed)
    if tr.sum() < 10:
        raise SandtrackError(f"too few calibration points to train on ({len(df)})")
    in_mean, in_std = x[tr].mean(0), _safe_std(x[tr])
    out_mean, out_std = y[tr].mean(0), _safe_std(y[tr])
    xn = (x - in_mean) / in_std

    with _TRAIN_LOCK, torch.random.fork_rng(devices=[]):  # deterministic; leaves the caller's RNG alone
        threads_before = torch.get_num_threads()
        try:
            model, tri, info = _train_phases(cfg, calibration, device, x, y, xn, tr, va, in_mean, in_std,
                                             out_mean, out_std, progress, should_stop)
            threads = torch.get_num_threads()
        finally:
            torch.set_num_threads(threads_before)
    train_seconds = time.perf_counter() - t0
    info["cpu_seconds"] = time.process_time() - cpu0  # with busy cores, wall time says little
    model.metrics = _metrics(model, df, tr, va, te, x, y, tri, info, train_seconds, device, threads)
    return model


def _train_phases(cfg, calibration, device, x, y, xn, tr, va, in_mean, in_std, out_mean, out_std, progress,
                  should_stop):
    if device.type == "cpu":
        torch.set_num_threads(_fastest_threads(cfg, device) if cfg.threads is None else cfg.threads)
    torch.manual_seed(cfg.seed)
    net, info = _fit(xn[tr], (y[tr] - out_mean) / out_std, xn[va], y[va], out_mean, out_std, cfg,
                     cfg.epochs, device, progress, should_stop, epoch0=0)
    model = RegressionModel(
        net=net.cpu().eval(), in_mean=in_mean, in_std=in_std, out_mean=out_mean, out_std=out_std,
        in_min=x[tr].min(0), in_max=x[tr].max(0), hull=_hull(y[tr]),
        config=_config_dict(cfg))
    tri = None
    if calibration is not None:
        tri = _triangulate(calibration, x)
    if tri is not None and cfg.residual and cfg.residual_epochs > 0 and info["stopped"] != "user":
        res = y - tri
        ok = np.isfinite(res).all(axis=1)
        res_mean, res_std = res[tr & ok].mean(0), _safe_std(res[tr & ok])
        rnet, rinfo = _fit(xn[tr & ok], (res[tr & ok] - res_mean) / res_std, xn[va & ok],
                           res[va & ok], res_mean, res_std, cfg, cfg.residual_epochs, device, progress,
                           should_stop, epoch0=info["epochs_run"], hidden=cfg.residual_hidden)
        model.residual_net = rnet.cpu().eval()
        model.res_mean, model.res_std = res_mean, res_std
        model.calibration_toml = calibration.to_toml()
        info["residual_epochs_run"] = rinfo["epochs_run"]
        if rinfo["stopped"] == "user":
            info["stopped"] = "user"
    if cfg.spread_epochs > 0:
        _fit_spreads(model, cfg, calibration, x, y, xn, tr, va)
    return model, tri, info


def _fit_spreads(model: RegressionModel, cfg: TrainConfig, calibration, x, y, xn, tr, va) -> None:
    """Each method's spread (spread.py), from its errors on the training and validation rows; the
    calibration's reprojection RMSE per camera, per image axis (a 2-D distance over √2, as `xyz` takes a
    pixel's default sd), is the pixel noise of the points, inside the spread."""
    from .spread import fit_spread

    rmse = [getattr(calibration.cameras.get(c), "rmse_px", None) if calibration is not None else None
            for c in ("side", "front")]
    pixel_sd = np.repeat([r / math.sqrt(2.0) if r is not None and np.isfinite(r) else 0.0 for r in rmse], 2)
    methods = ["mlp", "residual"] if model.has_residual else ["mlp"]
    for m in methods:
        spread = fit_spread(xn, predict(model, x, method=m) - y, tr, va, seed=cfg.seed, pixel_sd=pixel_sd,
                            epochs=cfg.spread_epochs)
        if spread is not None:
            model.spreads[m] = spread


def _fastest_threads(cfg: TrainConfig, device) -> int:
    """All cores, unless other processes keep them busy: then OpenMP threads wait on each other and one
    thread trains faster (measured: 4x on 2 busy cores). Decided by timing a few training steps."""
    n = usable_cores()
    if n <= 1:
        return 1
    probe = MLP(hidden=cfg.hidden, dropout=cfg.dropout).to(device)
    opt = torch.optim.Adam(probe.parameters(), lr=1e-4)
    xb = torch.zeros((cfg.batch_size, 4), device=device)
    timing = {}
    for threads in (n, 1, n):
        torch.set_num_threads(threads)
        t = time.perf_counter()
        for _ in range(3):
            opt.zero_grad(set_to_none=True)
            probe(xb).square().mean().backward()
            opt.step()
        timing[threads] = time.perf_counter() - t  # the second n-thread round is the warm one
    return n if timing[n] <= 1.2 * timing[1] else 1


def _safe_std(a: np.ndarray) -> np.ndarray:
    s = a.std(0)
    return np.where(s > 1e-12, s, 1.0)


def _config_dict(cfg: TrainConfig) -> dict:
    d = asdict(cfg)
    d["hidden"] = list(cfg.hidden)
    d["residual_hidden"] = list(cfg.residual_hidden)
    d["spread_hidden"] = list(SPREAD_HIDDEN)
    d["device"] = cfg.device or ""
    return d


def _fit(x_tr, y_tr, x_va, y_va_mm, out_mean, out_std, cfg: TrainConfig, epochs: int, device,
         progress, should_stop, epoch0: int, hidden=None):
    """Adam + cosine decay + early stopping on the validation mean error (mm), counted once the rate has
    decayed to half. Returns the best net."""
    net = MLP(hidden=hidden or cfg.hidden, dropout=cfg.dropout).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(epochs, 1), eta_min=cfg.lr * cfg.lr_final_frac)
    xt = torch.as_tensor(x_tr, dtype=torch.float32, device=device)
    yt = torch.as_tensor(y_tr, dtype=torch.float32, device=device)
    gen = torch.Generator().manual_seed(cfg.seed + epoch0)
    n = len(xt)
    best_err, best_state, best_epoch, stale = math.inf, None, 0, 0
    stopped, epoch = "max_epochs", 0
    batches = max(1, math.ceil(n / cfg.batch_size))
    for epoch in range(1, epochs + 1):
        net.train()
        perm = torch.randperm(n, generator=gen).to(device)
        total = 0.0
        for b in range(batches):
            idx = perm[b * cfg.batch_size:(b + 1) * cfg.batch_size]
            opt.zero_grad(set_to_none=True)
            loss = torch.mean((net(xt[idx]) - yt[idx]) ** 2)
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
            if should_stop is not None and b % 16 == 15 and should_stop():
                stopped = "user"
                break
        sched.step()
        if stopped == "user" and best_state is not None:
            break
        val_err = _val_error(net, x_va, y_va_mm, out_mean, out_std) if len(x_va) else total / n
        if val_err < best_err:
            best_err, best_state, best_epoch, stale = val_err, copy.deepcopy(net.state_dict()), epoch, 0
        elif opt.param_groups[0]["lr"] <= 0.5 * cfg.lr:
            # while the rate is high the validation error wanders; the decay that follows is where a
            # longer run gains, so only its second half counts towards stopping
            stale += 1
        if progress is not None:
            progress(epoch0 + epoch, total / n, float(val_err))
        if stopped == "user" or (should_stop is not None and should_stop()):
            stopped = "user"
            break
        if stale >= cfg.patience:
            stopped = "early_stopping"
            break
    if best_state is not None:
        net.load_state_dict(best_state)
    net.eval()
    return net, {"epochs_run": epoch, "best_epoch": best_epoch, "stopped": stopped,
                 "best_val_mm": float(best_err)}


def _val_error(net, x_va, y_va_mm, out_mean, out_std) -> float:
    from .model import _forward

    pred = _forward(net, x_va, allow_numpy=False) * out_std + out_mean
    return float(np.linalg.norm(pred - y_va_mm, axis=1).mean())


def _hull(xyz: np.ndarray) -> np.ndarray:
    try:
        return ConvexHull(xyz).equations
    except (QhullError, ValueError):
        return np.zeros((0, 4))  # flat or too few points: no hull test


def _triangulate(calibration, x: np.ndarray) -> np.ndarray | None:
    from ..triangulation import triangulate

    missing = [c for c in ("side", "front") if c not in calibration.cameras]
    if missing:
        raise SandtrackError(f"calibration has no camera named {', '.join(missing)} (needs side and front)")
    pts, _ = triangulate(calibration, {"side": x[:, :2], "front": x[:, 2:]}, world=True)
    return pts


def error_stats(pred: np.ndarray, truth: np.ndarray, prefix: str) -> dict:
    """Mean/SD/median/p95 of the 3-D error (mm) and R² per axis, keys prefixed by `prefix`."""
    err = np.linalg.norm(pred - truth, axis=1)
    err = err[np.isfinite(err)]
    if len(err) == 0:
        return {}
    out = {f"{prefix}_mean_error_mm": float(err.mean()), f"{prefix}_sd_mm": float(err.std(ddof=1) if len(err) > 1
                                                                                   else 0.0),
           f"{prefix}_median_mm": float(np.median(err)), f"{prefix}_p95_mm": float(np.percentile(err, 95))}
    ok = np.isfinite(pred).all(axis=1)
    for i, axis in enumerate("xyz"):
        ss_res = np.sum((truth[ok, i] - pred[ok, i]) ** 2)
        ss_tot = np.sum((truth[ok, i] - truth[ok, i].mean()) ** 2)
        out[f"{prefix}_r2_{axis}"] = float(1 - ss_res / ss_tot) if ss_tot > 0 else float("nan")
    return out


def _coverage_metrics(model: RegressionModel, x: np.ndarray, y: np.ndarray) -> dict:
    """Per method with a spread: the share of test errors within its 95 % interval (±1.96 sd) and the
    median sd, per axis; over test rows inside the training volume (outside, sd is NaN)."""
    from .spread import coverage, predict_with_sd

    out = {}
    for m in model.spreads:
        pred, sd = predict_with_sd(model, x, m)
        cov = coverage(pred - y, sd)
        for k, axis in enumerate("xyz"):
            out[f"{m}_coverage95_pct_{axis}"] = float(100.0 * cov[k])
            out[f"{m}_sd_median_mm_{axis}"] = float(np.nanmedian(sd[:, k])) if np.isfinite(sd[:, k]).any() \
                else float("nan")
    return out


def _metrics(model, df, tr, va, te, x, y, tri, info, train_seconds, device, threads) -> dict:
    m = {"points": int(len(df)), "train_points": int(tr.sum()), "val_points": int(va.sum()),
         "test_points": int(te.sum()), "frames": int(df["frame"].nunique()),
         "test_frames": int(df.loc[te, "frame"].nunique())}
    pred = predict(model, x[te])
    mlp = error_stats(pred, y[te], "mlp")
    m.update(mlp)
    for axis in "xyz":  # the study's names for the MLP's R²
        m[f"r2_{axis}"] = mlp.get(f"mlp_r2_{axis}", float("nan"))
    base = np.broadcast_to(model.out_mean, y[te].shape)
    m["baseline_mean_error_mm"] = float(np.linalg.norm(base - y[te], axis=1).mean())
    if tri is not None:
        m.update(error_stats(tri[te], y[te], "triangulation"))
        if model.has_residual:
            m.update(error_stats(predict(model, x[te], method="residual"), y[te], "residual"))
    m.update(_coverage_metrics(model, x[te], y[te]))
    m["test_outside_bounds"] = int(outside_training(model, x[te]).sum())
    m["test_outside_hull"] = int((hull_distance(model, y[te]) > 0).sum())
    m.update({"epochs_run": int(info["epochs_run"]), "best_epoch": int(info["best_epoch"]),
              "stopped": info["stopped"], "train_seconds": float(train_seconds),
              "train_cpu_seconds": float(info["cpu_seconds"]), "device": device.type,
              "threads": int(threads)})
    if "residual_epochs_run" in info:
        m["residual_epochs_run"] = int(info["residual_epochs_run"])
    return m
