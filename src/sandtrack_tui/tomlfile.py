"""Reading a TOML file with one-line errors (missing file, not text, not TOML)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from .errors import SandtrackError


def read_toml(path: str | Path, what: str) -> dict:
    """The parsed document of `path`; `what` names the file in messages ("board", "reference", ...)."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"{what} file not found: {p}")
    try:
        return tomllib.loads(p.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SandtrackError(f"{p}: not a valid TOML {what} file ({exc})") from None
