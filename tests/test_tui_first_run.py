"""First run: the bundled sample project opens synced, calibrated and with its trained network, so the
live table shows XYZ by triangulation and by the network side by side from the first seeded marker."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from conftest import SAMPLE_DATA, claimed, within
from sandtrack_tui.cli.cmd_tui import sample_project
from sandtrack_tui.store import Project
from sandtrack_tui.tracking.run import seed_marker
from sandtrack_tui.tui.app import SandtrackApp
from sandtrack_tui.xyz import xyz_at_frame
from test_tui_app import aio, settle

pytestmark = pytest.mark.skipif(not (SAMPLE_DATA / "model.pt").is_file(),
                                reason="sample_data/ with its trained network is not in this checkout")


@aio
async def test_sample_project_shows_both_xyz_columns_on_first_run(tmp_path):
    path = sample_project(SAMPLE_DATA, tmp_path / "sample.sandtrack")
    truth = json.loads((SAMPLE_DATA / "ground_truth" / "sync.json").read_text())["offset_s"]
    with Project.open(path) as proj:
        # the audio sync, to the mp4's millisecond rounding: README's figure for the sample
        assert within(1000 * abs(proj.sync_offset_s - truth), claimed("sync", "sample"))
        assert proj.calibration() is not None and proj.get("model")["path"].endswith("model.pt")
    side = pd.read_csv(SAMPLE_DATA / "ground_truth" / "markers_side.csv")
    front = pd.read_csv(SAMPLE_DATA / "ground_truth" / "markers_front.csv")
    xyz = pd.read_csv(SAMPLE_DATA / "ground_truth" / "trajectories.csv")
    app = SandtrackApp(path)
    async with app.run_test(size=(200, 55)) as pilot:
        await settle(pilot, app)
        first, _ = app.common_range()
        app.go_to(first)
        marker = 3
        s = side[(side.frame == first) & (side.marker == marker)].iloc[0]
        seed_marker(app.project, marker, "side", first, s.x_px, s.y_px)
        # the front camera's instant lies between two of its frames: XYZ needs a point in both
        j = app.cam_index("front")
        for k in (j - 1, j, j + 1):
            f = front[(front.frame == k) & (front.marker == marker)]
            if len(f):
                seed_marker(app.project, marker, "front", k, f.x_px.iloc[0], f.y_px.iloc[0])
        app.after_edit()
        table = app._w["table"]

        def shown() -> bool:
            return len(table.rows) == 1 and "—" not in {str(v) for v in table.get_row(str(marker))[5:7]}

        await settle(pilot, app, shown)
        row = next(r for r in app.table_rows() if r.marker == marker)
        true = xyz[(xyz.frame == first) & (xyz.marker == marker)][["X_mm", "Y_mm", "Z_mm"]].to_numpy()[0]
        assert np.linalg.norm(np.array(row.xyz_tri) - true) < 0.045  # measured 0.030 mm
        assert np.linalg.norm(np.array(row.xyz_net) - true) < 1.2  # the sample's network: measured 0.80 mm
        # the network's check against triangulation as the core gives it, "!" on the cell when inconsistent
        net = xyz_at_frame(app.project, first)
        net = net[(net.marker == marker) & (net.method == "mlp")]
        assert row.net_check == net.network_check.iloc[0] and row.net_check in ("ok", "inconsistent")
        assert str(table.get_row(str(marker))[6]).endswith("!") == (row.net_check == "inconsistent")
