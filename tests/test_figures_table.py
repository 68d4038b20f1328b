"""README's performance table is written from benchmarks/results.json (benchmarks/render_table.py): it
cannot differ from the committed figures, and a fresh benchmark run updates only what it measured."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _render_table():
    spec = importlib.util.spec_from_file_location("render_table", ROOT / "benchmarks" / "render_table.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_readme_table_is_the_rendering_of_results_json():
    rt = _render_table()
    doc = rt.load()
    assert rt.problems(doc) == []
    table = rt.readme_table((ROOT / "README.md").read_text(encoding="utf-8"))
    assert table == rt.render(doc), "README's table differs: python benchmarks/render_table.py --readme"
    assert all(len(line.encode()) <= rt.MAX_ROW for line in table.splitlines())
    assert json.loads(rt.dump(doc)) == doc  # the file's own layout holds everything


def test_a_fresh_run_updates_only_the_figures_it_produced():
    rt = _render_table()
    row = {"id": "r", "what": "w", "figure": "{a} / {b} px; {c}", "peer": "peer {p}", "target": "", "bench": "x",
           "measured": {"date": "2026-11-01", "commit": "aaaa"},
           "figures": {"a": {"key": "mean_px", "value": 0.2, "format": ".2f"},
                       "b": {"key": "nested/list/1", "value": 0.5, "format": ".1f"},
                       "c": {"key": "kb", "bench": "y", "value": 2000, "format": ".0f", "scale": 0.001},
                       "p": {"quoted": "a paper", "value": 2.3, "format": ".1f"}}}
    doc = {"about": "", "rows": [row]}
    assert rt.render_row(row) == "| w | 0.20 / 0.5 px; 2 | peer 2.3, quoted |  | [x](benchmarks/bench_x.py) |"
    taken = rt.update(doc, {"x": {"mean_px": 0.25, "nested": {"list": [9, 0.7]}}, "z": {"kb": 1}}, "2026-12-01", "bbbb")
    assert taken == ["r.a: 0.20 -> 0.25", "r.b: 0.5 -> 0.7"]
    figs = row["figures"]
    assert figs["a"]["measured"] == figs["b"]["measured"] == {"date": "2026-12-01", "commit": "bbbb"}
    assert "measured" not in figs["c"] and figs["c"]["value"] == 2000  # its benchmark did not run
    assert figs["p"] == {"quoted": "a paper", "value": 2.3, "format": ".1f"}
    assert rt.update(doc, {"x": {"error": "failed (see log)"}}, "2026-12-02", "cccc") == []
    assert rt.show({"value": 185, "format": "min_s"}) == "3 min 5 s"
    assert rt.show({"value": [-0.07, 0.02], "format": "+.2f"}) == "-0.07 / +0.02"


def test_problems_are_named():
    rt = _render_table()
    row = {"id": "r", "what": "w", "figure": "{a} {missing}", "bench": "nonexistent",
           "figures": {"a": {"key": "k", "quoted": "q", "value": 1}, "unused": {"source": "s", "value": 2}}}
    found = rt.problems({"about": "", "rows": [row]})
    assert "r: {missing} has no figure" in found
    assert "r: figure unused is not shown" in found
    assert "r: figure a needs exactly one of key, quoted, source" in found
    assert "r: figure a: no benchmarks/bench_nonexistent.py" in found
