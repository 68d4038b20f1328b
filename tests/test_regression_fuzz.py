"""Bad input to the regression readers: any bytes as points.csv or model file give a SandtrackError
(one line), never a traceback."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import examples
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.regression import load_model, load_points

HEADER = b"frame,corner_id,xs,ys,xf,yf,X_mm,Y_mm,Z_mm\n"
cell = st.one_of(st.integers(-10**20, 10**20).map(str), st.floats(allow_nan=True).map(repr),
                 st.text(alphabet="0123456789.-eE,nai\"x ", max_size=8))
row = st.lists(cell, min_size=0, max_size=11).map(lambda cells: ",".join(cells).encode())


@settings(max_examples=examples(120), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=st.one_of(st.binary(max_size=300), st.lists(row, max_size=6).map(lambda rows: HEADER + b"\n".join(rows))))
def test_points_reader_never_crashes(tmp_path, body):
    path = tmp_path / "points.csv"
    path.write_bytes(body)
    try:
        df = load_points(path)
    except SandtrackError as exc:
        assert "\n" not in str(exc)
        return
    assert len(df) > 0 and list(df.columns)[:3] == ["frame", "corner_id", "xs"]


@settings(max_examples=examples(40), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=st.binary(max_size=400))
def test_model_reader_never_crashes(tmp_path, body):
    path = tmp_path / "model.pt"
    path.write_bytes(body)
    with pytest.raises(SandtrackError):
        load_model(path)


def test_model_files_with_wrong_content(tmp_path):
    import collections

    import torch

    cases = {"empty_doc": {"format": "sandtrack-regression", "version": 1},
             "foreign": {"state_dict": {}},
             "newer": {"format": "sandtrack-regression", "version": 99},
             "unsafe": collections.Counter(a=1)}  # not loadable with weights_only=True
    for name, doc in cases.items():
        torch.save(doc, tmp_path / f"{name}.pt")
        with pytest.raises(SandtrackError) as info:
            load_model(tmp_path / f"{name}.pt")
        assert "\n" not in str(info.value)
