"""Digital twin benchmark: render the small preset, time it (wall and CPU), check sizes and detector figures.

`run() -> dict` renders into benchmarks/out/twin_small (not committed) and reports render time, CPU seconds,
bytes, two-view corner observations, ChArUco detection rate on the rendered calibration videos and the
median corner error against the true pixels.
"""

from __future__ import annotations

import resource
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _cpu_s() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def _detection(out: Path, camera: str, step: int = 3) -> dict:
    import numpy as np

    from sandtrack_tui.groundtruth import board_detection

    rate, errs = board_detection(out, camera, step)
    return {f"{camera}_detect_rate": round(rate, 3),
            f"{camera}_corner_err_median_px": round(float(np.median(errs)), 3) if len(errs) else None,
            f"{camera}_corner_err_p95_px": round(float(np.percentile(errs, 95)), 3) if len(errs) else None}


def run(preset: str = "small") -> dict:
    from sandtrack_tui.twin.sample import render_sample

    out = HERE / "out" / f"twin_{preset}"
    cpu0, t0 = _cpu_s(), time.perf_counter()
    res = render_sample(out, seed=0, preset=preset, workers=2)
    wall = time.perf_counter() - t0
    cpu = _cpu_s() - cpu0
    figures = {
        "preset": preset,
        "render_wall_s": round(wall, 1),
        "render_cpu_s": round(cpu, 1),
        "experiment_frames_per_camera": res["experiment_frames"],
        "calibration_frames_per_camera": res["calibration_frames"],
        "two_view_corner_observations": res["two_view_corner_observations"],
        "total_mb": round(res["total_bytes"] / 1e6, 2),
        "videos_mb": round(sum(v for k, v in res["files"].items() if k.endswith(".mp4")) / 1e6, 2),
    }
    for cam in ("side", "front"):
        figures.update(_detection(out, cam))
    from sandtrack_tui.twin.sample import two_view_observations

    figures["full_preset_two_view_corner_observations"] = two_view_observations("full")
    return figures


if __name__ == "__main__":
    import json

    print(json.dumps(run(*(sys.argv[1:2] or [])), indent=2))
