"""Regression benchmark: the study's MLP on 44,130 volume-filling calibration points (exact truth),
beside triangulation and the residual variant, plus the XYZ table's speed.

The calibration given to triangulation is the true rig perturbed by the error a good calibration
still has (focal 0.2 %, principal point 1.5 px, 0.05 deg, 0.5 mm), as in real use; the triangulation
error with the exact rig is reported too. The study reached a mean error of 2.3 mm (SD 1.8) and
R² 0.9988 / 0.9972 / 0.9982 on its 44,130 points.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from sandtrack_tui.camera import Calibration, Camera  # noqa: E402
from sandtrack_tui.regression import TrainConfig, predict, train  # noqa: E402
from sandtrack_tui.regression.synthetic import calibration_points, study_rig  # noqa: E402
from sandtrack_tui.store import Project  # noqa: E402
from sandtrack_tui.triangulation import triangulate  # noqa: E402
from sandtrack_tui.xyz import compute_xyz, xyz_at_frame  # noqa: E402


def perturbed(cal: Calibration) -> Calibration:
    """The rig as a good calibration would estimate it (errors at the calibration targets' limits)."""
    front = cal.cameras["front"]
    K = front.matrix.copy()
    K[0, 0] *= 1.002
    K[1, 1] *= 1.002
    K[0, 2] += 1.5
    R = cv2.Rodrigues(front.rvec)[0] @ cv2.Rodrigues(np.radians([0.05, 0.0, 0.0]))[0]
    est = Camera("front", front.width, front.height, K, front.distortion, cv2.Rodrigues(R)[0].ravel(),
                 front.tvec + np.array([0.5, 0.0, 0.0]))
    return Calibration({"side": cal.cameras["side"], "front": est}, cal.world_from_rig)


def run(epochs: int | None = None) -> dict:
    rig = study_rig()
    points = calibration_points(rig, n_points=44_130, seed=0)
    estimated = perturbed(rig)
    cfg = TrainConfig() if epochs is None else TrainConfig(epochs=epochs)
    model = train(points, cfg, calibration=estimated)
    m = model.metrics
    out = {"points": m["points"], "train_seconds": round(m["train_seconds"], 1), "epochs_run": m["epochs_run"],
           "residual_epochs_run": m.get("residual_epochs_run"), "threads": m["threads"]}
    for key in ("mlp_mean_error_mm", "mlp_sd_mm", "mlp_median_mm", "mlp_p95_mm", "r2_x", "r2_y", "r2_z",
                "triangulation_mean_error_mm", "triangulation_sd_mm", "residual_mean_error_mm", "residual_sd_mm"):
        out[key] = round(m[key], 5 if key.startswith("r2") else 3)
    px = points[["xs", "ys", "xf", "yf"]].to_numpy()
    truth = points[["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    exact, _ = triangulate(rig, {"side": px[:, :2], "front": px[:, 2:]})
    out["triangulation_exact_rig_mean_error_mm"] = round(float(np.linalg.norm(exact - truth, axis=1).mean()), 3)
    out["study_mean_error_mm"], out["study_sd_mm"] = 2.3, 1.8

    t = time.perf_counter()
    predict(model, px)
    out["predict_us_per_point"] = round((time.perf_counter() - t) / len(px) * 1e6, 2)
    out.update(_xyz_speed(rig, model))
    return out


def _xyz_speed(rig: Calibration, model, markers: int = 20, frames: int = 1500) -> dict:
    """XYZ table of `markers` markers over `frames` side frames (both methods), and one frame of it."""
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        model_path = Path(tmp) / "model.pt"
        model.save(model_path)
        proj = Project.create(Path(tmp) / "bench.sandtrack")
        proj.set_calibration(rig)
        proj.set("sync_offset_s", 0.0137)
        proj.set("model", {"path": str(model_path)})
        rows = []
        t = np.arange(frames) / 50.0
        for m in range(1, markers + 1):
            start = rng.uniform([-100, 10, -150], [100, 60, 0])
            pos = start + np.outer(t, [0, 0, 10.0])
            for cam, shift in (("side", 0.0), ("front", 0.0137)):
                pix = rig.project_world(cam, pos + np.outer(np.full(frames, shift), [0, 0, 10.0]))
                rows += [(i, cam, m, *pix[i], "tracked") for i in range(frames)]
        proj.set_points(rows, "bench tracks")
        t0 = time.perf_counter()
        table = compute_xyz(proj, method="both")
        full_s = time.perf_counter() - t0
        xyz_at_frame(proj, 10)  # warm the model cache
        t0 = time.perf_counter()
        for f in range(100, 120):
            xyz_at_frame(proj, f)
        frame_ms = (time.perf_counter() - t0) / 20 * 1000
        proj.close()
    return {"xyz_table_rows": len(table), "xyz_table_seconds": round(full_s, 2), "xyz_at_frame_ms": round(frame_ms, 1)}


if __name__ == "__main__":
    import json

    print(json.dumps(run(int(sys.argv[1]) if len(sys.argv) > 1 else None), indent=2))
