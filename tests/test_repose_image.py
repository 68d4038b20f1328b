"""Angle of repose from side photos and videos: rendered heaps of known angle (the twin's renderer), a heap
drawn with plain OpenCV shapes (not the renderer), a rolled camera, a camera above the heap, bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from sandtrack_tui.camera import Calibration, Camera
from sandtrack_tui.cli import main
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.repose import measure_path
from sandtrack_tui.repose.fit import robust_line, settled_value
from sandtrack_tui.repose.image import measure_image
from sandtrack_tui.twin.heap import Heap, Shot, render_heap
from sandtrack_tui.twin.repose_sample import HIGH, LEVEL

W, H = 960, 540
TARGET_DEG = 0.5
# (left, right angle), shot settings: a low lamp at the left (one flank in shade, a long shadow on the
# plate); a black backdrop lit from the right; the heap's shadow on a close backdrop next to its left flank
SCENES = {
    "low lamp": ((25.0, 25.0), dict(lamp_mm=(-600.0, 250.0, 300.0), backdrop_z_mm=-300.0)),
    "black backdrop, asymmetric": ((33.0, 40.0), dict(lamp_mm=(500.0, 350.0, 300.0), backdrop_z_mm=-200.0,
                                                      backdrop_bgr=(0.06, 0.06, 0.07))),
    "shadow beside the flank": ((31.0, 31.0), dict(lamp_mm=(260.0, 140.0, 520.0), backdrop_z_mm=-130.0)),
}


@pytest.fixture(scope="module")
def textures():
    from sandtrack_tui.twin.textures import Textures

    return Textures(0)


def _calibration(shot: Shot) -> Calibration:
    cam = shot.camera()
    world_from_rig = np.eye(4)
    world_from_rig[:3, :3] = cam.R.T
    world_from_rig[:3, 3] = cam.center_mm
    return Calibration({"side": Camera("side", cam.width, cam.height, cam.matrix, cam.distortion)}, world_from_rig)


@pytest.fixture(scope="module")
def photos(textures):
    out = {}
    for k, (name, ((al, ar), kw)) in enumerate(SCENES.items()):
        shot = Shot(**LEVEL, width=W, height=H, **kw)
        heap = Heap(height_mm=75.0, angle_left_deg=al, angle_right_deg=ar, rough_seed=k)
        out[name] = (render_heap(heap, shot, k, textures), shot, (al, ar))
    return out


@pytest.mark.parametrize("scene", list(SCENES))
def test_rendered_heaps_within_half_a_degree(photos, scene):
    img, shot, (al, ar) = photos[scene]
    for cal in (None, _calibration(shot)):
        r = measure_image(img, calibration=cal)
        assert abs(r.flanks["left"].angle_deg - al) < TARGET_DEG
        assert abs(r.flanks["right"].angle_deg - ar) < TARGET_DEG
        assert abs(r.angle_deg - (al + ar) / 2) < TARGET_DEG
        assert 0.01 < r.sigma_deg < 0.5  # an honest, non-zero uncertainty
        assert all(f.band == (0.2, 0.8) for f in r.flanks.values())  # a level camera sees straight flanks


def test_camera_above_the_heap_is_corrected_by_its_calibration(textures):
    shot = Shot(**HIGH, width=W, height=H, lamp_mm=(-300.0, 500.0, 400.0))
    img = render_heap(Heap(height_mm=75.0, angle_left_deg=34.0, angle_right_deg=34.0, rough_seed=5), shot, 5, textures)
    plain = measure_image(img)
    assert plain.angle_deg < 34.0 - 1.5  # perspective: the image's slopes are not the heap's
    cal = measure_image(img, calibration=_calibration(shot))
    assert abs(cal.angle_deg - 34.0) < TARGET_DEG
    assert all(f.band[0] > 0.2 for f in cal.flanks.values())  # the plate's rim below the flanks is left out


def drawn_heap(angle_left: float, angle_right: float, roll_deg: float = 0.0, seed: int = 0) -> np.ndarray:
    """A heap drawn with OpenCV shapes: straight flanks at the given angles, a circular cap, a toe; grain
    noise, a light gradient across the backdrop and a dark shadow beside the right flank."""
    rng = np.random.default_rng(seed)
    h, w = 600, 1000
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.dstack([150 + 60 * xx / w, 155 + 55 * xx / w, 160 + 50 * xx / w])  # uneven light
    img[yy > 430] = (70, 75, 80)  # the table
    base_y, apex_x = 430.0, 500.0
    tl, tr = np.tan(np.radians(angle_left)), np.tan(np.radians(angle_right))
    height = 230.0
    x = np.arange(0, w, 0.25)
    yl = base_y - height + (apex_x - x) * tl  # flanks as lines through a common apex
    yr = base_y - height + (x - apex_x) * tr
    y = np.maximum(yl, yr)
    cap = 40.0  # a round top: the parabola tangent to both flanks
    top = np.abs(x - apex_x) < cap
    y[top] = (base_y - height + cap * (tl + tr) / 4) + (x[top] - apex_x) ** 2 * (tl + tr) / (4 * cap) \
        + (apex_x - x[top]) * (tl - tr) / 2
    inside = y < base_y
    poly = np.column_stack([x[inside], y[inside]])  # from toe to toe, closed along the base line
    shadow = np.array([[apex_x + 60, base_y - height + 60 * tr + 10], [w - 50, base_y - 60], [w - 50, base_y]])
    cv2.fillPoly(img, [np.round(np.vstack([shadow, [[apex_x + 60, base_y]]]) * 16).astype(np.int32)],
                 (60, 62, 66), lineType=cv2.LINE_AA, shift=4)
    sand = np.zeros((h, w), np.uint8)
    cv2.fillPoly(sand, [np.round(np.vstack([poly, [[poly[-1, 0], base_y + 8], [poly[0, 0], base_y + 8]]]) * 16)
                        .astype(np.int32)], 255, lineType=cv2.LINE_AA, shift=4)
    a = sand.astype(np.float32)[..., None] / 255.0
    grain = 1 + 0.12 * cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 0.8)[..., None]
    shade = (0.75 + 0.4 * (xx < apex_x))[..., None]  # the left flank lit, the right one in shade
    img = img * (1 - a) + a * np.array([95.0, 140.0, 175.0]) * grain * shade
    img += rng.normal(0, 2.0, img.shape)
    if roll_deg:
        M = cv2.getRotationMatrix2D((w / 2, h / 2), roll_deg, 1.0)
        img = cv2.warpAffine(img, M, (w, h), borderMode=cv2.BORDER_REFLECT)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_drawn_heap_not_made_by_the_renderer():
    r = measure_image(drawn_heap(30.0, 36.0))
    assert abs(r.flanks["left"].angle_deg - 30.0) < 0.02  # measured 0.011 deg
    assert abs(r.flanks["right"].angle_deg - 36.0) < 0.02  # 0.004


def test_rolled_camera_tilts_the_flanks_but_not_their_mean():
    r = measure_image(drawn_heap(33.0, 33.0, roll_deg=2.0))
    left, right = r.flanks["left"].angle_deg, r.flanks["right"].angle_deg
    assert left - 33.0 > 1.5 and right - 33.0 < -1.5  # turned anticlockwise: left steeper, right shallower
    assert abs(r.angle_deg - 33.0) < 0.013  # measured 0.0084 deg
    assert abs(r.base_tilt_deg + 2.0) < 0.06 and any("off level" in w for w in r.warnings)


def test_one_flank_only_and_the_cli(tmp_path, capsys):
    p = tmp_path / "heap.png"
    cv2.imwrite(str(p), drawn_heap(30.0, 36.0))
    assert main(["repose", str(p), "--side", "right", "--scale-mm-per-px", "0.5", "--json",
                 "--plot", str(tmp_path / "fig.png")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out["flanks"]) == ["right"] and abs(out["angle_deg"] - 36.0) < 0.02
    assert out["height_mm"] == pytest.approx(out["height_px"] * 0.5)
    assert (tmp_path / "fig.png").stat().st_size > 10_000


def test_no_heap_is_one_clear_error(tmp_path, capsys):
    p = tmp_path / "empty.png"
    cv2.imwrite(str(p), np.full((300, 400, 3), 128, np.uint8))
    with pytest.raises(SandtrackError, match="no heap found"):
        measure_path(p)
    assert main(["repose", str(p)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no heap found" in err[0]
    assert main(["repose", str(tmp_path / "missing.jpg")]) == 1
    assert main(["repose", str(p), "--band", "0.7,0.8"]) == 1


def test_video_gives_the_angle_over_time_and_the_settled_value(tmp_path, capsys):
    from sandtrack_tui.twin.writer import Mp4Writer

    fps, n = 5.0, 6
    angles = [38.0, 35.0, 33.6] + [33.0] * (n - 3)  # settled from the 4th frame (0.6 s)
    with Mp4Writer(tmp_path / "v.mp4", 1000, 600, fps, np.zeros(int(n / fps * 48000), np.float32), crf=18) as w:
        for k, a in enumerate(angles):
            w.write(drawn_heap(a, a, seed=k))
    assert main(["repose", str(tmp_path / "v.mp4"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    got = [s["angle_deg"] for s in out["samples"]]
    assert len(got) == n and np.max(np.abs(np.array(got) - angles)) < 0.042  # measured 0.028
    assert abs(out["settled"]["angle_deg"] - 33.0) < 0.0093  # measured 0.0062 deg
    assert out["settled"]["from_s"] == pytest.approx(0.6, abs=0.21)


def test_robust_line_and_settled_value_known_answers():
    rng = np.random.default_rng(0)
    x = np.arange(200.0)
    y = 3.0 - 0.7 * x + rng.normal(0, 0.2, len(x))
    y[::10] += 40.0  # 10 % gross outliers
    fit = robust_line(x, y)
    assert fit.slope == pytest.approx(-0.7, abs=0.0004) and not fit.inliers[::10].any()
    assert 0.0 < fit.slope_sigma < 0.0004  # measured 0.00026
    t = np.arange(40) * 0.1
    a = 33.0 + 6.0 * np.exp(-t / 0.4) + rng.normal(0, 0.05, len(t))
    s = settled_value(t, a)
    assert s.angle_deg == pytest.approx(33.0, abs=0.022)
    assert 1.2 < s.from_s < 2.2  # 6 exp(-t / 0.4) falls under 0.3 deg (the floor) at t = 1.2 s
