"""Tracking on the committed digital-twin sample (sample_data/), against its ground truth.

A 130-frame stretch where the tool passes: markers pushed, hidden behind the tool or under sand,
reappearing. Skipped when sample_data/ is absent.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.camera import Calibration
from sandtrack_tui.store import Project
from sandtrack_tui.tracking.run import accept_seeds, camera_offsets, paired_frame, track_project
from sandtrack_tui.tracking.seeding import snap_to_marker

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data"
pytestmark = pytest.mark.skipif(not (SAMPLE / "ground_truth" / "cameras.toml").exists(),
                                reason="sample_data/ not rendered")
START, STOP = 200, 330


def test_sample_stretch_with_occlusions(tmp_path):
    gt = SAMPLE / "ground_truth"
    videos = {c: SAMPLE / "experiment" / f"{c}.mp4" for c in ("side", "front")}
    truth = {c: pd.read_csv(gt / f"markers_{c}.csv") for c in videos}
    proj = Project.create(tmp_path / "s.sandtrack", videos)
    proj.set_calibration(Calibration.load(gt / "cameras.toml"))
    proj.set("sync_offset_s", json.loads((gt / "sync.json").read_text())["offset_s"])
    sources = proj.open_sources(cache_mb=64)
    offsets = camera_offsets(proj, ["side", "front"])
    rows = []
    for cam in videos:
        f = START if cam == "side" else paired_frame(sources, offsets, "side", START, cam)[0]
        img = sources[cam].frame(f)
        for r in truth[cam].query("frame == @f and visible == 1").itertuples():
            x, y = snap_to_marker(img, r.x_px + 2.0, r.y_px - 1.5)  # an operator's click, snapped
            rows.append((int(r.marker), cam, f, x, y, 16.0, 16.0))
    accept_seeds(proj, pd.DataFrame(rows, columns=["marker", "camera", "frame", "x_px", "y_px", "w", "h"]))
    summary = track_project(proj, start=START, stop=STOP, sources=sources)
    assert summary["stereo"] and summary["frames"] == STOP - START + 1
    pts = proj.points()
    errs, hidden_flagged, flagged_hidden = [], [], []
    for cam, t in truth.items():
        p = pts[(pts.camera == cam) & (pts.status != "manual")].merge(t, on=["frame", "marker"], suffixes=("", "_t"))
        p["err"] = np.hypot(p.x_px - p.x_px_t, p.y_px - p.y_px_t)
        vis = p[p.visible == 1]
        assert (vis.status == "tracked").mean() > 0.991  # measured 99.4 % side, 99.9 % front
        errs.append(vis[vis.status == "tracked"].err.to_numpy())
        hidden_flagged.append(p[p.visible == 0].status.isin(["occluded", "lost"]).to_numpy())
        flagged_hidden.append((p[p.status.isin(["occluded", "lost"])].visible == 0).to_numpy())
    e = np.concatenate(errs)
    hf, fh = np.concatenate(hidden_flagged), np.concatenate(flagged_hidden)
    assert e.max() < 3.0, "false lock"
    # The busiest stretch (markers pushed and rolling): the whole clip does better (README's 0.198 / 0.498 px).
    # Measured here: 0.349 / 0.770 px, hidden frames flagged 99.7 % (1 of 340 missed), flags truly hidden 98.3 %.
    assert e.mean() < 0.52 and np.percentile(e, 95) < 1.15
    assert len(hf) > 300 and 1 - hf.mean() <= 1.5 * 0.003
    assert 1 - fh.mean() <= 1.5 * 0.0174
    for s in sources.values():
        s.close()
