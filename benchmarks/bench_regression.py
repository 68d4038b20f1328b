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
    out = {"points": m["points"], "train_seconds": round(m["train_seconds"], 1),
           "train_cpu_seconds": round(m["train_cpu_seconds"], 1), "epochs_run": m["epochs_run"],
           "residual_epochs_run": m.get("residual_epochs_run"), "threads": m["threads"]}
    for key in ("mlp_mean_error_mm", "mlp_sd_mm", "mlp_median_mm", "mlp_p95_mm", "r2_x", "r2_y", "r2_z",
                "triangulation_mean_error_mm", "triangulation_sd_mm", "residual_mean_error_mm", "residual_sd_mm"):
        out[key] = round(m[key], 5 if key.startswith("r2") else 3)
    for key in (k for k in m if "_coverage95_pct_" in k or "_sd_median_mm_" in k):
        out[key] = round(m[key], 2 if "coverage" in key else 4)
    px = points[["xs", "ys", "xf", "yf"]].to_numpy()
    truth = points[["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    exact, _ = triangulate(rig, {"side": px[:, :2], "front": px[:, 2:]})
    out["triangulation_exact_rig_mean_error_mm"] = round(float(np.linalg.norm(exact - truth, axis=1).mean()), 3)
    out["study_mean_error_mm"], out["study_sd_mm"] = 2.3, 1.8

    t = time.perf_counter()
    predict(model, px)
    out["predict_us_per_point"] = round((time.perf_counter() - t) / len(px) * 1e6, 2)
    out.update(_xyz_speed(rig, model))
    out.update(_twin(epochs))
    return out


SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "ground_truth"


def _twin_folder() -> Path:
    """The full preset's ground truth when `sandtrack demo` has rendered it, else the bundled sample."""
    from sandtrack_tui import demo

    name = "sample-full-seed0"
    if hasattr(demo, "renderer_version"):
        name += f"-{demo.renderer_version()}"
    full = demo.cache_dir() / name
    return full / "ground_truth" if (full / ".complete").is_file() else SAMPLE


def twin_points(folder: Path = SAMPLE, noise_px: float = 0.3, seed: int = 0):
    """points.csv rows from the digital twin's true calibration corners (side frame i pairs with
    front frame i - offset_frames), with Gaussian detection noise; None if the twin is absent."""
    import json

    import pandas as pd

    files = [folder / n for n in ("calibration_corners_side.csv", "calibration_corners_front.csv", "sync.json")]
    if not all(f.is_file() for f in files):
        return None
    side, front = pd.read_csv(files[0]), pd.read_csv(files[1])
    off = int(json.loads(files[2].read_text())["calibration"]["offset_frames"])
    j = side.merge(front.assign(frame=front["frame"] + off)[["frame", "corner_id", "x_px", "y_px"]],
                   on=["frame", "corner_id"], suffixes=("_s", "_f"))
    rng = np.random.default_rng(seed)
    px = j[["x_px_s", "y_px_s", "x_px_f", "y_px_f"]].to_numpy() + rng.normal(0, noise_px, (len(j), 4))
    return pd.DataFrame({"frame": j["frame"], "corner_id": j["corner_id"], "xs": px[:, 0], "ys": px[:, 1],
                         "xf": px[:, 2], "yf": px[:, 3], "X_mm": j["X_mm"], "Y_mm": j["Y_mm"], "Z_mm": j["Z_mm"]})


def _twin(epochs: int | None) -> dict:
    """The same recipe on the rendered twin's calibration corners (true pixels + 0.3 px noise), and
    how many visible marker positions of its experiment lie outside the volume the board covered."""
    import pandas as pd

    from sandtrack_tui.regression import hull_distance

    folder = _twin_folder()
    points = twin_points(folder)
    if points is None:
        return {}
    cal = Calibration.load(folder / "cameras.toml")
    model = train(points, TrainConfig() if epochs is None else TrainConfig(epochs=epochs), calibration=cal)
    m = model.metrics
    out = {f"twin_{k}": round(m[k], 3) for k in ("points", "train_seconds", "mlp_mean_error_mm", "mlp_sd_mm",
                                                 "triangulation_mean_error_mm", "residual_mean_error_mm")}
    out.update({f"twin_{k}": round(v, 2) for k, v in m.items() if "_coverage95_pct_" in k})
    out["twin_preset"] = "full" if folder != SAMPLE else "small"
    traj = pd.read_csv(folder / "trajectories.csv")
    seen = traj[(traj["visible_side"] == 1) & (traj["visible_front"] == 1)][["X_mm", "Y_mm", "Z_mm"]].to_numpy()
    if len(seen):
        out["twin_markers_outside_board_volume_pct"] = round(100 * float((hull_distance(model, seen) > 5).mean()), 1)
    return out


def _blank_clip(path: Path, frames: int, fps: int = 50) -> Path:
    """A small grey H.264 clip: the project's cameras are its videos (their frame count and rate)."""
    import av

    with av.open(str(path), "w") as out:
        stream = out.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        stream.options = {"preset": "ultrafast", "bf": "0"}
        frame = av.VideoFrame.from_ndarray(np.full((48, 64, 3), 128, np.uint8), format="bgr24")
        for _ in range(frames):
            out.mux(stream.encode(frame))
        out.mux(stream.encode())
    return path


def _xyz_speed(rig: Calibration, model, markers: int = 20, frames: int = 1500) -> dict:
    """XYZ table of `markers` markers over `frames` side frames (both methods), and one frame of it."""
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        model_path = Path(tmp) / "model.pt"
        model.save(model_path)
        videos = {cam: _blank_clip(Path(tmp) / f"{cam}.mp4", frames) for cam in ("side", "front")}
        proj = Project.create(Path(tmp) / "bench.sandtrack", videos)
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
