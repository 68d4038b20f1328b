"""tracking/'s modules form no import cycle (an import anywhere in a file counts, inside a function too),
no class there has several bases, and kernels.py imports only what its compiled kernels need."""

from __future__ import annotations

import ast
from pathlib import Path

import sandtrack_tui.tracking as tracking

FOLDER = Path(tracking.__file__).parent


def _imports(path: Path, package: str) -> set[str]:
    """Modules of `package` (its own folder only) that the file imports, anywhere in it."""
    here = {p.stem for p in FOLDER.glob("*.py")}
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom):
            if node.level == 1:  # from . import x / from .x import y
                names = [node.module] if node.module else [a.name for a in node.names]
            elif node.level == 0 and (node.module or "").startswith(package + "."):
                names = [node.module[len(package) + 1:].split(".")[0]]
        elif isinstance(node, ast.Import):
            names = [a.name[len(package) + 1:].split(".")[0] for a in node.names if a.name.startswith(package + ".")]
        out |= {n for n in names if n in here}
    return out - {path.stem}


def _graph() -> dict[str, set[str]]:
    return {p.stem: _imports(p, "sandtrack_tui.tracking") for p in FOLDER.glob("*.py") if p.stem != "__init__"}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_cycle_finder_finds_a_cycle_of_lazy_imports(tmp_path):
    (tmp_path / "a.py").write_text("from . import b\n")
    (tmp_path / "b.py").write_text("def f():\n    from .c import g\n")
    (tmp_path / "c.py").write_text("import numpy\nfrom .a import x\n")
    graph = {p.stem: set() for p in tmp_path.glob("*.py")}
    for p in tmp_path.glob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                graph[p.stem] |= {node.module} if node.module else {a.name for a in node.names}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set(), "c": {"a"}}) == []


def test_tracking_modules_form_no_import_cycle():
    graph = _graph()
    assert {"engine", "kernels", "tracker", "run"} <= set(graph)
    assert "kernels" in graph["matcher"]  # (the graph sees the imports)
    assert _cycles(graph) == []


def test_kernels_import_no_other_tracking_module_but_the_luma_weights():
    assert _graph()["kernels"] <= {"chroma"}


def test_no_tracking_class_has_several_bases():
    several = [f"{p.name}:{n.name}" for p in FOLDER.glob("*.py") for n in ast.walk(ast.parse(p.read_text()))
               if isinstance(n, ast.ClassDef) and len(n.bases) > 1]
    assert several == []
