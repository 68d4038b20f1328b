"""The source a module runs: itself and every module of this package it imports, transitively.

A cached result (a rendered twin) is keyed on the hash of that source, so it is made again when code
it runs changed, and only then: a new module that it does not import leaves the key as it was. Imports
are read from the source (module level and inside functions); imports of other packages are not
followed (a new numpy or OpenCV does not change the key).
"""

from __future__ import annotations

import ast
import hashlib
from pathlib import Path

PACKAGE = "sandtrack_tui"
ROOT = Path(__file__).resolve().parent.parent  # the folder holding the package


def _file(module: str, root: Path) -> Path | None:
    rel = Path(*module.split("."))
    for f in (root / rel.with_suffix(".py"), root / rel / "__init__.py"):
        if f.is_file():
            return f
    return None


def _imports(module: str, path: Path) -> set[str]:
    """Modules of the package that `module` (source at `path`) imports, with the packages above them."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.add(target)
            found.update(f"{target}.{a.name}" for a in node.names)  # (from . import module)
    out = set()
    for name in found:
        if name == PACKAGE or name.startswith(PACKAGE + "."):
            parts = name.split(".")
            out.update(".".join(parts[:k]) for k in range(1, len(parts) + 1))
    return out


def module_files(module: str, root: Path = ROOT) -> list[Path]:
    """Source files of `module` and of every package module it imports, transitively (sorted)."""
    seen: dict[str, Path] = {}
    todo = [module] + [module.rsplit(".", k)[0] for k in range(1, module.count(".") + 1)]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        path = _file(name, root)
        if path is None:
            continue  # (a name imported from a module, not a module)
        seen[name] = path
        todo.extend(_imports(name, path) - seen.keys())
    return sorted(seen.values())


def source_hash(module: str, root: Path = ROOT) -> str:
    """Hash (10 hex digits) of the source `module` runs (module_files)."""
    h = hashlib.sha1()
    for f in module_files(module, root):
        h.update(f.relative_to(root).as_posix().encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:10]
