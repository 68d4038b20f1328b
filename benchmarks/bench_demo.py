"""End to end: `sandtrack demo` (full preset) in a child process; every stage's time and key figures.

The full preset's one-time render (cached, see `sandtrack_tui.demo.ensure_sample`) is timed
separately as `render_seconds` (0 when the cache already holds it), so `stages_seconds` is the
demo's own time, the figure the issue's 10-minute target applies to.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

KEY_FIGURES = {
    "sync": ("offset_error_ms",),
    "calibration": ("reprojection_rmse_px", "board_rmse_mm", "focal_error_pct", "corner_error_mm"),
    "regression": ("points", "mlp_mean_error_mm", "mlp_sd_mm", "triangulation_mean_error_mm", "train_seconds"),
    "tracking": ("mean_error_px", "p95_error_px", "false_locks", "hidden_flagged_pct", "ms_per_marker_frame"),
    "xyz": ("mean_error_mm", "p95_error_mm"),
    "compare": ("recovered_shift_s", "true_shift_s", "shift_error_frames", "drifting_particles",
                *(f"{m}_{k}" for m in ("triangulation", "mlp", "residual")
                  for k in ("inconsistent_particles", "within_95_pct_of_true_particles"))),
}


def _render_once() -> float:
    from sandtrack_tui import demo

    t0 = time.perf_counter()
    demo.ensure_sample("full", log=lambda msg: print(msg, file=sys.stderr, flush=True))
    return time.perf_counter() - t0


def run() -> dict:
    render_s = _render_once()
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "sandtrack_tui", "demo", "--json"], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"sandtrack demo exited {proc.returncode}: {proc.stderr.strip()[-300:]}")
    result = json.loads(proc.stdout)
    figures: dict = {"render_seconds": round(render_s, 1), "demo_wall_seconds": round(wall, 1),
                     "stages_seconds": result["seconds"]}
    for stage, info in result["stages"].items():
        figures[f"{stage}_seconds"] = info["seconds"]
        for key in KEY_FIGURES.get(stage, ()):
            if key in info:
                figures[f"{stage}_{key}"] = info[key]
    return figures


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
