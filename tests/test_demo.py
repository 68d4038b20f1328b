"""The end-to-end regression test: `sandtrack demo --fast` on the bundled sample, scored against truth."""

import json
import subprocess
import sys

import pytest

from conftest import SAMPLE_DATA

pytestmark = pytest.mark.skipif(not (SAMPLE_DATA / "ground_truth" / "cameras.toml").is_file(),
                                reason="sample_data not rendered")


def test_demo_fast_end_to_end(tmp_path):
    out = subprocess.run([sys.executable, "-m", "sandtrack_tui", "demo", "--fast", "--json", "--workdir", tmp_path],
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    stages = json.loads(out.stdout)["stages"]
    assert set(stages) == {"sync", "calibration", "regression", "tracking", "xyz", "export", "compare"}
    assert stages["sync"]["offset_error_ms"] <= 1.0
    cal = stages["calibration"]
    assert cal["reprojection_rmse_px"] < 1.0 and cal["focal_error_pct"] < 0.5 and cal["corner_error_mm"] < 1.0
    reg = stages["regression"]
    # few epochs on the small preset: far from the study's figure, but a real fit
    assert reg["points"] > 1000 and reg["mlp_mean_error_mm"] < 40 and reg["triangulation_mean_error_mm"] < 1.0
    # the network's 95 % intervals on the held-out calibration points, against the true corners (measured 94.8-96.5)
    assert all(92.0 <= reg[f"mlp_coverage95_pct_{a}"] <= 98.5 for a in "xyz")
    assert {"mlp_coverage95_pct_x", "residual_coverage95_pct_z"} <= set(stages["xyz"])
    trk = stages["tracking"]
    assert trk["markers_matched"] == 8 and trk["false_locks"] == 0
    assert trk["mean_error_px"] < 0.5 and trk["hidden_flagged_pct"] > 90
    assert stages["xyz"]["mean_error_mm"] < 2.0
    cmp = stages["compare"]
    assert cmp["particles"] == 8 and cmp["shift_error_frames"] <= 0.5
    assert cmp["flagged_particles"] == cmp["drifting_particles"]
    assert (tmp_path / "trajectories.csv").stat().st_size > 0
