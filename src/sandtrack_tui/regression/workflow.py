"""Train from a points file (or table) to a model file, optionally recording it in a project: the
one call behind `sandtrack train`, the TUI's training step and the demo."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ..errors import SandtrackError
from .dataset import load_points
from .model import RegressionModel
from .train import ProgressFn, StopFn, TrainConfig, train

# Metrics stored with the model path in the project's "model" setting.
PROJECT_KEYS = ["points", "mlp_mean_error_mm", "mlp_sd_mm", "mlp_median_mm", "mlp_p95_mm", "r2_x", "r2_y", "r2_z",
                "triangulation_mean_error_mm", "triangulation_sd_mm", "residual_mean_error_mm", "residual_sd_mm",
                "baseline_mean_error_mm", "test_points", "test_outside_bounds", "epochs_run", "best_epoch",
                "stopped", "device", "threads", "train_seconds", "train_cpu_seconds",
                *(f"{m}_coverage95_pct_{a}" for m in ("mlp", "residual") for a in "xyz")]


def train_to_file(points: str | Path | pd.DataFrame, output: str | Path, calibration=None, project=None,
                  config: TrainConfig | None = None, progress: ProgressFn | None = None,
                  should_stop: StopFn | None = None) -> RegressionModel:
    """Train, write the model file (atomically), and with a project store {"path": absolute path,
    metrics...} as its "model" setting (one undoable edit). Without an explicit calibration the
    project's is used for the triangulation comparison and the residual variant."""
    out = Path(output)
    if not out.parent.exists():
        raise SandtrackError(f"folder does not exist: {out.parent}")
    df = points if isinstance(points, pd.DataFrame) else load_points(points)
    if calibration is None and project is not None:
        calibration = project.calibration()
    model = train(df, config, calibration=calibration, progress=progress, should_stop=should_stop)
    model.save(out)
    if project is not None:
        m = model.metrics
        project.set("model", {"path": str(out.resolve()), **{k: m[k] for k in PROJECT_KEYS if k in m}},
                    "train regression model")
    return model
