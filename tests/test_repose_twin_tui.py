"""`sandtrack sample --preset repose` (file layout and ground truth, in its quick form) and the TUI's repose
screen (F7) measuring a dump and running a sweep."""

from __future__ import annotations

import asyncio
import functools
import json
import re

import numpy as np
import pandas as pd

from sandtrack_tui.repose import measure_path
from sandtrack_tui.tui.app import SandtrackApp
from sandtrack_tui.twin.heap import Heap
from sandtrack_tui.twin.heap_particles import heap_particles, write_liggghts_dump
from sandtrack_tui.twin.repose_sample import render_repose
from tui_synth import make_frames, make_project


def test_repose_preset_writes_photos_dumps_video_and_truth(tmp_path):
    res = render_repose(tmp_path, seed=1, quick=True)
    truth = json.loads((tmp_path / "ground_truth" / "repose.json").read_text())
    assert res["heaps"] == len(truth) == 23
    kinds = {e["kind"] for e in truth}
    assert kinds == {"photo", "dump", "csv", "video"}
    for e in truth:
        assert (tmp_path / e["file"]).is_file() and isinstance(e["angle_deg"], float)
        assert 25.0 - 0.5 <= e["angle_deg"] <= 41.0
    photos = [e["angle_deg"] for e in truth if e["kind"] == "photo" and "heap_0" in e["file"]]
    assert len(photos) == 6 and max(photos) - min(photos) > 14  # 25 to 40 deg, jittered by the seed
    assert (tmp_path / "repose" / "README.md").read_text().startswith("# Heaps of known angle")
    dump = next(e for e in truth if e["file"].endswith("heap_03.liggghts"))
    # coarse particles (measured 0.17 deg)
    assert abs(measure_path(tmp_path / dump["file"]).angle_deg - dump["angle_deg"]) < 0.25


def aio(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        return asyncio.run(fn(*args, **kwargs))

    return wrapper


async def _run(pilot, app, path: str, target: str = "") -> str:
    app.screen.query_one("#path").value = path
    app.screen.query_one("#target").value = target
    await pilot.click("#run")
    for _ in range(600):
        await pilot.pause(0.05)
        if app.bg_task is None and str(app.screen.query_one("#result").render()).strip():
            break
    return str(app.screen.query_one("#result").render())


@aio
async def test_repose_screen_measures_a_dump_and_ranks_a_sweep(tmp_path):
    P, rad = heap_particles(Heap(height_mm=55.0, angle_left_deg=35.0, angle_right_deg=35.0), seed=3,
                            diameter_mm=4.0, rounds=25)
    write_liggghts_dump(tmp_path / "heap.liggghts", [(1000, P, rad)])
    runs = pd.DataFrame({"run": ["a", "b", "c", "d", "e", "f"], "mu": [0.1, 0.2, 0.3, 0.1, 0.2, 0.3],
                         "e": [0.3, 0.3, 0.3, 0.6, 0.6, 0.6], "angle_deg": [27.0, 31.5, 34.0, 26.0, 30.5, 33.0]})
    runs.to_csv(tmp_path / "runs.csv", index=False)
    project = make_project(tmp_path, frames=make_frames(tmp_path / "frames"))
    app = SandtrackApp(project)
    async with app.run_test(size=(120, 50)) as pilot:
        await pilot.pause()
        await pilot.press("f7")
        await pilot.pause(0.2)
        text = await _run(pilot, app, str(tmp_path / "heap.liggghts"))
        angle = float(re.search(r"angle of repose ([\d.]+) deg", text).group(1))
        assert abs(angle - 35.0) < 0.23  # measured 0.15
        text = await _run(pilot, app, str(tmp_path / "runs.csv"), target="31.5")
        ranked = [ln.split()[1] for ln in text.splitlines() if re.match(r"\s*\d+(\.0+)?\s+[a-f]\s", ln)]
        assert ranked[0] == "b" and "suggested parameters" in text
        await pilot.press("escape")
        assert app.screen is app._main_screen
    project.close()
    assert np.isfinite(angle)
