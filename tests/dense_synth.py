"""A dense scene for the display tests: a 1280 x 320 grey frame of a flume's bed, about 300 touching black
beads (24 px, each with the small bright centre light makes through a glass bead) packed in rows along the
bottom and a few resting or flying above, on grey sand with noise. Deterministic."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

WIDTH, HEIGHT = 1280, 320
RADIUS = 12.0  # px


def bead_centres(n: int = 300) -> np.ndarray:
    """(n, 2) bead centres (px): hexagonally packed rows from the bottom, the rest scattered above."""
    rng = np.random.default_rng(3)
    pitch = 2 * RADIUS + 0.5
    out = []
    for row in range(5):
        y = HEIGHT - RADIUS - 1 - row * pitch * np.sqrt(3) / 2
        x0 = RADIUS + 1 + (pitch / 2 if row % 2 else 0.0)
        out += [(x, y) for x in np.arange(x0, WIDTH - RADIUS, pitch)]
    out = out[:n]
    while len(out) < n:
        p = rng.uniform([RADIUS, RADIUS], [WIDTH - RADIUS, HEIGHT - 6 * pitch])
        if all(np.hypot(*(p - q)) > 2 * RADIUS + 2 for q in out):
            out.append(tuple(p))
    return np.array(out)


def dense_frame(centres: np.ndarray | None = None) -> np.ndarray:
    """The grey frame (uint8) of `centres` (default `bead_centres()`)."""
    centres = bead_centres() if centres is None else centres
    rng = np.random.default_rng(4)
    img = np.clip(rng.normal(150, 10, (HEIGHT, WIDTH)), 0, 255).astype(np.float32)
    img = cv2.GaussianBlur(img, (3, 3), 0)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    for x, y in centres:
        y0, y1, x0, x1 = (max(int(y - RADIUS - 2), 0), int(y + RADIUS + 3), max(int(x - RADIUS - 2), 0),
                          int(x + RADIUS + 3))
        d = np.hypot(xx[y0:y1, x0:x1] - x, yy[y0:y1, x0:x1] - y)
        body = np.clip(RADIUS + 0.5 - d, 0, 1)  # anti-aliased rim
        centre = np.clip(2.5 - d, 0, 1)
        patch = img[y0:y1, x0:x1]
        img[y0:y1, x0:x1] = patch * (1 - body) + 35 * body
        img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - centre) + 210 * centre
    return np.clip(img, 0, 255).astype(np.uint8)


def write_frames(folder: Path, n_frames: int = 2) -> Path:
    """An image-folder video of the dense frame (`n_frames` identical frames)."""
    folder.mkdir(parents=True, exist_ok=True)
    img = dense_frame()
    for i in range(n_frames):
        cv2.imwrite(str(folder / f"{i:04d}.png"), img)
    return folder
