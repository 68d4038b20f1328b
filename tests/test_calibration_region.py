"""The image region a calibration covered (calibration/region.py): pixels beyond a camera's hull of
calibration points are marked, since there the lens model extrapolates and the sd leaves out its error."""

import tomllib

import numpy as np
import pandas as pd
import pytest
import tomli_w

from sandtrack_tui.calibration.region import image_region, region_labels, tolerance_px
from sandtrack_tui.calibration.synthetic import stereo_rig
from sandtrack_tui.camera import Calibration
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.xyz_pixels import xyz_from_pixels


def _calibration() -> Calibration:
    """The synthetic rig (960 x 540 px) with each camera's calibration points on [200, 700] x [100, 400] px."""
    cal = stereo_rig()
    grid = np.stack(np.meshgrid(np.linspace(200, 700, 11), np.linspace(100, 400, 7)), -1).reshape(-1, 2)
    cal.regions = {n: image_region(grid) for n in cal.cameras}
    return cal


def test_pixels_beyond_a_cameras_hull_are_outside_within_its_tolerance_inside():
    cal = _calibration()
    tol = tolerance_px((960, 540))
    assert tol == pytest.approx(0.01 * np.hypot(960, 540))  # 11.0 px
    side = np.array([[450, 250], [700 + 0.5 * tol, 250], [700 + 2 * tol, 250], [450, 250], [np.nan, np.nan],
                     [np.nan, np.nan]])
    front = np.array([[300, 300], [300, 300], [300, 300], [450, 100 - 3 * tol], [450, 250], [np.nan, np.nan]])
    labels = region_labels(cal, {"side": side, "front": front}, len(side))
    assert list(labels) == ["inside", "inside", "outside", "outside", "inside", ""]
    # a camera without a region does not judge; a calibration without any leaves every row unknown
    cal.regions.pop("front")
    assert list(region_labels(cal, {"side": side, "front": front}, len(side))) == \
        ["inside", "inside", "outside", "inside", "", ""]
    cal.regions = {}
    assert set(region_labels(cal, {"side": side, "front": front}, len(side))) == {""}


def test_the_file_keeps_the_region_and_refuses_a_broken_one(tmp_path):
    cal = _calibration()
    cal.save(tmp_path / "c.toml")
    back = Calibration.load(tmp_path / "c.toml")
    assert set(back.regions) == {"side", "front"}
    assert np.allclose(back.regions["side"], cal.regions["side"])
    doc = tomllib.loads((tmp_path / "c.toml").read_text())
    for bad, why in (([[1.0, "a", 2.0]], "rows of three numbers"), ([[1.0, 0.0, -5.0]], "three or more")):
        doc["calibrated_region"]["side"]["halfplanes_px"] = bad
        (tmp_path / "bad.toml").write_text(tomli_w.dumps(doc))
        with pytest.raises(SandtrackError, match=f"calibrated_region.side: .*{why}"):
            Calibration.load(tmp_path / "bad.toml")


def test_xyz_of_a_pixels_table_marks_the_rows_and_says_how_many():
    cal = _calibration()
    df = pd.DataFrame({"xs": [450.0, 900.0], "ys": [250.0, 500.0], "xf": [450.0, 450.0], "yf": [250.0, 250.0]})
    table, notes = xyz_from_pixels(df, {"side": ("xs", "ys"), "front": ("xf", "yf")}, cal, method="triangulation")
    assert list(table["calibrated_region"]) == ["inside", "outside"]
    assert any(n.startswith("1 of 2 rows with XYZ have a pixel outside the image region") for n in notes)
