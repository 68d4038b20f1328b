"""Cached twin renders are keyed on what they depend on (source_hash.py, twin/catalog.py cache_key): the
source their renderer runs and the case's settings; a module a renderer does not import leaves its key."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

from sandtrack_tui import demo
from sandtrack_tui.source_hash import ROOT, module_files, source_hash
from sandtrack_tui.twin import catalog

RENDERERS = ("sandtrack_tui.twin.variants", "sandtrack_tui.twin.flume", "sandtrack_tui.twin.sample")


def _keys(root: Path) -> dict[str, str]:
    return {m: source_hash(m, root) for m in RENDERERS}


def _edit(root: Path, rel: str) -> None:
    f = root / "sandtrack_tui" / rel
    f.write_text(f.read_text() + "\n# changed\n")


def test_a_render_is_keyed_on_the_modules_it_imports_only(tmp_path):
    shutil.copytree(ROOT / "sandtrack_tui", tmp_path / "sandtrack_tui", ignore=shutil.ignore_patterns("__pycache__"))
    before = _keys(tmp_path)
    assert before == _keys(ROOT)  # (the key does not depend on where the package is)
    (tmp_path / "sandtrack_tui" / "twin" / "new_case.py").write_text("from .flume import Flume\n")
    assert _keys(tmp_path) == before  # a new renderer module: no cached render is made again

    steps = [("twin/flume_optics.py", {"sandtrack_tui.twin.flume"}),
             ("twin/scene.py", {"sandtrack_tui.twin.variants", "sandtrack_tui.twin.sample"}),
             ("camera.py", {"sandtrack_tui.twin.variants", "sandtrack_tui.twin.sample"}),  # (from ..camera)
             ("twin/heap.py", {"sandtrack_tui.twin.sample"}),  # (imported inside a function of sample.py)
             ("jit.py", {"sandtrack_tui.twin.flume"}),  # (the kernels' module, imported when beads are simulated)
             ("tracking/run.py", set())]
    for rel, changed in steps:
        _edit(tmp_path, rel)
        after = _keys(tmp_path)
        assert {m for m in RENDERERS if after[m] != before[m]} == changed, rel
        before = after


def test_the_flume_runs_none_of_the_sand_box_renderer():
    flume = {p.name for p in module_files("sandtrack_tui.twin.flume")}
    assert {"flume.py", "flume_physics.py", "flume_kernels.py", "flume_optics.py"} <= flume
    assert not flume & {"variants.py", "render.py", "scene.py", "catalog.py"}
    assert "flume.py" not in {p.name for p in module_files("sandtrack_tui.twin.variants")}
    assert demo.renderer_version() == source_hash("sandtrack_tui.twin.sample")


def test_a_case_key_follows_its_own_settings():
    key = catalog.cache_key("dense")
    assert key == catalog.cache_key(catalog.VARIANTS["dense"]) and len(key) == 10
    assert catalog.cache_key(replace(catalog.VARIANTS["dense"], speed_mm_s=201.0)) != key
    assert catalog.cache_key("flume") != catalog.cache_key("flume-8bit")
    flume = catalog.VARIANTS["flume"]
    assert catalog.cache_key(replace(flume, physics=replace(flume.physics, ustar_mm_s=80.0))) != \
        catalog.cache_key("flume")
