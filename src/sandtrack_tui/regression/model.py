"""The pixel -> XYZ regression model: an MLP of the study's shape, its normalisation, and the
self-contained model file.

Model file (`.pt`, written by `torch.save`, loadable with ``torch.load(weights_only=True)``): a dict
of plain values and tensors only::

    format: "sandtrack-regression", version: 3 (version 1 files load without a spread; version 2 stored
        the spread's pixel_sd as the 2-D RMSE, read per image axis)
    config: training settings (hidden sizes, dropout, epochs, batch size, seed, ...)
    state_dict: MLP weights (4 pixel inputs xs, ys, xf, yf -> 3 outputs X, Y, Z in mm; layers.N.weight/bias)
    normalisation: in_mean, in_std (px), out_mean, out_std (mm)
    bounds: in_min, in_max: per-input range of the training pixels
    hull: (F, 4) half-spaces of the convex hull of the training XYZ (n . x + d <= 0 inside)
    metrics: test-set figures (see train.metrics)
    residual: None, or {state_dict, res_mean, res_std, calibration_toml}: a second, lighter MLP
        (config residual_hidden) that learns the correction (truth - triangulation, mm) on top of
        triangulation with that calibration
    spread: {"mlp": ..., "residual": ...} (version 2): per method a small net (standardised pixels -> log sd
        per axis), err_scale (3, mm), scale (3, the validation split's factor), pixel_sd (4, px per image
        axis: the calibration points' pixel noise inside the spread) and hidden; see `spread`

The MLP only interpolates: outside the volume the training board covered its errors grow fast
(tens of mm), so `outside_training` flags such queries.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..errors import SandtrackError

FORMAT = "sandtrack-regression"
VERSION = 3
STUDY_HIDDEN = (512, 1024, 256)
BOUNDS_MARGIN = 0.02  # fraction of the training range tolerated beyond it, per input
HULL_TOLERANCE_MM = 5.0  # distance outside the training hull still counted as inside
SMALL_BATCH = 256  # rows up to which inference runs in numpy
SPREAD_HIDDEN = (64, 64)
Z95 = 1.959963984540054  # two-sided 95 % quantile of the normal distribution


class MLP(nn.Module):
    """in -> hidden... -> out, ReLU and dropout after each hidden layer."""

    def __init__(self, n_in: int = 4, n_out: int = 3, hidden=STUDY_HIDDEN, dropout: float = 0.1):
        super().__init__()
        layers: list[nn.Module] = []
        width = n_in
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            if dropout > 0:
                layers.append(nn.Dropout(dropout))
            width = h
        layers.append(nn.Linear(width, n_out))
        self.layers = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)


@dataclass
class Spread:
    net: MLP  # standardised pixels -> log sd per axis, in units of err_scale
    err_scale: np.ndarray  # (3,) mm: RMS training error per axis
    scale: np.ndarray  # (3,) the validation split's factor per axis
    pixel_sd: np.ndarray  # (4,) px (xs, ys, xf, yf): pixel noise already inside the spread; 0 where unknown

    def sd(self, x_std: np.ndarray) -> np.ndarray:
        """sd (N, 3) mm for standardised pixels (N, 4)."""
        log_sd = np.clip(_forward(self.net, x_std), -20.0, 20.0)
        return np.exp(log_sd) * self.err_scale * self.scale

    def to_doc(self) -> dict:
        def t(a):
            return torch.as_tensor(np.asarray(a, dtype=np.float64))

        return {"state_dict": {k: v.detach().cpu() for k, v in self.net.state_dict().items()},
                "hidden": list(_hidden(self.net)), "err_scale": t(self.err_scale), "scale": t(self.scale),
                "pixel_sd": t(self.pixel_sd)}

    @classmethod
    def from_doc(cls, doc: dict) -> Spread:
        net = MLP(hidden=tuple(int(h) for h in doc["hidden"]), dropout=0.0)
        net.load_state_dict(doc["state_dict"])
        net.eval()
        return cls(net, doc["err_scale"].numpy(), doc["scale"].numpy(), doc["pixel_sd"].numpy())


def _hidden(net: MLP) -> tuple[int, ...]:
    linear = [m for m in net.layers if isinstance(m, nn.Linear)]
    return tuple(m.out_features for m in linear[:-1])


@dataclass
class RegressionModel:
    net: MLP
    in_mean: np.ndarray
    in_std: np.ndarray
    out_mean: np.ndarray
    out_std: np.ndarray
    in_min: np.ndarray
    in_max: np.ndarray
    hull: np.ndarray  # (F, 4)
    config: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    residual_net: MLP | None = None
    res_mean: np.ndarray | None = None
    res_std: np.ndarray | None = None
    calibration_toml: str | None = None
    spreads: dict[str, Spread] = field(default_factory=dict)  # method -> its spread (see `spread`)
    _calibration: object = field(default=None, repr=False)

    @property
    def has_residual(self) -> bool:
        return self.residual_net is not None and self.calibration_toml is not None

    @property
    def calibration(self):
        """The calibration the residual variant was trained on top of (None without residual)."""
        if self._calibration is None and self.calibration_toml:
            from ..camera import Calibration

            self._calibration = Calibration.from_toml(self.calibration_toml, source="model calibration")
        return self._calibration

    def save(self, path: str | Path) -> None:
        def t(a):
            return torch.as_tensor(np.asarray(a, dtype=np.float64))

        doc = {
            "format": FORMAT,
            "version": VERSION,
            "config": dict(self.config),
            "state_dict": {k: v.detach().cpu() for k, v in self.net.state_dict().items()},
            "normalisation": {"in_mean": t(self.in_mean), "in_std": t(self.in_std),
                              "out_mean": t(self.out_mean), "out_std": t(self.out_std)},
            "bounds": {"in_min": t(self.in_min), "in_max": t(self.in_max)},
            "hull": t(self.hull),
            "metrics": {k: v for k, v in self.metrics.items() if isinstance(v, (int, float, str, bool))},
            "residual": None,
            "spread": {m: sp.to_doc() for m, sp in self.spreads.items()},
        }
        if self.has_residual:
            doc["residual"] = {
                "state_dict": {k: v.detach().cpu() for k, v in self.residual_net.state_dict().items()},
                "res_mean": t(self.res_mean), "res_std": t(self.res_std),
                "calibration_toml": self.calibration_toml,
            }
        p = Path(path)
        tmp = p.with_name(p.name + ".tmp")
        try:
            torch.save(doc, tmp)
            tmp.replace(p)  # atomic: a killed process never leaves a half-written model
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise SandtrackError(f"cannot write model file {p}: {exc.strerror}") from None


def load_model(path: str | Path) -> RegressionModel:
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"model file not found: {p}")
    try:
        doc = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for damaged or foreign files
        raise SandtrackError(f"{p}: not a readable model file ({type(exc).__name__})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise SandtrackError(f"{p}: not a sandtrack regression model")
    if int(doc.get("version", 0)) > VERSION:
        raise SandtrackError(f"{p}: made by a newer sandtrack (model version {doc['version']}); upgrade")
    try:
        cfg = doc["config"]
        net = _net_from_state(doc["state_dict"], cfg)
        norm, bounds = doc["normalisation"], doc["bounds"]
        model = RegressionModel(
            net=net,
            in_mean=norm["in_mean"].numpy(), in_std=norm["in_std"].numpy(),
            out_mean=norm["out_mean"].numpy(), out_std=norm["out_std"].numpy(),
            in_min=bounds["in_min"].numpy(), in_max=bounds["in_max"].numpy(),
            hull=doc["hull"].numpy(), config=cfg, metrics=dict(doc.get("metrics", {})))
        res = doc.get("residual")
        if res:
            model.residual_net = _net_from_state(res["state_dict"], cfg, "residual_hidden")
            model.res_mean, model.res_std = res["res_mean"].numpy(), res["res_std"].numpy()
            model.calibration_toml = res["calibration_toml"]
        model.spreads = {str(m): Spread.from_doc(d) for m, d in (doc.get("spread") or {}).items()}
        if int(doc.get("version", 0)) < 3:
            for spread in model.spreads.values():
                spread.pixel_sd = spread.pixel_sd / np.sqrt(2.0)
    except (KeyError, RuntimeError, TypeError, AttributeError) as exc:
        raise SandtrackError(f"{p}: damaged model file ({exc})") from None
    return model


def _net_from_state(state: dict, cfg: dict, key: str = "hidden") -> MLP:
    net = MLP(hidden=tuple(cfg.get(key, cfg.get("hidden", STUDY_HIDDEN))), dropout=float(cfg.get("dropout", 0.0)))
    net.load_state_dict(state)
    net.eval()
    return net


def _forward(net: MLP, x_std: np.ndarray, batch: int = 65536, allow_numpy: bool = True) -> np.ndarray:
    """Standardised inputs -> standardised outputs. The numpy path caches the weights: only for a
    trained net (allow_numpy=False while its weights still change)."""
    if allow_numpy and len(x_std) <= SMALL_BATCH:
        return _forward_numpy(net, x_std)
    device = next(net.parameters()).device
    out = np.empty((len(x_std), 3))
    net.eval()
    with torch.inference_mode():
        for i in range(0, len(x_std), batch):
            xb = torch.as_tensor(x_std[i:i + batch], dtype=torch.float32, device=device)
            out[i:i + batch] = net(xb).double().cpu().numpy()
    return out


def _forward_numpy(net: MLP, x_std: np.ndarray) -> np.ndarray:
    """Inference for a few rows without any thread pool (einsum's own loop, not BLAS): with the cores
    busy, torch's and BLAS's threads waited on each other for 30-60 ms per call, against ~6 ms here.
    The live XYZ table's case."""
    layers = getattr(net, "_numpy_layers", None)
    if layers is None:
        layers = [(m.weight.detach().cpu().numpy().T.copy(), m.bias.detach().cpu().numpy().copy())
                  for m in net.layers if isinstance(m, nn.Linear)]
        net._numpy_layers = layers  # weights do not change after training
    h = np.asarray(x_std, dtype=np.float32)
    for k, (w, b) in enumerate(layers):
        h = np.einsum("ij,jk->ik", h, w) + b
        if k < len(layers) - 1:
            np.maximum(h, 0, out=h)
    return h.astype(np.float64)


def _inputs(xs, ys=None, xf=None, yf=None) -> np.ndarray:
    if ys is None:
        x = np.asarray(xs, dtype=np.float64).reshape(-1, 4)
    else:
        x = np.stack([np.asarray(v, dtype=np.float64).ravel() for v in (xs, ys, xf, yf)], axis=1)
    return x


def predict(model: RegressionModel, xs, ys=None, xf=None, yf=None, method: str = "mlp") -> np.ndarray:
    """World XYZ (N, 3) mm for pixel arrays xs, ys (side) and xf, yf (front), or one (N, 4) array.
    method "mlp": the network alone; "residual": triangulation with the model's calibration plus the
    learned correction. Rows with a missing pixel give NaN."""
    x = _inputs(xs, ys, xf, yf)
    out = np.full((len(x), 3), np.nan)
    ok = np.isfinite(x).all(axis=1)
    if not ok.any():
        return out
    xn = (x[ok] - model.in_mean) / model.in_std
    if method == "mlp":
        out[ok] = _forward(model.net, xn) * model.out_std + model.out_mean
    elif method == "residual":
        if not model.has_residual:
            raise SandtrackError("this model has no residual variant (train it with a calibration)")
        from ..triangulation import triangulate

        tri, _ = triangulate(model.calibration, {"side": x[ok, :2], "front": x[ok, 2:]}, world=True)
        out[ok] = tri + _forward(model.residual_net, xn) * model.res_std + model.res_mean
    else:
        raise SandtrackError(f"unknown regression method {method!r} (mlp or residual)")
    return out


def hull_distance(model: RegressionModel, xyz: np.ndarray) -> np.ndarray:
    """Signed distance (mm) of points from the training hull: > 0 outside, <= 0 inside."""
    pts = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if len(model.hull) == 0:
        return np.zeros(len(pts))
    return (pts @ model.hull[:, :3].T + model.hull[:, 3]).max(axis=1)


def outside_training(model: RegressionModel, inputs: np.ndarray, xyz: np.ndarray | None = None,
                     tolerance_mm: float = HULL_TOLERANCE_MM) -> np.ndarray:
    """True where a query lies outside what the MLP was trained on: a pixel beyond the training
    range (plus BOUNDS_MARGIN of it), or its XYZ more than `tolerance_mm` outside the convex hull
    of the training XYZ. NaN inputs count as inside (they have no prediction to flag)."""
    x = np.asarray(inputs, dtype=np.float64).reshape(-1, 4)
    span = model.in_max - model.in_min
    lo, hi = model.in_min - BOUNDS_MARGIN * span, model.in_max + BOUNDS_MARGIN * span
    with np.errstate(invalid="ignore"):
        out = ((x < lo) | (x > hi)).any(axis=1)
        if xyz is not None:
            out |= hull_distance(model, xyz) > tolerance_mm
    return out
