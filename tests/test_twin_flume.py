"""The bedload flume twin (twin/flume*.py): its pictures against its truth, its physics, its files.

The optics are checked on a hand-made scene (beads placed where the test wants them: one alone, one
partly behind another, one cut by the frame's edge, one fast), the physics on small simulations, the
whole render on a small flume (a 192 x 96 px view, a few frames)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pandas as pd
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares

from sandtrack_tui.cli import main
from sandtrack_tui.twin import catalog
from sandtrack_tui.twin.flume import Flume, FlumeCamera, MarkerIds, flume_camera, frame_truth, render_flume
from sandtrack_tui.twin.flume_physics import RHO_WATER, FlumePhysics, FlumeRun, FlumeSim
from sandtrack_tui.video import FrameSource

SMALL = Flume(name="flume-small", size=(192, 96), frames=3,
              physics=FlumePhysics(bed_mm=12.0, settle_s=0.25, spinup_s=0.15))


# -- the optics, on beads placed by hand -----------------------------------------------------------

def _scene() -> tuple[Flume, FlumeRun]:
    """Five beads in a 160 x 96 px view (40 x 24 mm; the channel 60 mm long, the view from x = 10 mm):
    0 alone at rest, 1 in front of 2 (2 partly behind it), 3 at 800 mm/s along the flow, 4 cut by the
    frame's left edge. Two frames; bead 3 has come round the channel again in frame 1."""
    spec = Flume(size=(160, 96), frames=2)
    optics = spec.optics
    centres = np.array([[20.3, 16.2, 5.0], [35.1, 10.3, 3.0], [39.6, 10.3, 7.0], [45.0, 21.0, 5.0],
                        [10.4, 8.0, 5.0]])
    vel = np.zeros_like(centres)
    vel[3] = (800.0, 0.0, 0.0)
    s = optics.samples
    offsets = (np.linspace(0, 1, s) - 0.5) * optics.exposure_s
    pos = centres[None, None] + offsets[None, :, None, None] * vel[None, None]
    pos = np.repeat(pos, 2, axis=0)
    wraps = np.zeros((2, 5), np.int64)
    wraps[1, 3] = 1
    run = FlumeRun(radius=np.full(5, 3.0), mobile=np.ones(5, bool), pos=pos, vel=np.repeat(vel[None], 2, axis=0),
                   contact_steps=np.array([[10, 10, 10, 0, 10]] * 2), wraps=wraps, steps_per_frame=200,
                   dt=1 / 130 / 200, spec=spec.physics, length_mm=60.0)
    return spec, run


def _centroid(weights: np.ndarray, x0: int, y0: int) -> np.ndarray:
    ys, xs = np.mgrid[0:weights.shape[0], 0:weights.shape[1]]
    return np.array([(weights * xs).sum(), (weights * ys).sum()]) / weights.sum() + (x0, y0)


def _window(img: np.ndarray, u: float, v: float, half: int):
    x0, y0 = int(round(u)) - half, int(round(v)) - half
    return img[y0:y0 + 2 * half + 1, x0:x0 + 2 * half + 1], x0, y0


def test_a_bead_is_drawn_centred_on_its_truth():
    spec, run = _scene()
    cam = FlumeCamera(spec, run, seed=1)
    t = pd.DataFrame(frame_truth(run, 0, cam.cam, spec, MarkerIds()))
    bead = t.iloc[int(np.argmin(np.abs(t.X_mm - 10.3)))]  # bead 0: alone, at rest
    T = cam.transmission(0)
    win, x0, y0 = _window(1 - T, bead.x_px, bead.y_px, 20)
    dark = _centroid(win, x0, y0)
    assert np.hypot(*(dark - (bead.x_px, bead.y_px))) < 0.001  # the dark disc
    spot_win, sx, sy = _window(T, bead.x_px, bead.y_px, 6)  # its bright centre: a Gaussian on the dark body
    ys, xs = np.mgrid[sy:sy + 13, sx:sx + 13]

    def misfit(q):
        return (q[2] + q[3] * np.exp(-((xs - q[0]) ** 2 + (ys - q[1]) ** 2) / (2 * q[4])) - spot_win).ravel()

    fit = least_squares(misfit, [sx + 6.0, sy + 6.0, 0.05, 0.5, 4.0]).x
    assert np.hypot(fit[0] - bead.x_px, fit[1] - bead.y_px) < 0.001 and fit[3] > 0.2
    spot_sum = float(np.clip(_window(T, bead.x_px, bead.y_px, 8)[0] - cam.look.body[0], 0, None).sum())
    area = (float(win.sum()) + spot_sum) / (1 - cam.look.body[0])  # the disc's size: as its truth says
    assert abs(2 * math.sqrt(area / math.pi) / bead.diameter_px - 1) < 0.006
    # ... and in the recorded frame, through the backlight, the lamp's ripple and the sensor's noise
    dn = cam.frame(0).astype(float) / (2**spec.optics.bits - 1) - spec.optics.black_level
    seen = dn / np.median(dn[:10, :])  # (flat-fielded on the empty water above)
    light = cam.light / np.median(cam.light[:10, :])
    win, x0, y0 = _window(np.clip(1 - seen / light, 0, None), bead.x_px, bead.y_px, 20)
    assert np.hypot(*(_centroid(win, x0, y0) - (bead.x_px, bead.y_px))) < 0.015


