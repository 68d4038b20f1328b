"""The twin's harder sand-box cases (twin/variants.py, listed in twin/catalog.py): short excerpts rendered
here, their truth checked against the pictures (the markers found where the truth says, in the output each
variant writes)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pandas as pd
import pytest
from scipy.spatial import cKDTree

from sandtrack_tui.cli import main
from sandtrack_tui.cli.cmd_sample import VARIANT_NAMES
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.tracking.learning import learn
from sandtrack_tui.tracking.seeding import detect_markers
from sandtrack_tui.twin.catalog import VARIANTS, excerpt, render_variant
from sandtrack_tui.twin.scene import SHANK_HALF_X, Timeline
from sandtrack_tui.twin.variants import TOOL_X, ScatteredLayer
from sandtrack_tui.video import FrameSource


def _found(folder, camera: str, kind: str, frames) -> tuple[int, int, list[float]]:
    """(visible true markers, of them found by detect_markers like the first one, their errors px)."""
    info = json.loads((folder / "variant.json").read_text())
    truth = pd.read_csv(folder / "ground_truth" / f"markers_{camera}.csv")
    n = found = 0
    errs = []
    with FrameSource(folder / info["videos"][camera]) as src:
        for f in frames:
            img = src.frame(f)
            t = truth[(truth.frame == f) & (truth.visible == 1)]
            ref = t.iloc[0]
            model = learn(img, ref.x_px, ref.y_px, 16, 16)
            assert model.kind == kind
            det = detect_markers(img, model=model)
            for r in t.itertuples():
                n += 1
                d = np.hypot(det.x_px - r.x_px, det.y_px - r.y_px).min() if len(det) else np.inf
                if d < 1.0:
                    found += 1
                    errs.append(float(d))
    return n, found, errs


def test_black_beads_through_a_window_of_the_side_camera(tmp_path):
    info = render_variant(excerpt("black", 4.9, 2, cameras=("side",)), tmp_path)
    assert info["frames"] == 2 and (tmp_path / "experiment" / "side.mp4").is_file()
    n, found, errs = _found(tmp_path, "side", "dark", [0, 1])
    assert n >= 12 and found == n and np.median(errs) < 0.37  # measured 0.25 px


def test_a_shaken_panned_view_moves_its_truth_with_it(tmp_path):
    info = render_variant(excerpt("shake", 3.0, 3), tmp_path)
    assert info["output"] == "jpeg" and len(list((tmp_path / "experiment" / "side").glob("*.jpg"))) == 3
    truth = pd.read_csv(tmp_path / "ground_truth" / "markers_side.csv")
    still = truth.pivot(index="frame", columns="marker", values="X_mm")
    assert np.ptp(still.to_numpy(), axis=0).max() < 0.5  # the markers hardly move: the view does
    moved = truth.pivot(index="frame", columns="marker", values="x_px").diff().abs().min(axis=1).iloc[1:]
    assert (moved > 0.3).all()
    n, found, errs = _found(tmp_path, "side", "bright", [0, 1, 2])  # (blurred and shaken: 0.3-0.5 px)
    assert found >= 0.9 * n and np.median(errs) < 0.56  # measured 0.37 px


def test_dense_identical_beads_in_16_bit_grey_tiff(tmp_path):
    info = render_variant(excerpt("dense", 1.0, 1, cameras=("side",)), tmp_path)
    tif = sorted((tmp_path / "experiment" / "side").glob("*.tif"))
    raw = cv2.imread(str(tif[0]), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.ndim == 2 and raw.max() > 255 and info["output"] == "tiff16"
    truth = pd.read_csv(tmp_path / "ground_truth" / "markers_side.csv")
    assert truth.marker.nunique() >= 40 and truth.visible.sum() >= 40
    # Touching beads: the true centres of neighbours are one bead diameter apart.
    t = truth[truth.visible == 1][["x_px", "y_px"]].to_numpy()
    d = np.hypot(*(t[:, None, :] - t[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    with FrameSource(tmp_path / "experiment" / "side") as src:
        img = src.frame(0)
    lum = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    centres = lum[t[:, 1].round().astype(int), t[:, 0].round().astype(int)]
    assert np.median(centres) < 0.6 * np.median(lum)  # dark beads there, on lighter sand
    assert 10 < np.median(d.min(axis=1)) < 16  # ~13 px beads, touching


def test_unknown_variant_is_one_clear_error(tmp_path, capsys):
    with pytest.raises(SandtrackError, match="unknown twin variant 'nope'"):
        render_variant("nope", tmp_path)
    assert tuple(VARIANTS) == VARIANT_NAMES  # the CLI's help names them all
    assert main(["sample", str(tmp_path / "v"), "--variant", "nope"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown twin variant 'nope'" in err[0]


def test_scattered_beads_are_pushed_aside_by_the_tool_never_through_each_other():
    layer = ScatteredLayer(0, Timeline(speed_mm_s=150.0), 2.5)
    start, end = layer.track[0], layer.track[-1]
    assert len(start) == 300
    near = cKDTree(start).query(start, k=2)[0][:, 1]
    assert near.min() >= 5.1 and 0.3 < (near < 5.15).mean() < 0.7  # none overlapping, about half touching
    closest = [cKDTree(xz).query(xz, k=2)[0][:, 1].min() for xz in layer.track[::5]]
    assert min(closest) > 5.0 - 0.02  # at most 0.02 mm into each other while the tool crowds them
    lateral = start[:, 0] - TOOL_X
    moved = np.hypot(*(end - start).T)
    lane = np.abs(lateral) < SHANK_HALF_X + 2.5
    assert lane.sum() > 15 and (np.abs(end[lane, 0] - TOOL_X) > 25).all()  # the shank's lane cleared
    assert np.median(moved[np.abs(lateral) < 20]) > 6 * np.median(moved[np.abs(lateral) > 80])


def test_three_hundred_blue_markers_in_the_tool_lane(tmp_path):
    info = render_variant(excerpt("dense300", 4.0, 1, cameras=("side",)), tmp_path)
    assert info["layout"] == "scattered" and tuple(info["size"]) == (640, 448)
    truth = pd.read_csv(tmp_path / "ground_truth" / "markers_side.csv")
    assert truth.marker.nunique() == 300 and truth.visible.sum() > 250
    n, found, errs = _found(tmp_path, "side", "colour", [0])  # (touching ones merge: found by their blobs)
    assert found >= 0.45 * n and np.median(errs) < 0.3
