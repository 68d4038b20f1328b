"""Core pieces of the operator's session: auto-seed identities, merge and rename, the one-camera
scale, XYZ at an instant from any number of cameras, camera clocks."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest

from sandtrack_tui import corrections, scale, xyz
from sandtrack_tui.camera import Calibration, Camera
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.store import Project
from sandtrack_tui.tracking.identity import known_positions, match_proposals, number_proposals
from sandtrack_tui.video import camera_offsets, synced_camera
from tui_synth import calibration, true_xyz


def proposal(rows):
    return pd.DataFrame(rows, columns=["marker", "camera", "frame", "x_px", "y_px", "w", "h", "epipolar_px"])


def points(rows):
    return pd.DataFrame(rows, columns=["frame", "camera", "marker", "x_px", "y_px", "status"])


# -- identities ------------------------------------------------------------------------------
def test_known_position_is_the_nearest_usable_point_in_time():
    pts = points([(0, "side", 1, 10.0, 10.0, "manual"), (8, "side", 1, 30.0, 10.0, "tracked"),
                  (10, "side", 1, np.nan, np.nan, "occluded"), (12, "side", 1, 50.0, 10.0, "tracked"),
                  (11, "side", 2, 90.0, 90.0, "lost")])
    known = known_positions(pts, {"side": 10})
    assert len(known) == 1  # marker 2 is only known as lost: no position
    r = known.iloc[0]
    assert (r.marker, r.x_px, r.gap_frames) == (1, 30.0, 2)  # frames 8 and 12 tie: the earlier wins


def test_blobs_take_their_markers_ids_and_the_rest_are_numbered_after_the_highest():
    # two touching beads (10 px apart) known in this frame, a third bead nobody has seen yet
    known = pd.DataFrame([(3, "side", 100.0, 100.0, 0), (7, "side", 110.0, 100.0, 0), (3, "front", 200.0, 50.0, 0),
                          (7, "front", 212.0, 50.0, 0)], columns=["marker", "camera", "x_px", "y_px", "gap_frames"])
    props = proposal([(1, "side", 5, 110.4, 100.2, 14, 14, 0.1), (1, "front", 5, 212.3, 50.1, 14, 14, 0.1),
                      (2, "side", 5, 99.7, 100.1, 14, 14, 0.2), (2, "front", 5, 200.2, 49.9, 14, 14, 0.2),
                      (3, "side", 5, 300.0, 40.0, 14, 14, 0.3), (3, "front", 5, 330.0, 20.0, 14, 14, 0.3)])
    matches = match_proposals(props, known)
    assert {p: m for p, (m, _d) in matches.items()} == {1: 7, 2: 3}
    out = number_proposals(props, matches, next_id=8)
    assert list(out.drop_duplicates("marker")["marker"]) == [7, 3, 8]
    assert out["existing"].tolist() == [True] * 4 + [False] * 2


def test_a_blob_beyond_half_a_bead_from_a_marker_known_now_is_new():
    known = pd.DataFrame([(1, "side", 100.0, 100.0, 0)], columns=["marker", "camera", "x_px", "y_px", "gap_frames"])
    near = proposal([(1, "side", 0, 104.0, 100.0, 14, 14, np.nan)])  # 10 px bead: within 5 px
    far = proposal([(1, "side", 0, 106.0, 100.0, 14, 14, np.nan)])
    assert match_proposals(near, known) and not match_proposals(far, known)
    # seen 20 frames ago: it may have moved since, up to 2 px a frame
    old = known.assign(gap_frames=20)
    assert match_proposals(proposal([(1, "side", 0, 140.0, 100.0, 14, 14, np.nan)]), old)
    assert not match_proposals(proposal([(1, "side", 0, 150.0, 100.0, 14, 14, np.nan)]), old)
    # in one camera the blob fits, in the other it lies on another bead: not this marker
    both = pd.concat([known, known.assign(camera="front")])
    split = proposal([(1, "side", 0, 101.0, 100.0, 14, 14, 0.5), (1, "front", 0, 160.0, 100.0, 14, 14, 0.5)])
    assert not match_proposals(split, both)
    # unpaired (touching lookalikes): one proposal per camera, each on the marker's place in its camera
    unpaired = proposal([(1, "side", 0, 101.0, 100.0, 14, 14, np.nan), (2, "front", 0, 99.5, 100.0, 14, 14, np.nan)])
    assert {p: m for p, (m, _d) in match_proposals(unpaired, both).items()} == {1: 1, 2: 1}


# -- merge and rename ----------------------------------------------------------------------------
@pytest.fixture
def proj(tmp_path):
    p = Project.create(tmp_path / "p.sandtrack")
    yield p
    p.close()


def test_merge_keeps_the_better_point_and_is_one_edit(proj):
    for m in (1, 2):
        proj.add_marker(str(m), m)
    rows = [(0, "side", 1, 10.0, 10.0, "lost", None, None, None), (0, "side", 2, 11.0, 10.0, "tracked", 0.9, 5, 1),
            (1, "side", 1, 12.0, 10.0, "manual", 1.0, None, None), (1, "side", 2, 13.0, 10.0, "tracked", 0.9, 5, 1),
            (2, "side", 2, 14.0, 10.0, "interpolated", None, None, None),
            (3, "side", 1, 15.0, 10.0, "tracked", 0.8, 4, 1), (3, "side", 2, 16.0, 10.0, "tracked", 0.9, 5, 1)]
    proj.set_points(rows, "tracks")
    proj.set("tracking_boxes", {"1/side": [10, 10], "2/side": [12, 12], "2/front": [14, 14]})
    before = proj.points()
    edits = len(proj.history())
    assert corrections.merge_markers(proj, 1, 2) == 2  # frames 0 (tracked beats lost) and 2 (only 2 had one)
    # (the box a track starts from: the dropped marker's in a camera where the kept one has none)
    assert proj.get("tracking_boxes") == {"1/side": [10, 10], "1/front": [14, 14]}
    got = proj.points().set_index("frame")
    assert set(got.marker) == {1} and list(proj.markers()["id"]) == [1]
    assert got.loc[0, "x_px"] == 11.0 and got.loc[1, "x_px"] == 12.0 and got.loc[2, "status"] == "interpolated"
    assert got.loc[3, "x_px"] == 15.0  # a tie: the kept marker's point
    assert len(proj.history()) == edits + 1
    assert proj.undo().startswith("merge marker 2 into 1")
    assert proj.points().equals(before) and list(proj.markers()["id"]) == [1, 2]
    assert proj.get("tracking_boxes") == {"1/side": [10, 10], "2/side": [12, 12], "2/front": [14, 14]}
    with pytest.raises(SandtrackError, match="two different"):
        corrections.merge_markers(proj, 1, 1)
    with pytest.raises(SandtrackError, match="no marker 9"):
        corrections.merge_markers(proj, 1, 9)


def test_rename_is_one_undoable_edit_and_checks_the_label(proj):
    proj.add_marker("1", 1)
    corrections.rename_marker(proj, 1, "A3")
    assert proj.markers()["label"].tolist() == ["A3"]
    assert proj.undo() == "rename marker 1 to A3" and proj.markers()["label"].tolist() == ["1"]
    for bad in ("", "x" * 17, "a\nb"):
        with pytest.raises(SandtrackError, match="printable"):
            corrections.rename_marker(proj, 1, bad)


# -- one camera: scale ---------------------------------------------------------------------------
def _facing_camera(depth_mm=1000.0, focal=800.0) -> Calibration:
    """One camera looking at a world whose origin lies `depth_mm` straight ahead."""
    cam = Camera("side", 640, 360, [[focal, 0, 320], [0, focal, 180], [0, 0, 1]], np.zeros(5))
    world = np.eye(4)
    world[2, 3] = -depth_mm  # world = rig - (0, 0, depth): the world origin is the rig point (0, 0, depth)
    return Calibration({"side": cam}, world)


def test_scale_from_a_known_length_and_from_a_calibration_agree(proj):
    cal = _facing_camera()
    s_cal = scale.from_calibration(cal, "side")
    assert s_cal == pytest.approx(1000.0 / 800.0)
    # two points 100 mm apart at the world origin's depth, as the camera sees them
    a, b = cal.cameras["side"].project(cal.to_rig(np.array([[0.0, 0, 0], [60.0, 80.0, 0]])))
    assert scale.from_length(a, b, 100.0) == pytest.approx(s_cal, rel=1e-9)
    assert np.allclose(scale.to_mm([b], s_cal) - scale.to_mm([a], s_cal), [[60.0, 80.0]])
    assert scale.project_scale(proj, "side", cal)[0] == pytest.approx(s_cal)
    scale.set_scale(proj, "side", 0.5, "test")  # a known length, once set, wins
    assert scale.project_scale(proj, "side", cal) == (0.5, "test")
    with pytest.raises(SandtrackError, match="2 px apart"):
        scale.from_length((10, 10), (10.5, 10), 5.0)
    with pytest.raises(SandtrackError, match="positive"):
        scale.from_length((10, 10), (50, 10), -5.0)


# -- several cameras -------------------------------------------------------------------------------
def test_camera_clocks():
    assert synced_camera(["side"]) is None and synced_camera(["a", "b"]) == "b"
    assert synced_camera(["side", "front", "top"]) == "front" and synced_camera(["a", "b", "c"]) is None
    assert camera_offsets(["side", "top", "front"], 0.3) == {"side": 0.0, "top": 0.0, "front": 0.3}


def test_xyz_at_an_instant_from_three_cameras_interpolates_the_late_one(tmp_path):
    cams = ["side", "front", "top"]
    for cam in cams:  # stand-ins for the videos (50 fps): only their clocks matter here
        (tmp_path / cam).mkdir()
        for f in range(4):
            cv2.imwrite(str(tmp_path / cam / f"{f}.png"), np.zeros((360, 640, 3), np.uint8))
    proj = Project.create(tmp_path / "p.sandtrack", {c: tmp_path / c for c in cams})
    proj.set("sync_offset_s", 0.01)  # front started half a frame later (50 fps)
    proj.set_calibration(calibration(cams))
    rows = []
    for f in range(4):
        for cam in cams:
            # the front camera's frame f shows the scene half a frame after the side camera's frame f
            t = f + (0.5 if cam == "front" else 0.0)
            p = true_xyz(2, 0) + t * (true_xyz(2, 1) - true_xyz(2, 0))
            x, y = calibration(cams).cameras[cam].project(p[None])[0]
            rows.append((f, cam, 2, float(x), float(y), "tracked", None, None, None))
    proj.set_points(rows, "tracks")
    out = xyz.xyz_at_frame(proj, 2)  # triangulation only: the project has no network
    assert len(out) == 1 and (out[["status_side", "status_front", "status_top"]] == "tracked").all(axis=None)
    assert list(out.columns) == xyz.xyz_columns(cams) and {"xs", "xf", "x_top"} <= set(out.columns)
    assert np.linalg.norm(out[["X_mm", "Y_mm", "Z_mm"]].to_numpy()[0] - true_xyz(2, 2)) < 0.001
    assert out.residual_px.iloc[0] < 1e-4
    # with one camera only the marker has no XYZ
    proj.delete_points(2, "front")
    proj.delete_points(2, "top")
    out = xyz.xyz_at_frame(proj, 2)
    assert out.status_front.iloc[0] == "missing" and out[["X_mm", "Y_mm", "Z_mm"]].isna().all(axis=None)
    proj.close()


def test_new_project_with_more_cameras(tmp_path, capsys):
    from sandtrack_tui.cli import main

    for cam in ("a", "b", "c"):
        (tmp_path / cam).mkdir()
        cv2.imwrite(str(tmp_path / cam / "0.png"), np.zeros((36, 64, 3), np.uint8))
    path = tmp_path / "p.sandtrack"
    assert main(["new", str(path), "--side", str(tmp_path / "a"), "--front", str(tmp_path / "b"),
                 "--camera", f"top={tmp_path / 'c'}"]) == 0
    with Project.open(path) as proj:
        assert proj.cameras() == ["side", "front", "top"]
    capsys.readouterr()
    assert main(["new", str(tmp_path / "q.sandtrack"), "--side", str(tmp_path / "a"), "--camera", "top"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "NAME=PATH" in err[0]
