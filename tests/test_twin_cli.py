"""`sandtrack sample`: renders a complete sample folder, the same again for the same seed (its frames and
its truth), in agreement with the committed sample; bad input is one clear line."""

import json
import os
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.cli import main
from sandtrack_tui.twin.sample import PRESETS, _experiment_worker
from sandtrack_tui.video import FrameSource

SAMPLE = Path(os.environ.get("SANDTRACK_SAMPLE_DIR") or Path(__file__).resolve().parents[1] / "sample_data")
EXPECTED = [
    "README.md", "board.toml", "calibration/front.mp4", "calibration/reference.toml", "calibration/side.mp4",
    "dem/differences.json", "dem/particles.csv", "experiment/front.mp4", "experiment/side.mp4",
    "ground_truth/calibration_board_poses.csv", "ground_truth/calibration_corners_front.csv",
    "ground_truth/calibration_corners_side.csv", "ground_truth/cameras.toml", "ground_truth/markers_front.csv",
    "ground_truth/markers_side.csv", "ground_truth/scene.json", "ground_truth/sync.json", "ground_truth/tool.csv",
    "ground_truth/trajectories.csv",
]


def test_sample_tiny_writes_every_file_and_renders_the_same_again(tmp_path, capsys):
    """One render through the command line and one of its side camera alone (each render costs seconds)."""
    out = tmp_path / "s"
    assert main(["sample", str(out), "--preset", "tiny", "--seed", "0", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert sorted(res["files"]) == sorted(EXPECTED)
    assert res["experiment_frames"] == PRESETS["tiny"].exp_frames
    ref = tomllib.loads((out / "calibration" / "reference.toml").read_text())
    assert set(ref) >= {"frame", "origin_mm"}
    dem = pd.read_csv(out / "dem" / "particles.csv")
    assert list(dem.columns) == ["particle_id", "time_s", "x", "y", "z"]
    diff = json.loads((out / "dem" / "differences.json").read_text())
    assert diff["time_shift_s"] > 0 and diff["drifting_particles"]
    sync = json.loads((out / "ground_truth" / "sync.json").read_text())
    frames = sync["offset_s"] * sync["fps"]
    assert abs(frames - round(frames)) > 0.1  # not a whole number of frames

    # the same seed again (the side camera's experiment alone): identical frames and truth
    again = _experiment_worker(("side", 0, "tiny", str(tmp_path / "again.mp4")))
    with FrameSource(out / "experiment" / "side.mp4") as a, FrameSource(tmp_path / "again.mp4") as b:
        assert len(a) == len(b) == PRESETS["tiny"].exp_frames
        assert all(np.array_equal(a.frame(i), b.frame(i)) for i in range(len(a)))
    cols = ["frame", "time_s", "scene_time_s", "marker", "X_mm", "Y_mm", "Z_mm", "x_px", "y_px", "visible",
            "visible_fraction"]
    tiny = pd.DataFrame(again["rows"], columns=cols)
    written = pd.read_csv(out / "ground_truth" / "markers_side.csv")
    for c in ("X_mm", "Y_mm", "Z_mm", "x_px", "y_px"):
        assert np.abs(written[c].to_numpy() - tiny[c].to_numpy()).max() < 1e-4  # written to 4 decimals
    assert (written["visible"].to_numpy() == tiny["visible"].to_numpy()).all()

    # and the committed sample's truth over the same frames (its first frames are the tiny preset's)
    if not (SAMPLE / "ground_truth" / "markers_side.csv").is_file():
        pytest.skip("sample_data/ not rendered")
    first = int(round(PRESETS["tiny"].exp_start_s * 50))
    committed = pd.read_csv(SAMPLE / "ground_truth" / "markers_side.csv")
    committed = committed[(committed["frame"] >= first)
                          & (committed["frame"] < first + len(tiny) // 8)].reset_index(drop=True)
    assert len(committed) == len(tiny)
    for c in ("X_mm", "Y_mm", "Z_mm", "x_px", "y_px"):
        assert np.abs(committed[c].to_numpy() - tiny[c].to_numpy()).max() < 1e-4  # measured 5e-5 (4 decimals)
    assert (committed["visible"].to_numpy() == tiny["visible"].to_numpy()).all()


def test_sample_bad_output_is_one_line(tmp_path, capsys):
    f = tmp_path / "file.txt"
    f.write_text("x")
    assert main(["sample", str(f)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a folder" in err[0]
