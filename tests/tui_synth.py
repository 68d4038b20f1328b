"""A small synthetic experiment for the TUI tests: two image-folder "videos" of sand-coloured noise
with blue discs at known, moving positions (deterministic, no codec involved)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sandtrack_tui.camera import Calibration, Camera
from sandtrack_tui.store import Project

WIDTH, HEIGHT, N_FRAMES = 640, 360, 30
RADIUS = 5
FOCAL = 800.0
# start XYZ (mm, rig = world frame = side camera frame) and velocity (mm/frame) per marker
MARKERS = {1: ((-120.0, -40.0, 1000.0), (2.5, 0.6, 0.0)), 2: ((110.0, 40.0, 1040.0), (-1.8, 0.3, -1.0)),
           3: ((20.0, -70.0, 980.0), (0.6, 1.2, 0.5))}


def calibration(cameras=("side", "front")) -> Calibration:
    """The synthetic rig: side (the rig frame), front 250 mm to its right, top 250 mm above it."""
    K = [[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1]]
    poses = {"side": (np.zeros(3), np.zeros(3)), "front": (np.array([0.0, 0.25, 0.0]), np.array([250.0, 0.0, 0.0])),
             "top": (np.array([0.25, 0.0, 0.0]), np.array([0.0, -250.0, 0.0]))}
    cams = {}
    for name in cameras:
        rvec, centre = poses[name]
        R = cv2.Rodrigues(rvec)[0]
        cams[name] = Camera(name, WIDTH, HEIGHT, K, np.zeros(5), rvec, -R @ centre)
    return Calibration(cams)


_CAL = calibration(("side", "front", "top"))


def true_xyz(marker: int, frame: int) -> np.ndarray:
    p, v = MARKERS[marker]
    return np.array(p) + frame * np.array(v)


def true_xy(marker: int, frame: int, camera: str = "side") -> tuple[float, float]:
    x, y = _CAL.cameras[camera].project(true_xyz(marker, frame)[None])[0]
    return float(x), float(y)


_SAND: dict[str, np.ndarray] = {}


def _sand(camera: str) -> np.ndarray:
    if camera not in _SAND:
        rng = np.random.default_rng(1 + ("side", "front", "top").index(camera))
        base = np.array([120, 170, 200], np.float32)  # BGR
        img = np.clip(base + rng.normal(0, 18, (HEIGHT, WIDTH, 3)), 0, 255).astype(np.uint8)
        _SAND[camera] = cv2.GaussianBlur(img, (3, 3), 0)
    return _SAND[camera]


BLUE = (190, 70, 20)  # BGR of the markers' paint


def render(frame: int, camera: str, paint=BLUE) -> np.ndarray:
    img = np.roll(_sand(camera), 3 * frame, axis=1)  # the texture changes from frame to frame
    ss = 8  # draw discs supersampled so their centroid is exact to a small fraction of a pixel
    for m in MARKERS:
        x, y = true_xy(m, frame, camera)
        cv2.circle(img, (int(round(x * ss)), int(round(y * ss))), RADIUS * ss, paint, -1, cv2.LINE_AA, shift=3)
    return img


def make_frames(folder: Path, cameras=("side", "front"), paint=BLUE, n_frames: int = N_FRAMES) -> Path:
    for cam in cameras:
        d = folder / cam
        d.mkdir(parents=True, exist_ok=True)
        for i in range(n_frames):
            cv2.imwrite(str(d / f"{i:04d}.bmp"), render(i, cam, paint))
    return folder


def make_project(folder: Path, name: str = "synthetic", frames: Path | None = None,
                 calibrated: bool = False, synced: bool = True) -> Project:
    """A project in `folder` linking the frames in `frames` (rendered into `folder` if not given).
    synced: the cameras' sync offset (0: the rendered cameras are frame-locked) is stored, as if set in F2."""
    frames = frames or make_frames(folder)
    proj = Project.create(folder / f"{name}.sandtrack", {"side": frames / "side", "front": frames / "front"})
    if synced:
        proj.set("sync_offset_s", 0.0)
    if calibrated:
        proj.set_calibration(calibration())
    return proj
