"""A two-view crowd for tests: touching identical black beads (a dense layer) rendered in both cameras of
the synthetic stereo rig with exact truth, and a project seeded as touching lookalikes are seeded."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pandas as pd

from sandtrack_tui.store import Project
from sandtrack_tui.tracking import synthetic
from sandtrack_tui.tracking.run import accept_seeds

BEAD_MM = 4.0
SEED_BOX_PX = 22.0  # a bead (~7 px radius here) with its touching neighbours' rims and some sand around
CLICKED = 2  # the bead seeded in both views (at the layer's edge: sand around it, neighbours touching it)


def layer_mm(cols: int = 4, rows: int = 3) -> np.ndarray:
    """Touching beads in hexagonal rows at ~400 mm from the side camera (mm): a row lies along the
    stereo baseline, so the beads of a row share one epipolar line in each view."""
    s = 2.02 * BEAD_MM
    return np.array([(-15.0 + s * (c + 0.5 * (j % 2)), -8.0 + 0.866 * s * j, 400.0)
                     for j in range(rows) for c in range(cols)])


def turned(layer: np.ndarray, frames: int, rest: int, deg_per_frame: float) -> np.ndarray:
    """The layer at rest for `rest` frames, then turned about its middle (a patch the tool twists): the
    beads of a row leave each other's lines. (frames, beads, 3) mm."""
    mid = layer.mean(axis=0)
    out = []
    for f in range(frames):
        th = math.radians(deg_per_frame * max(f - rest, 0))
        turn = np.array([[math.cos(th), -math.sin(th), 0], [math.sin(th), math.cos(th), 0], [0, 0, 1]])
        out.append((layer - mid) @ turn.T + mid)
    return np.array(out)


def crowd_project(tmp_path, centres: np.ndarray):
    """A project on the two views of `centres` (synthetic.render_stereo_crowd), seeded as touching
    lookalikes are: bead CLICKED as marker 1 in both views, every other bead a marker of one view
    (side 2.., front numbered on in another order). Returns (project, clips, {(camera, bead): marker})."""
    cal, clips = synthetic.render_stereo_crowd(centres, BEAD_MM)
    for name, clip in clips.items():
        (tmp_path / name).mkdir()
        for i, f in enumerate(clip.frames):
            cv2.imwrite(str(tmp_path / name / f"{i:05d}.png"), f)
    proj = Project.create(tmp_path / "crowd.sandtrack", {c: tmp_path / c for c in ("side", "front")})
    proj.set("sync_offset_s", 0.0)
    proj.set_calibration(cal)
    others = [b for b in range(1, centres.shape[1] + 1) if b != CLICKED]
    ids = {("side", CLICKED): 1, ("front", CLICKED): 1}
    ids.update({("side", b): 2 + i for i, b in enumerate(others)})
    ids.update({("front", b): 2 + len(others) + i for i, b in enumerate(reversed(others))})
    rows = [(ids[(cam, int(r.marker))], cam, 0, r.x_px + 0.3, r.y_px - 0.2, SEED_BOX_PX, SEED_BOX_PX, "dark")
            for cam, clip in clips.items() for r in clip.truth[clip.truth.frame == 0].itertuples()]
    accept_seeds(proj, pd.DataFrame(rows, columns=["marker", "camera", "frame", "x_px", "y_px", "w", "h", "model"]))
    return proj, clips, ids
