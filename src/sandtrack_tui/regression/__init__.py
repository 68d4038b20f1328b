"""Pixel -> XYZ regression (the study's MLP) beside direct triangulation.

Public API: `load_points`, `split_by_frame`, `TrainConfig`, `train`, `RegressionModel`,
`load_model`, `predict`, `predict_with_sd` (XYZ and its sd per axis), `outside_training`,
`error_stats`. See `model` for the model file format.
"""

from .dataset import INPUTS, POINT_COLUMNS, TARGETS, check_points, load_points, split_by_frame
from .model import MLP, RegressionModel, hull_distance, load_model, outside_training, predict
from .spread import coverage, predict_with_sd
from .train import TrainConfig, error_stats, train

__all__ = [
    "INPUTS", "MLP", "POINT_COLUMNS", "TARGETS", "RegressionModel", "TrainConfig", "check_points",
    "coverage", "error_stats", "hull_distance", "load_model", "load_points", "outside_training", "predict",
    "predict_with_sd", "split_by_frame", "train",
]
