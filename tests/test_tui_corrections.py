"""Corrections (core, no UI): each is one undoable edit with the expected result."""

from __future__ import annotations

import numpy as np
import pytest

from sandtrack_tui import corrections
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.store import Project


@pytest.fixture
def proj(tmp_path):
    p = Project.create(tmp_path / "c.sandtrack")
    p.add_marker("1", 1)
    p.add_marker("2", 2)
    rows = []
    for f in range(10):
        rows.append({"frame": f, "camera": "side", "marker": 1, "x_px": 10.0 + 2 * f, "y_px": 50.0 - f,
                     "status": "tracked"})
        rows.append({"frame": f, "camera": "side", "marker": 2, "x_px": 300.0, "y_px": 200.0 + f,
                     "status": "tracked"})
    p.set_points(rows, "setup")
    yield p
    p.close()


def test_interpolate_gap_fills_linearly_and_undoes(proj):
    proj.delete_points(1, "side", (3, 6))
    assert corrections.gap_around(proj, 1, "side", 4) == (3, 6)
    n = corrections.interpolate_gap(proj, 1, "side", (3, 6))
    assert n == 4
    pts = proj.points(camera="side", marker=1, frames=(3, 6))
    assert (pts["status"] == "interpolated").all()
    np.testing.assert_allclose(pts["x_px"], 10.0 + 2 * np.arange(3, 7))
    np.testing.assert_allclose(pts["y_px"], 50.0 - np.arange(3, 7))
    assert proj.undo().startswith("interpolate")
    assert proj.points(camera="side", marker=1, frames=(3, 6)).empty


def test_interpolate_needs_anchors(proj):
    with pytest.raises(SandtrackError):
        corrections.interpolate_gap(proj, 1, "side", (20, 30))


def test_swap_over_range_is_one_edit(proj):
    before = proj.points(camera="side")
    n = corrections.swap_markers(proj, 1, 2, (2, 4))
    assert n == 6
    m1 = proj.points(camera="side", marker=1)
    assert m1.set_index("frame").loc[3, "x_px"] == 300.0
    assert m1.set_index("frame").loc[5, "x_px"] == 20.0
    proj.undo()
    after = proj.points(camera="side")
    assert before.equals(after)


def test_swap_moves_points_one_marker_lacks(proj):
    proj.delete_points(2, "side", (3, 3))
    corrections.swap_markers(proj, 1, 2, (3, 3))
    assert proj.points(camera="side", marker=1, frame=3).empty
    assert proj.points(camera="side", marker=2, frame=3)["x_px"].iloc[0] == 16.0


def test_nudge_and_occlude(proj):
    corrections.nudge(proj, 1, "side", 2, 1.5, -0.5)
    r = proj.points(camera="side", marker=1, frame=2).iloc[0]
    assert (r["x_px"], r["y_px"], r["status"]) == (15.5, 47.5, "manual")
    corrections.mark_occluded(proj, 2, "side", (7, 8))
    occ = proj.points(camera="side", marker=2, frames=(7, 8))
    assert (occ["status"] == "occluded").all() and occ["x_px"].isna().all()
    proj.undo()
    proj.undo()
    assert proj.points(camera="side", marker=1, frame=2)["x_px"].iloc[0] == 14.0
