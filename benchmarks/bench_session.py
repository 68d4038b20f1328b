"""The operator's session: id placement in crowds, auto-seed identities, four views stepping, the
first run of the sample project, XYZ at an instant from three cameras, a dense scene.

- labels: `draw_overlays` on a 100 x 30-cell view of a 1080p frame, n touching 10 px beads in a
  square cluster, at 1x, 4x and 16x zoom: CPU ms, ids placed of those in view, overlapping ids
  (must be 0), ids moved away with a leader line.
- identities: `match_proposals` of n blobs against n known markers in two cameras.
- four views: key -> all four views decoded, downscaled and composed (200 x 50 cells, 2 x 2 grid of
  the sample's two videos, each linked twice), in process like bench_tui's step.
- first run: `sample_project` made afresh (audio sync of the sample, calibration, the network's
  metrics read from its file).
- xyz: `xyz.xyz_at_frame` for 20 markers seen by three cameras.
- dense: a flume's packed bed of 300 beads (tests/dense_synth.py): what the marker boost paints, ids of
  300 markers, a step of the app with 300 tracked markers (`dense_figures`).

Wall times depend on how busy the machine is; CPU times are printed beside them.
"""

from __future__ import annotations

import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "tests"))

from sandtrack_tui.tui.frame_view import MarkerMark, Overlays, ViewTransform, draw_overlays  # noqa: E402

SAMPLE = ROOT / "sample_data"


def _cpu_ms(fn, repeats: int) -> tuple[float, float, object]:
    """Median wall and CPU ms of fn() over `repeats` calls, and its last result."""
    wall, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        wall.append((time.perf_counter() - t0) * 1000)
        cpu.append((time.process_time() - c0) * 1000)
    return statistics.median(wall), statistics.median(cpu), out


