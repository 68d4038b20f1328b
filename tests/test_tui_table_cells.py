"""The live table's XYZ cells: a network XYZ inconsistent with the triangulation is marked, and so are pixels
beyond the calibrated image region."""

from __future__ import annotations

from sandtrack_tui.tui.table import MarkerRow, format_row


def _network_cell(check: str) -> str:
    row = MarkerRow(1, "1", xyz_tri=(10.0, 20.0, 30.0), sd_tri=(0.1, 0.1, 0.1),
                    xyz_net=(11.5, 20.0, 30.0), sd_net=(1.5, 0.3, 0.3), net_check=check)
    return str(format_row(row, ["side", "front"])[6])


def test_an_inconsistent_network_xyz_ends_with_a_mark_and_a_consistent_one_does_not():
    assert _network_cell("inconsistent") == "11.5,20.0,30.0 ±1.50!"
    assert _network_cell("ok") == "11.5,20.0,30.0 ±1.50"
    assert _network_cell("unchecked") == "11.5,20.0,30.0 ±1.50"


def test_pixels_beyond_the_calibrated_region_mark_both_xyz_cells():
    row = MarkerRow(1, "1", xyz_tri=(10.0, 20.0, 30.0), sd_tri=(0.1, 0.2, 0.1), xyz_net=(10.5, 20.0, 30.0),
                    sd_net=None, outside_region=True)
    cells = format_row(row, ["side", "front"])
    assert (str(cells[5]), str(cells[6])) == ("10.0,20.0,30.0 ±0.20^", "10.5,20.0,30.0 ±?^")
