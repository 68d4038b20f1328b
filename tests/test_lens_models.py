"""Every lens model through every reader of a camera: projection against OpenCV, undistortion,
the calibration file, triangulation with 2..N cameras, the tracker's stereo check, the epipolar
curve, the residual regression variant's triangulation, and the Caliscope export."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sandtrack_tui.calibration.caliscope import export_caliscope, import_caliscope
from sandtrack_tui.camera import Calibration, Camera
from sandtrack_tui.epipolar import epipolar_curve
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.lens import LENSES, lens_of, project
from sandtrack_tui.tracking.stereo import StereoCheck
from sandtrack_tui.triangulation import triangulate

# Coefficients of each model's terms, of the size real lenses show (a GoPro-like wide lens for the
# radial terms, small decentring, prism and tilt); the fisheye a real equidistant lens.
TERM_VALUES = {"k1": -0.2, "k2": 0.04, "p1": 0.0012, "p2": -0.0009, "k3": -0.003, "k4": -0.05, "k5": 0.01,
               "k6": -0.002, "s1": 0.0015, "s2": -0.0004, "s3": -0.0011, "s4": 0.0003, "tau_x": 0.01,
               "tau_y": -0.008}
FISHEYE = np.array([0.05, -0.01, 0.004, -0.001])


def coefficients(lens) -> np.ndarray:
    if lens.family == "fisheye":
        return FISHEYE.copy()
    from sandtrack_tui.lens import TERMS

    d = np.zeros(lens.length)
    for i, t in enumerate(TERMS[: lens.length]):
        if t in lens.terms:
            d[i] = TERM_VALUES[t]
    return d


def look_at(centre, target=(0.0, 0.0, 0.0)):
    z = np.asarray(target, float) - np.asarray(centre, float)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return cv2.Rodrigues(R)[0].ravel(), -R @ np.asarray(centre, float)


def rig(lens_name: str, n_cameras: int = 3) -> Calibration:
    """Cameras around the origin (about 800 mm away), every one with the given lens model."""
    lens = LENSES[lens_name]
    centres = [(-800.0, -100.0, 60.0), (60.0, -150.0, -780.0), (560.0, -400.0, 520.0)][:n_cameras]
    cams = {}
    for k, c in enumerate(centres):
        rvec, tvec = look_at(c)
        K = [[900.0 + 10 * k, 0, 958.0], [0, 905.0, 541.0], [0, 0, 1]]
        cams[f"c{k}"] = Camera(f"c{k}", 1920, 1080, K, coefficients(lens), rvec, tvec, model=lens.family,
                               lens=lens.name, rmse_px=0.2 + 0.05 * k)
    return Calibration(cameras=cams)


POINTS = np.random.default_rng(7).uniform(-150, 150, (300, 3))


@pytest.mark.parametrize("name", list(LENSES))
def test_projection_matches_opencv(name):
    lens = LENSES[name]
    d = coefficients(lens)
    K = np.array([[900.0, 0, 958], [0, 905, 541], [0, 0, 1]])
    X = POINTS + [0, 0, 700]
    if lens.family == "fisheye":
        ref, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, d)
    else:
        ref, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, d)
    assert np.abs(project(X, K, d, lens.family) - ref.reshape(-1, 2)).max() < 1e-8
    assert lens_of(d, lens.family).name == name  # the coefficients name their model back


@pytest.mark.parametrize("name", list(LENSES))
def test_calibration_file_round_trip_and_undistortion(name):
    cal = rig(name)
    back = Calibration.from_toml(cal.to_toml())
    for n, cam in cal.cameras.items():
        other = back.cameras[n]
        assert other.lens == name and other.model == cam.model
        assert np.array_equal(other.distortion, cam.distortion)
        px = cam.project(POINTS)
        assert np.abs(other.project(POINTS) - px).max() < 1e-9
        # undistort -> project through a distortion-free copy gives the same pixel back
        plain = Camera("p", 1920, 1080, cam.matrix, np.zeros(5), cam.rvec, cam.tvec)
        assert np.abs(plain.project(POINTS) - cam.undistort(px)).max() < 1e-6


@pytest.mark.parametrize("name", list(LENSES))
def test_triangulation_uses_every_camera_that_saw_a_point(name):
    cal = rig(name)
    px = {n: c.project(POINTS) for n, c in cal.cameras.items()}
    xyz, res = triangulate(cal, px, refine=True, world=False)
    assert np.abs(xyz - POINTS).max() < 1e-6 and res.max() < 1e-5
    # a third of the points without camera c2, a third without c0: still exact from the other two
    px["c2"][:100] = np.nan
    px["c0"][100:200] = np.nan
    xyz, res = triangulate(cal, px, refine=True, world=False)
    assert np.abs(xyz - POINTS).max() < 1e-6
    # one camera only: no point
    px["c1"][:100] = np.nan
    xyz, _ = triangulate(cal, px, refine=True, world=False)
    assert np.isnan(xyz[:100]).all() and np.isfinite(xyz[100:]).all()


def test_noisier_camera_counts_less():
    """Three views of each point, one of them 4x noisier and said so by its RMSE: the refined points
    come closer to the truth than the unweighted linear solution."""
    cal = rig("standard")
    rng = np.random.default_rng(3)
    cal.cameras["c2"].rmse_px = 2.0
    for c in ("c0", "c1"):
        cal.cameras[c].rmse_px = 0.5
    px = {n: c.project(POINTS) + rng.normal(0, c.rmse_px, (len(POINTS), 2)) for n, c in cal.cameras.items()}
    linear, _ = triangulate(cal, px, refine=False, world=False)
    refined, _ = triangulate(cal, px, refine=True, world=False)
    err_lin = np.linalg.norm(linear - POINTS, axis=1).mean()
    err_ref = np.linalg.norm(refined - POINTS, axis=1).mean()
    assert err_ref < 0.9 * err_lin


@pytest.mark.parametrize("name", list(LENSES))
def test_stereo_check_and_epipolar_curve(name):
    cal = rig(name, 2)
    check = StereoCheck(cal, "c0", "c1")
    a, b = cal.cameras["c0"].project(POINTS[:50]), cal.cameras["c1"].project(POINTS[:50])
    assert check.distance("c0", a, "c1", b).max() < 1e-4
    moved = b + [0.0, 6.0]  # a jump of 6 px in the other view breaks the epipolar constraint
    assert np.median(check.distance("c0", a, "c1", moved)) > 2.0
    curve = epipolar_curve(cal, "c0", a[0], "c1")
    assert np.min(np.linalg.norm(curve - b[0], axis=1)) < 2.0  # sampled curve passes by the true point


def test_residual_variant_triangulates_with_its_calibration():
    """The regression's residual variant adds its correction to triangulation through the stored
    calibration: with every lens model that calibration must triangulate exactly."""
    from sandtrack_tui.regression.model import MLP, RegressionModel, predict

    cal = rig("full", 2)
    cal.cameras = {"side": cal.cameras["c0"], "front": cal.cameras["c1"]}
    for n, c in cal.cameras.items():
        c.name = n
    net = MLP(hidden=(4,), dropout=0.0)
    for p in net.parameters():
        p.data.zero_()  # a zero correction
    model = RegressionModel(net=net, in_mean=np.zeros(4), in_std=np.ones(4), out_mean=np.zeros(3),
                            out_std=np.ones(3), in_min=np.zeros(4), in_max=np.ones(4), hull=np.zeros((0, 4)),
                            residual_net=net, res_mean=np.zeros(3), res_std=np.ones(3),
                            calibration_toml=cal.to_toml())
    x = np.hstack([cal.cameras["side"].project(POINTS), cal.cameras["front"].project(POINTS)])
    assert np.abs(predict(model, x, method="residual") - POINTS).max() < 0.02


def test_caliscope_export_keeps_five_terms_and_says_what_it_dropped(tmp_path):
    cal = rig("rational-prism", 2)
    path = tmp_path / "camera_array.toml"
    notes = export_caliscope(cal, path)
    assert len(notes) == 2 and all("k4 k5 k6 s1 s2 s3 s4" in n for n in notes)
    moved = float(notes[0].split("up to ")[1].split(" px")[0])
    back = import_caliscope(path)
    cam, imp = cal.cameras["c0"], back.cameras["cam_0"]
    assert len(imp.distortion) == 5
    # the five-term model stays within the reported displacement over the image
    grid = np.stack(np.meshgrid(np.linspace(100, 1820, 12), np.linspace(100, 980, 8)), -1).reshape(-1, 2)
    rays = cam.undistort(grid)
    plain = Camera("p", 1920, 1080, cam.matrix, np.zeros(5))
    pts = np.hstack([np.linalg.solve(cam.matrix, np.vstack([rays.T, np.ones(len(rays))])).T[:, :2],
                     np.ones((len(rays), 1))]) * 500
    d = np.linalg.norm(Camera("q", 1920, 1080, cam.matrix, imp.distortion).project(pts) - grid, axis=1)
    assert d.max() <= moved + 0.05 and plain.width == 1920
    # a standard camera goes out unchanged, without a note
    assert export_caliscope(rig("standard", 2), tmp_path / "plain.toml") == []


def test_bad_lens_entries_are_refused():
    good = rig("rational", 2).to_toml()
    with pytest.raises(SandtrackError, match="unknown lens model"):
        Calibration.from_toml(good.replace('lens = "rational"', 'lens = "zoom"', 1))
    with pytest.raises(SandtrackError, match="does not fit"):
        Calibration.from_toml(good.replace('lens = "rational"', 'lens = "radial1"', 1))
    with pytest.raises(SandtrackError, match="fisheye"):
        Calibration.from_toml(good.replace('lens = "rational"', 'lens = "fisheye"', 1))
