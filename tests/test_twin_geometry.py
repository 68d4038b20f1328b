"""Digital twin: geometry, cameras and the scene's ground truth (no rendering)."""

import numpy as np
import pytest

from sandtrack_tui.camera import Calibration
from sandtrack_tui.twin.rig import SAND_Y, pixel_rays, true_calibration, world_cameras
from sandtrack_tui.twin.scene import (
    MARKER_IDS,
    MARKER_RADIUS,
    MarkerScript,
    SurfaceGrid,
    Timeline,
    ray_box,
    shank_box,
    visible_fraction,
)


def test_true_calibration_round_trip_and_rig_frame(tmp_path):
    cal = true_calibration()
    assert np.allclose(cal.cameras["side"].rvec, 0) and np.allclose(cal.cameras["side"].tvec, 0)
    cal.save(tmp_path / "c.toml")
    back = Calibration.load(tmp_path / "c.toml")
    wc = world_cameras()
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(150, 350, 50), rng.uniform(220, 300, 50), rng.uniform(450, 750, 50)])
    for name in ("side", "front"):
        assert np.abs(back.project_world(name, pts) - wc[name].project(pts)).max() < 1e-6
    # side camera centre in the world = translation of world_from_rig
    assert np.allclose(back.world_from_rig[:3, 3], wc["side"].center_mm)


def test_issue_intrinsics_exact():
    cal = true_calibration()
    f = cal.cameras["front"]
    assert f.matrix[0, 0] == 913.36 and f.matrix[1, 1] == 917.34 and f.matrix[0, 2] == 944.89
    assert list(f.distortion) == [0.01, -0.01, 0.0, -0.01, 0.0]
    s = cal.cameras["side"]
    assert (s.matrix[0, 0], s.matrix[1, 1], s.matrix[0, 2], s.matrix[1, 2]) == (915.81, 919.63, 944.03, 544.69)
    assert (s.width, s.height) == (1920, 1080)


@pytest.mark.parametrize("name", ["side", "front"])
def test_pixel_rays_invert_projection(name):
    cam = world_cameras()[name]
    xs = np.array([0.0, 100.5, 960.0, 1919.0, 1500.25])
    ys = np.array([0.0, 1079.0, 540.0, 10.0, 800.75])
    o, d = pixel_rays(cam, xs, ys)
    px = cam.project(o + 600.0 * d)
    assert np.abs(px - np.column_stack([xs, ys])).max() < 1e-6


def test_markers_size_in_pixels():
    wc = world_cameras()
    p0 = MarkerScript(0, Timeline()).p0
    for name, lo, hi in (("side", 9.0, 12.0), ("front", 7.0, 12.0)):
        cam = wc[name]
        for P in p0.values():
            diam = 2 * MARKER_RADIUS * cam.matrix[0, 0] / np.linalg.norm(P - cam.center_mm)
            assert lo <= diam <= hi


def test_incremental_surface_equals_rebuild():
    tl = Timeline()
    a = SurfaceGrid(3)
    for t in np.arange(3.0, 4.0, 0.02):
        a.set_tool(float(tl.tool_z(t)))
    b = SurfaceGrid(3)
    b.set_tool(float(tl.tool_z(3.98)))
    assert np.abs(a.H - b.H).max() < 1e-4
    # the one-point evaluation used for marker heights agrees with the grid
    rng = np.random.default_rng(0)
    for X, Z in zip(rng.uniform(140, 360, 30), rng.uniform(300, 700, 30), strict=True):
        assert abs(b.height_at(X, Z, b.zt) - float(b.height(X, Z))) < 1e-4


def test_markers_never_inside_the_shank_and_rest_on_sand():
    tl = Timeline()
    script = MarkerScript(0, tl)
    surf = SurfaceGrid(0)
    for t in np.arange(0.0, tl.tool_end_s + 0.5, 0.02):
        zt = float(tl.tool_z(t))
        box = shank_box(zt)
        for P in script.positions(t, surf).values():
            gap = np.maximum(np.maximum(box[0] - P, P - box[1]), 0)
            assert np.linalg.norm(gap) >= MARKER_RADIUS - 0.2, (t, P, zt)
    # untouched markers rest on the flat sand
    P = script.positions(0.0, surf)
    assert all(abs(P[m][1] - (SAND_Y + MARKER_RADIUS)) < 1e-3 for m in MARKER_IDS)


def test_visibility_rules():
    tl = Timeline()
    script = MarkerScript(0, tl)
    surf = SurfaceGrid(0)
    cams = world_cameras()
    surf.set_tool(float(tl.tool_z(0.0)))
    pos = script.positions(0.0, surf)
    for cam in cams.values():
        assert all(visible_fraction(cam, P, surf.zt, surf) == 1.0 for P in pos.values())
    # a marker sunk 10 mm under the surface is invisible; one behind the shank too
    P = pos[1] - np.array([0, 2 * MARKER_RADIUS + 5, 0])
    assert visible_fraction(cams["side"], P, surf.zt, surf) == 0.0
    box = shank_box(surf.zt)
    centre = box.mean(axis=0)
    centre[1] = SAND_Y + MARKER_RADIUS
    side = cams["side"].center_mm
    behind = centre + (centre - side) / np.linalg.norm(centre - side) * 30.0
    behind[1] = SAND_Y + MARKER_RADIUS + 5
    t, _ = ray_box(side, (behind - side)[None] / np.linalg.norm(behind - side), box)
    assert np.isfinite(t[0])
    assert visible_fraction(cams["side"], behind, surf.zt, surf) < 0.2


def test_full_preset_has_the_studys_number_of_two_view_observations():
    from sandtrack_tui.twin.sample import two_view_observations

    assert two_view_observations("full") >= 44130