def _lens_area(d: float, r1: float, r2: float) -> float:
    """Area shared by two discs of radii r1, r2 whose centres are d apart."""
    a = r1 * r1 * math.acos((d * d + r1 * r1 - r2 * r2) / (2 * d * r1))
    b = r2 * r2 * math.acos((d * d + r2 * r2 - r1 * r1) / (2 * d * r2))
    return a + b - 0.5 * math.sqrt((-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2))


def test_visible_fraction_of_a_bead_partly_behind_another_and_one_cut_by_the_edge():
    spec, run = _scene()
    cam = flume_camera(spec)
    t = pd.DataFrame(frame_truth(run, 0, cam, spec, MarkerIds()))
    t = t.assign(z=t.Z_mm.round(1), x=t.X_mm.round(1))
    front, back = t[(t.x == 25.1) & (t.z == 3.0)].iloc[0], t[(t.x == 29.6) & (t.z == 7.0)].iloc[0]
    r1, r2 = front.diameter_px / 2, back.diameter_px / 2
    assert r1 > r2  # nearer the camera: larger
    d = math.hypot(front.x_px - back.x_px, front.y_px - back.y_px)
    hidden = _lens_area(d, r1, r2) / (math.pi * r2 * r2)
    assert 0.05 < hidden < 0.3
    assert back.visible_fraction == pytest.approx(1 - hidden, abs=0.012)  # (256 points over the disc)
    assert front.visible_fraction == 1.0
    edge = t[t.x == 0.4].iloc[0]  # its centre 1.6 px inside the frame's left edge (at -0.5)
    r, inside = edge.diameter_px / 2, edge.x_px + 0.5
    cut = (r * r * math.acos(inside / r) - inside * math.sqrt(r * r - inside * inside)) / (math.pi * r * r)
    assert edge.visible_fraction == pytest.approx(1 - cut, abs=0.005) and edge.visible == 1
    # the picture: dark wherever either bead is, the back one's bright centre showing beside the front one
    T = FlumeCamera(spec, run, seed=1).transmission(0)
    ys, xs = np.mgrid[0:T.shape[0], 0:T.shape[1]]
    to_back, to_front = np.hypot(xs - back.x_px, ys - back.y_px), np.hypot(xs - front.x_px, ys - front.y_px)
    assert T[(to_back < r2 - 2) & (to_front < r1 - 2)].max() < 0.01  # light through both bodies
    assert T[(to_back < r2 - 2) & (to_back > 0.5 * r2)].max() < 0.12
    assert T[to_back < 1].min() > 0.2


def test_a_fast_bead_smears_over_the_exposure_about_its_mid_exposure_truth():
    spec, run = _scene()
    cam = FlumeCamera(spec, run, seed=1)
    t = pd.DataFrame(frame_truth(run, 0, cam.cam, spec, MarkerIds()))
    fast = t[t.state == "saltating"].iloc[0]
    assert fast.vx_px == pytest.approx(800 * spec.px_per_mm / spec.fps, rel=0.01)  # ~24.6 px per frame
    T = cam.transmission(0)
    win, x0, y0 = _window(1 - T, fast.x_px, fast.y_px, 22)
    assert np.hypot(*(_centroid(win, x0, y0) - (fast.x_px, fast.y_px))) < 0.001
    smear = fast.vx_px * spec.fps * spec.optics.exposure_s
    assert 3.5 < smear < 4.5
    # the streak is the bead at rest spread over the exposure's instants: its spread along x grows by theirs
    held = run.pos.copy()
    held[:, :, 3] = run.pos[:, run.mid, 3][:, None]
    rest, _, _ = _window(1 - FlumeCamera(spec, replace(run, pos=held), seed=1).transmission(0), fast.x_px,
                         fast.y_px, 22)

    def spread(w):
        xs = np.arange(w.shape[1])
        p = w.sum(axis=0)
        return float((p * xs * xs).sum() / p.sum() - ((p * xs).sum() / p.sum()) ** 2)

    instants = cam.cam.project(run.pos[0, :, 3])[0]
    assert spread(win) - spread(rest) == pytest.approx(np.var(instants), rel=0.001)


