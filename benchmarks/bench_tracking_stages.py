"""Where the tracking step's time goes, on sample_data, with no decoder running beside it.

The videos are decoded once into memory (the 4:2:0 frames the tracker receives, yuv.py), then
`track_project` replays them RUNS times on fresh copies of one seeded project (seeds as in
bench_tracking.py). Decoding is out of the picture, so the step's CPU is measured without the two
decoder threads competing for the cores and the GIL: `step_cpu_ms_per_marker_frame_min` /
`_median` (thread CPU inside `Engine.step`, per marker and camera frame; the first run, which loads
the compiled kernels, is left out). One more run with a CPU timer around each stage gives each
stage's share of the step (`share_*`, inclusive: the template matches that re-acquisition
verifies count in both `share_match` and `share_reacquire`), and the calls (`calls_*`). The main
thread's CPU of a whole replayed run (`main_cpu_s_*`, median of the runs) is split into the steps
(`step_cpu_s_median`), starting the tracks (`setup_cpu_s_median`: each seed's appearance model and
templates, `MarkerTrack.__init__`) and writing the points to the project (`writes_cpu_s_median`).
Needs ~3 GB of memory for the decoded frames; sample_data absent: skipped.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[0] / "src"))

import bench_tracking as bt  # noqa: E402
from sandtrack_tui.store import Project, _Edit  # noqa: E402
from sandtrack_tui.tracking import run as tracking_run  # noqa: E402
from sandtrack_tui.tracking import verify  # noqa: E402
from sandtrack_tui.tracking.engine import Engine  # noqa: E402
from sandtrack_tui.tracking.line_search import LineSearch  # noqa: E402
from sandtrack_tui.tracking.matcher import TemplateMatcher  # noqa: E402
from sandtrack_tui.tracking.reattach import Reacquisition  # noqa: E402
from sandtrack_tui.tracking.refine import LumaCarry  # noqa: E402
from sandtrack_tui.tracking.rest import RestReference  # noqa: E402
from sandtrack_tui.tracking.run import accept_seeds, track_project  # noqa: E402
from sandtrack_tui.tracking.tracker import MarkerTrack  # noqa: E402
from sandtrack_tui.video import FrameSource  # noqa: E402

RUNS = 6
STAGES = {  # name -> (class or module, function)
    "step": (Engine, "step"),
    "propose": (MarkerTrack, "propose"),
    "match": (TemplateMatcher, "match"),
    "rest_shift": (RestReference, "shift"),
    "luma_carry": (LumaCarry, "refine"),
    "reacquire": (Reacquisition, "run"),
    "band_search": (LineSearch, "band_blobs"),
    "apply": (MarkerTrack, "apply"),
    "stereo_check": (verify, "stereo_check"),
}


class _Replay:
    """prefetch() stand-in: hands out frames decoded beforehand, in the order asked."""

    frames: dict = {}  # id(source) -> list of frames

    def __init__(self, source, indices, lazy=True):
        self._items = iter([(j, self.frames[id(source)][j]) for j in indices])

    def wait_for(self, n):
        pass

    def get(self):
        return next(self._items)

    def close(self):
        pass


def _timed(cpu: dict, calls: dict, name: str, fn):
    def wrapper(*args, **kwargs):
        c0 = time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            cpu[name] += time.thread_time() - c0
            calls[name] += 1
    return wrapper


def run() -> dict:
    if not (bt.SAMPLE / "ground_truth" / "cameras.toml").exists():
        return {"skipped": "sample_data absent"}
    videos, truth, cal, offset = bt._sample_dataset()
    with tempfile.TemporaryDirectory() as tmpdir:
        seeded = Path(tmpdir) / "seeded.sandtrack"
        proj = Project.create(seeded, videos)
        proj.set_calibration(cal)
        proj.set("sync_offset_s", offset)
        accept_seeds(proj, bt._seeds(videos, truth))
        proj.close()
        srcs = {c: FrameSource(v, cache_mb=64) for c, v in videos.items()}
        _Replay.frames = {id(s): [s.lazy_frame(j) for j in range(len(s))] for s in srcs.values()}
        real_prefetch, tracking_run.prefetch = tracking_run.prefetch, _Replay
        try:
            step_ms, points, split = [], None, []
            for rep in range(RUNS + 2):
                instrumented = rep == RUNS + 1
                cpu, calls, saved = dict.fromkeys(STAGES, 0.0), dict.fromkeys(STAGES, 0), []
                outside = {"setup": 0.0, "writes": 0.0}
                for name, (cls, meth) in (("setup", (MarkerTrack, "__init__")), ("writes", (_Edit, "write"))):
                    saved.append((cls, meth, cls.__dict__[meth]))
                    setattr(cls, meth, _timed(outside, {name: 0}, name, cls.__dict__[meth]))
                if instrumented:
                    for name, (cls, meth) in STAGES.items():
                        saved.append((cls, meth, cls.__dict__[meth]))
                        setattr(cls, meth, _timed(cpu, calls, name, cls.__dict__[meth]))
                run_file = Path(tmpdir) / f"run{rep}.sandtrack"
                shutil.copyfile(seeded, run_file)
                try:
                    with Project.open(run_file) as p:
                        c0 = time.thread_time()
                        summary = track_project(p, sources=srcs)
                        main_cpu = time.thread_time() - c0
                        if points is None:
                            points = p.points()
                finally:
                    for cls, meth, fn in saved:
                        setattr(cls, meth, fn)
                if 0 < rep <= RUNS:
                    step_ms.append(summary["track_cpu_ms_per_marker_frame"])
                    split.append((main_cpu, outside["setup"], outside["writes"],
                                  summary["track_cpu_ms_per_marker_frame"] * summary["marker_frames"] / 1000))
        finally:
            tracking_run.prefetch = real_prefetch
            _Replay.frames = {}
            for s in srcs.values():
                s.close()
    out = {"data": "sample_data", "runs": RUNS, "step_cpu_ms_per_marker_frame_min": min(step_ms),
           "step_cpu_ms_per_marker_frame_median": round(float(np.median(step_ms)), 4),
           "step_cpu_ms_per_marker_frame_runs": step_ms}
    main, setup, writes, steps = (float(np.median([s[k] for s in split])) for k in range(4))
    out.update(main_cpu_s_median=round(main, 4), main_cpu_s_runs=[round(s[0], 4) for s in split],
               step_cpu_s_median=round(steps, 4), setup_cpu_s_median=round(setup, 4),
               writes_cpu_s_median=round(writes, 4))
    total = cpu["step"]
    out.update({f"share_{k}": round(v / total, 3) for k, v in cpu.items() if k != "step"})
    out.update({f"calls_{k}": v for k, v in calls.items()})
    score = bt._score(points, truth)
    out.update(mean_error_px=round(score["mean_error_px"], 4), false_locks=score["false_locks"])
    return out


if __name__ == "__main__":
    for k, v in run().items():
        print(f"{k}: {v}")
