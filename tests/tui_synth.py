"""A small synthetic experiment for the TUI tests: two image-folder "videos" of sand-coloured noise
with blue discs at known, moving positions (deterministic, no codec involved)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sandtrack_tui.store import Project

WIDTH, HEIGHT, N_FRAMES = 640, 360, 30
RADIUS = 5
# start (x, y) and velocity (px/frame) per marker; front positions are shifted copies
MARKERS = {1: ((150.3, 120.6), (2.0, 0.5)), 2: ((420.7, 230.2), (-1.5, 0.25)), 3: ((300.4, 80.8), (0.5, 1.0))}
FRONT_SHIFT = (-40.0, 25.0)


def true_xy(marker: int, frame: int, camera: str = "side") -> tuple[float, float]:
    (x, y), (vx, vy) = MARKERS[marker]
    x, y = x + vx * frame, y + vy * frame
    if camera == "front":
        x, y = x + FRONT_SHIFT[0], y + FRONT_SHIFT[1]
    return x, y


_SAND: dict[str, np.ndarray] = {}


def _sand(camera: str) -> np.ndarray:
    if camera not in _SAND:
        rng = np.random.default_rng(1 + (camera == "front"))
        base = np.array([120, 170, 200], np.float32)  # BGR
        img = np.clip(base + rng.normal(0, 18, (HEIGHT, WIDTH, 3)), 0, 255).astype(np.uint8)
        _SAND[camera] = cv2.GaussianBlur(img, (3, 3), 0)
    return _SAND[camera]


def render(frame: int, camera: str) -> np.ndarray:
    img = np.roll(_sand(camera), 3 * frame, axis=1)  # the texture changes from frame to frame
    ss = 8  # draw discs supersampled so their centroid is exact to a small fraction of a pixel
    for m in MARKERS:
        x, y = true_xy(m, frame, camera)
        cv2.circle(img, (int(round(x * ss)), int(round(y * ss))), RADIUS * ss, (190, 70, 20), -1, cv2.LINE_AA,
                   shift=3)
    return img


def make_frames(folder: Path) -> Path:
    for cam in ("side", "front"):
        d = folder / cam
        d.mkdir(parents=True, exist_ok=True)
        for i in range(N_FRAMES):
            cv2.imwrite(str(d / f"{i:04d}.bmp"), render(i, cam))
    return folder


def make_project(folder: Path, name: str = "synthetic", frames: Path | None = None) -> Project:
    """A project in `folder` linking the frames in `frames` (rendered into `folder` if not given)."""
    frames = frames or make_frames(folder)
    return Project.create(folder / f"{name}.sandtrack", {"side": frames / "side", "front": frames / "front"})
