"""Digital twin: the same seed gives identical ground truth and identically decoding videos."""

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.twin.sample import PRESETS, _experiment_worker
from sandtrack_tui.video import FrameSource

SAMPLE = Path(os.environ.get("SANDTRACK_SAMPLE_DIR") or Path(__file__).resolve().parents[1] / "sample_data")


@pytest.fixture(scope="module")
def two_renders(tmp_path_factory):
    out = []
    for name in ("a", "b"):
        path = tmp_path_factory.mktemp("twin") / f"{name}.mp4"
        out.append((path, _experiment_worker(("side", 0, "tiny", str(path)))))
    return out


def test_same_seed_renders_identical_frames_and_truth(two_renders):
    (a, ra), (b, rb) = two_renders
    assert ra["rows"] == rb["rows"] and ra["traj"] == rb["traj"]
    fa, fb = FrameSource(a), FrameSource(b)
    assert len(fa) == len(fb) == PRESETS["tiny"].exp_frames
    for i in range(len(fa)):
        assert np.array_equal(fa.frame(i), fb.frame(i))


@pytest.mark.skipif(not (SAMPLE / "ground_truth" / "markers_side.csv").is_file(), reason="sample_data/ not rendered")
def test_tiny_render_agrees_with_committed_sample_truth(two_renders):
    r = two_renders[0][1]
    cols = ["frame", "time_s", "scene_time_s", "marker", "X_mm", "Y_mm", "Z_mm", "x_px", "y_px", "visible",
            "visible_fraction"]
    tiny = pd.DataFrame(r["rows"], columns=cols)
    first = int(round(PRESETS["tiny"].exp_start_s * 50))
    ref = pd.read_csv(SAMPLE / "ground_truth" / "markers_side.csv")
    ref = ref[(ref["frame"] >= first) & (ref["frame"] < first + len(tiny) // 8)].reset_index(drop=True)
    assert len(ref) == len(tiny)
    for c in ("X_mm", "Y_mm", "Z_mm", "x_px", "y_px"):
        assert np.abs(ref[c].to_numpy() - tiny[c].to_numpy()).max() < 1e-3
    assert (ref["visible"].to_numpy() == tiny["visible"].to_numpy()).all()
