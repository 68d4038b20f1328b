"""`sandtrack sample`: renders a complete sample folder; bad input is one clear line."""

import json
import tomllib

import pandas as pd

from sandtrack_tui.cli import main
from sandtrack_tui.twin.sample import PRESETS

EXPECTED = [
    "README.md", "board.toml", "calibration/front.mp4", "calibration/reference.toml", "calibration/side.mp4",
    "dem/differences.json", "dem/particles.csv", "experiment/front.mp4", "experiment/side.mp4",
    "ground_truth/calibration_board_poses.csv", "ground_truth/calibration_corners_front.csv",
    "ground_truth/calibration_corners_side.csv", "ground_truth/cameras.toml", "ground_truth/markers_front.csv",
    "ground_truth/markers_side.csv", "ground_truth/scene.json", "ground_truth/sync.json", "ground_truth/tool.csv",
    "ground_truth/trajectories.csv",
]


def test_sample_tiny_writes_every_file(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["sample", str(out), "--preset", "tiny", "--seed", "2", "--json"]) == 0
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


def test_sample_bad_output_is_one_line(tmp_path, capsys):
    f = tmp_path / "file.txt"
    f.write_text("x")
    assert main(["sample", str(f)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a folder" in err[0]