def test_a_bead_coming_round_again_is_a_new_marker():
    spec, run = _scene()
    cam, ids = flume_camera(spec), MarkerIds()
    f0 = pd.DataFrame(frame_truth(run, 0, cam, spec, ids))
    f1 = pd.DataFrame(frame_truth(run, 1, cam, spec, ids))
    again = set(f1.marker) - set(f0.marker)
    assert len(again) == 1 and len(set(f0.marker) & set(f1.marker)) == len(f0) - 1
    assert f0.sort_values("x_px").marker.is_monotonic_increasing  # numbered left to right as they appear


# -- the physics ------------------------------------------------------------------------------------

def test_the_bed_is_a_packing_of_touching_beads_on_the_floor():
    spec = FlumePhysics(bed_mm=14.0, settle_s=0.35)
    sim = FlumeSim(spec, length_mm=72.0, seed=3, fps=130.0)
    sim.settle()
    p, r, mob = sim.pos, sim.rad, sim.mobile
    assert np.percentile(np.linalg.norm(sim.vel[mob], axis=1), 95) < 1.0  # at rest (mm/s; a few may roll on)
    d = p[:, None, :] - p[None, :, :]
    d[..., 0] -= sim.length_mm * np.round(d[..., 0] / sim.length_mm)  # (periodic along the flow)
    dist = np.linalg.norm(d, axis=2)
    np.fill_diagonal(dist, np.inf)
    contact = r[:, None] + r[None, :]
    assert (contact - dist).max() < 0.001 * spec.bead_mm  # overlaps: elastic contacts, < 0.1 % of a bead
    gap = (dist / contact).min(axis=1)[mob]
    assert np.median(gap) < 1.001  # each bead touches another
    proj = np.hypot(d[..., 0], d[..., 1]) / contact
    np.fill_diagonal(proj, np.inf)
    depth = np.clip((spec.channel_mm - contact) / contact, 0, 1)  # the most two beads can be apart in depth
    allowed = np.sqrt(1 - depth**2)
    assert (proj - allowed).min() > -0.003  # in view, a bead hides behind another only as far as the channel allows
    assert (proj < 0.9).sum() > 0  # ... and some do
    assert p[mob, 1].max() > 2.5 * spec.bead_mm  # several layers
    top = sim.bed_surface()
    assert top.std() > 0.1 * spec.bead_mm  # an irregular surface, not a grid
    assert (p[mob, 2] - r[mob] > -0.01).all() and (p[mob, 2] + r[mob] < spec.channel_mm + 0.01).all()


def test_a_bead_in_flight_follows_its_ballistic_path_with_drag():
    spec = FlumePhysics(bed_mm=4.0, settle_s=0.1)
    sim = FlumeSim(spec, length_mm=60.0, seed=0, fps=130.0)
    sim.settle()
    k = int(np.nonzero(sim.mobile)[0][0])
    p0, v0 = np.array([20.0, 70.0, 5.0]), np.array([450.0, 260.0, 0.0])
    sim.pos[k], sim.vel[k], sim.omg[k] = p0, v0, 0.0
    frames = 12  # ~92 ms, up and down again, far above the bed
    path = []
    for _ in range(frames):
        sim.advance(sim.steps_per_frame, flow=False)
        path.append(sim.pos[k].copy())
    r = sim.rad[k]
    vol = 4 / 3 * math.pi * r**3
    mass = vol * (spec.rho_bead + 0.5 * RHO_WATER)
    g = 9810.0
    weight = vol * np.array([spec.rho_bead * g * math.sin(spec.theta),
                             -(spec.rho_bead - RHO_WATER) * g * math.cos(spec.theta), 0.0])

    def motion(_, s):
        v = s[3:]
        w = float(np.linalg.norm(v))
        re = w * 2 * r / 1.0
        cd = 24 / re * (1 + 0.15 * re**0.687) if re < 1000 else 0.44
        drag = -0.5 * RHO_WATER * cd * math.pi * r * r * w * v
        return np.r_[v, (weight + drag) / mass]

    ts = np.arange(1, frames + 1) / 130.0
    ode = solve_ivp(motion, (0, ts[-1]), np.r_[p0, v0], t_eval=ts, rtol=1e-10, atol=1e-10)
    err = np.linalg.norm(np.array(path) - ode.y[:3].T, axis=1)
    assert err.max() < 0.02  # mm (0.08 px)
    assert np.array(path)[:, 0].max() - p0[0] > 30  # it flew: ~6 diameters