def label_figures() -> dict:
    out = {}
    for n in (8, 30, 100):
        side = int(np.ceil(np.sqrt(n)))
        pos = [(960 + 10 * (k % side), 540 + 10 * (k // side)) for k in range(n)]
        marks = [MarkerMark(k + 1, str(k + 1), x, y, "tracked") for k, (x, y) in enumerate(pos)]
        for zoom in (1, 4, 16):
            tf = ViewTransform.make(1920, 1080, 100, 30, zoom, (960 + 5 * side, 540 + 5 * side))
            rgb = np.zeros((60, 100, 3), np.uint8)

            def run(tf=tf, marks=marks, rgb=rgb):
                rgb[:] = 0
                return draw_overlays(rgb, tf, Overlays(marks=marks))

            _wall, cpu, labels = _cpu_ms(run, 7)
            shown = [m.label for m in marks if tf.contains(m.x, m.y)]
            runs = _runs(labels)
            out[f"labels_{n}_markers_{zoom}x_cpu_ms"] = round(cpu, 2)
            out[f"labels_{n}_markers_{zoom}x_placed"] = f"{sum(r in shown for r in runs)}/{len(shown)}"
            out[f"labels_{n}_markers_{zoom}x_overlapping"] = sum(r not in shown for r in runs)
    return out


def _runs(labels: dict) -> list[str]:
    runs, cur, last = [], "", None
    for (r, c) in sorted(labels):
        if last is not None and (r, c - 1) == last:
            cur += labels[(r, c)][0]
        else:
            if cur:
                runs.append(cur)
            cur = labels[(r, c)][0]
        last = (r, c)
    if cur:
        runs.append(cur)
    return runs


def identity_figures(n: int = 100) -> dict:
    from sandtrack_tui.tracking.identity import match_proposals

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 1900, (n, 2))
    known = pd.DataFrame([(k + 1, cam, x + d, y, 3) for k, (x, y) in enumerate(xy)
                          for cam, d in (("side", 0.0), ("front", 40.0))],
                         columns=["marker", "camera", "x_px", "y_px", "gap_frames"])
    jitter = rng.normal(0, 1.0, (n, 2))
    props = pd.DataFrame([(k + 1, cam, 0, x + d + jx, y + jy, 14, 14, 0.1)
                          for k, ((x, y), (jx, jy)) in enumerate(zip(xy, jitter, strict=True))
                          for cam, d in (("side", 0.0), ("front", 40.0))],
                         columns=["marker", "camera", "frame", "x_px", "y_px", "w", "h", "epipolar_px"])
    wall, cpu, matches = _cpu_ms(lambda: match_proposals(props, known), 3)
    right = sum(p == m for p, (m, _d) in matches.items())
    return {f"identity_{n}_blobs_ms": round(wall, 1), f"identity_{n}_blobs_cpu_ms": round(cpu, 1),
            f"identity_{n}_blobs_right": f"{right}/{n}"}


async def _four_view_steps(path: Path, steps: int = 20) -> tuple[list[float], float]:
    from sandtrack_tui.tui.app import SandtrackApp

    app = SandtrackApp(path)
    async with app.run_test(size=(200, 50)) as pilot:
        for _ in range(300):
            await pilot.pause(0.02)
            if app.views_ready():
                break
        app.step_latencies_ms.clear()
        c0 = time.process_time()
        for _ in range(steps):
            await pilot.press("right")
            t0 = time.perf_counter()
            while not app.views_ready() and time.perf_counter() - t0 < 5:
                await pilot.pause(0.002)
            await pilot.pause(0.05)  # the user's pace
        cpu = (time.process_time() - c0) * 1000 / steps
        return list(app.step_latencies_ms), cpu


def four_view_figures(tmp: Path) -> dict:
    from sandtrack_tui.store import Project

    exp = SAMPLE / "experiment"
    if not (exp / "side.mp4").is_file():
        return {"four_views": "skipped: sample_data/experiment is missing"}
    with Project.create(tmp / "four.sandtrack", {"side": exp / "side.mp4", "front": exp / "front.mp4",
                                                 "top": exp / "side.mp4", "back": exp / "front.mp4"}) as p:
        p.set("sync_offset_s", 0.0)
    steps, cpu = asyncio.run(_four_view_steps(tmp / "four.sandtrack"))
    return {"step_four_views_200x50_ms_median": round(statistics.median(steps), 1),
            "step_four_views_200x50_ms_p95": round(float(np.percentile(steps, 95)), 1),
            "step_four_views_cpu_ms_per_step": round(cpu, 1)}


def first_run_figures(tmp: Path) -> dict:
    from sandtrack_tui.cli.cmd_tui import sample_project
    from sandtrack_tui.store import Project

    if not (SAMPLE / "model.pt").is_file():
        return {"first_run": "skipped: sample_data/model.pt is missing"}
    t0, c0 = time.perf_counter(), time.process_time()
    path = sample_project(SAMPLE, tmp / "sample.sandtrack")
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    with Project.open(path) as proj:
        offset = proj.sync_offset_s
        model = proj.get("model") or {}
    return {"first_run_sample_project_s": round(wall, 2), "first_run_sample_project_cpu_s": round(cpu, 2),
            "first_run_sync_offset_ms": round(offset * 1000, 2),
            "first_run_network_test_mean_mm": model.get("mlp_mean_error_mm")}


def multiview_figures(tmp: Path, n: int = 20) -> dict:
    import cv2

    from sandtrack_tui import xyz as xyz_table
    from sandtrack_tui.store import Project
    from tui_synth import calibration

    cams = ["side", "front", "top"]
    for cam in cams:
        (tmp / cam).mkdir()
        for f in range(3):
            cv2.imwrite(str(tmp / cam / f"{f}.png"), np.zeros((360, 640, 3), np.uint8))
    cal = calibration(cams)
    rng = np.random.default_rng(1)
    xyz = rng.uniform([-100, -60, 950], [100, 60, 1050], (n, 3))
    with Project.create(tmp / "three.sandtrack", {c: tmp / c for c in cams}) as proj:
        proj.set("sync_offset_s", 0.005)
        proj.set_calibration(cal)
        rows = [(f, c, m + 1, *map(float, cal.cameras[c].project(xyz[m][None])[0]), "tracked", None, None, None)
                for f in range(3) for c in cams for m in range(n)]
        proj.set_points(rows, "points")
        wall, cpu, out = _cpu_ms(lambda: xyz_table.xyz_at_frame(proj, 1), 7)
        err = np.linalg.norm(out[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - xyz[out.marker.to_numpy() - 1], axis=1)
    return {f"xyz_three_cameras_{n}_markers_ms": round(wall, 1), f"xyz_three_cameras_{n}_markers_cpu_ms": round(cpu, 1),
            "xyz_three_cameras_max_error_mm": float(f"{err.max():.2g}")}


def dense_figures(tmp: Path, tracked: int = 20, steps: int = 10) -> dict:
    """A flume's packed bed of 300 black beads (tests/dense_synth.py), a 98 x 27-cell view (the boost's look
    from a bead, as after a click): the share of the picture that looks like markers, what the boost paints
    with every bead tracked and with `tracked` of them, its CPU; the ids of 300 markers (placed of those in
    view, overlapping, CPU); and a step of the running app with 300 tracked markers (100 x 30, half-blocks)."""
    import cv2

    from dense_synth import HEIGHT, WIDTH, bead_centres, dense_frame, write_frames
    from sandtrack_tui.store import Project
    from sandtrack_tui.tracking.run import marker_look
    from sandtrack_tui.tui.frame_view import BOOST_RGB, render

    centres = bead_centres()
    bgr = cv2.cvtColor(dense_frame(centres), cv2.COLOR_GRAY2BGR)
    look = marker_look(bgr, *centres[int(np.argmin(np.hypot(*(centres - (640, 300)).T)))])
    marks = [MarkerMark(k + 1, str(k + 1), x, y, "tracked", half_size_px=12.0) for k, (x, y) in enumerate(centres)]
    out: dict = {"dense_beads": len(centres), "dense_look": look.kind if look is not None else None}
    for zoom in (1, 4):
        tf = ViewTransform.make(WIDTH, HEIGHT, 98, 27, zoom, (640, 280))
        for label, where in (("all", centres), (str(tracked), centres[:: len(centres) // tracked])):
            _wall, cpu, res = _cpu_ms(lambda tf=tf, where=where: render(bgr, tf, True, look, where), 7)
            out[f"dense_boost_{zoom}x_{label}_tracked_painted_pct"] = round(
                100 * float(np.all(res.pixels == BOOST_RGB, axis=2).mean()), 2)
            out[f"dense_boost_{zoom}x_{label}_tracked_cpu_ms"] = round(cpu, 2)
        out[f"dense_boost_{zoom}x_looks_like_markers_pct"] = round(100 * res.marker_share, 1)
        _wall, cpu, _ = _cpu_ms(lambda tf=tf: render(bgr, tf, False), 7)
        out[f"dense_render_{zoom}x_without_boost_cpu_ms"] = round(cpu, 2)
        rgb = np.zeros((54, 98, 3), np.uint8)
        _wall, cpu, labels = _cpu_ms(lambda tf=tf, rgb=rgb: draw_overlays(rgb, tf, Overlays(marks=marks)), 3)
        shown = [m.label for m in marks if tf.contains(m.x, m.y)]
        runs = _runs(labels)
        out[f"dense_ids_{zoom}x_placed"] = f"{sum(r in shown for r in runs)}/{len(shown)}"
        out[f"dense_ids_{zoom}x_overlapping"] = sum(r not in shown for r in runs)
        out[f"dense_ids_{zoom}x_cpu_ms"] = round(cpu, 1)
    write_frames(tmp / "bed", n_frames=steps + 1)
    with Project.create(tmp / "bed.sandtrack", {"side": tmp / "bed"}) as proj:
        proj.set_points([(f, "side", k + 1, float(x), float(y), "tracked") for f in range(steps + 1)
                         for k, (x, y) in enumerate(centres)], "beads")
    latencies, cpu = asyncio.run(_steps(tmp / "bed.sandtrack", steps, (100, 30)))
    out["dense_step_300_markers_ms_median"] = round(statistics.median(latencies), 1)
    out["dense_step_300_markers_cpu_ms"] = round(cpu, 1)
    return out


async def _steps(path: Path, steps: int, size: tuple[int, int]) -> tuple[list[float], float]:
    """Key -> every view decoded, rendered and composed in the running app (ms), and CPU ms per step."""
    from sandtrack_tui.tui.app import SandtrackApp

    app = SandtrackApp(path)
    async with app.run_test(size=size) as pilot:
        for _ in range(300):
            await pilot.pause(0.02)
            if app.views_ready():
                break
        app.step_latencies_ms.clear()
        c0 = time.process_time()
        for _ in range(steps):
            await pilot.press("right")
            t0 = time.perf_counter()
            while not app.views_ready() and time.perf_counter() - t0 < 5:
                await pilot.pause(0.002)
            await pilot.pause(0.05)  # the user's pace
        return list(app.step_latencies_ms), (time.process_time() - c0) * 1000 / steps


def run() -> dict:
    figures = {**label_figures(), **identity_figures()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "mv").mkdir()
        figures.update(multiview_figures(tmp / "mv"))
        figures.update(first_run_figures(tmp))
        figures.update(four_view_figures(tmp))
        figures.update(dense_figures(tmp))
    figures["step_target_ms"] = 100
    return figures


if __name__ == "__main__":
    for k, v in run().items():
        print(f"{k}: {v}")