# -- the whole render --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("flume")
    info = render_flume(SMALL, out / "a", seed=5)
    return out, info


def test_small_flume_render_truth_and_16_bit_frames(small):
    out, info = small
    folder = out / "a"
    truth = pd.read_csv(folder / "ground_truth" / "markers_side.csv")
    assert info["frames"] == 3 and list(info["cameras"]) == ["side"] and info["videos"] == {"side": "experiment/side"}
    assert set(truth.columns) >= {"frame", "marker", "x_px", "y_px", "visible", "visible_fraction", "state",
                                  "vx_px", "vy_px", "X_mm", "Y_mm", "Z_mm", "diameter_px"}
    assert truth.groupby("frame").size().min() >= 15 and set(truth.state) <= {"resting", "rolling", "saltating"}
    assert truth.marker.groupby(truth.frame).nunique().equals(truth.groupby("frame").size())
    assert truth.diameter_px.between(23.0, 25.2).all()  # 6 mm +-3 % at 4 px/mm, nearer or farther
    raw = cv2.imread(str(folder / "experiment" / "side" / "00000.tif"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (96, 192) and (raw % 16 == 0).all() and raw.max() > 40000
    with FrameSource(folder / "experiment" / "side") as src:
        assert len(src) == 3
        img = src.frame(2)
    grey = img[..., 1].astype(float)
    t = truth[(truth.frame == 2) & (truth.visible_fraction == 1)]
    on_beads = grey[t.y_px.round().astype(int), t.x_px.round().astype(int)]  # their bright centres ...
    ring = grey[(t.y_px + 0.7 * t.diameter_px / 2).round().astype(int).clip(0, 95),
                t.x_px.round().astype(int)]  # ... brighter than their dark bodies
    assert np.median(on_beads - ring) > 45 and np.median(ring) < 0.08 * np.median(grey[:8])


def test_small_flume_is_deterministic_and_8_bit_frames_read_the_same(small, tmp_path):
    out, _ = small
    again = render_flume(SMALL, tmp_path / "b", seed=5)
    a, b = (pd.read_csv(d / "ground_truth" / "markers_side.csv") for d in (out / "a", tmp_path / "b"))
    assert a.equals(b) and again["markers"] == a.marker.nunique()
    for name in ("00000.tif", "00002.tif"):
        assert (out / "a" / "experiment" / "side" / name).read_bytes() == \
            (tmp_path / "b" / "experiment" / "side" / name).read_bytes()
    png = render_flume(replace(SMALL, output="png8"), tmp_path / "c", seed=5)
    assert png["output"] == "png8"
    raw = cv2.imread(str(tmp_path / "c" / "experiment" / "side" / "00001.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint8 and raw.ndim == 2
    with FrameSource(out / "a" / "experiment" / "side") as s16, FrameSource(tmp_path / "c" / "experiment" /
                                                                               "side") as s8:
        diff = np.abs(s16.frame(1).astype(int) - s8.frame(1).astype(int))
    assert diff.max() <= 1  # the same picture through either reader (12 bits: shifted, or scaled)
    other = render_flume(SMALL, tmp_path / "d", seed=6)
    assert not pd.read_csv(tmp_path / "d" / "ground_truth" / "markers_side.csv").equals(a) and other["frames"] == 3


def test_sample_cli_renders_the_flume(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(catalog.VARIANTS, "flume", replace(SMALL, name="flume", frames=2))
    assert main(["sample", str(tmp_path / "f"), "--variant", "flume", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["name"] == "flume" and result["frames"] == 2 and result["cameras"] == ["side"]
    assert len(list((tmp_path / "f" / "experiment" / "side").glob("*.tif"))) == 2
    assert (tmp_path / "f" / "ground_truth" / "markers_side.csv").is_file()
