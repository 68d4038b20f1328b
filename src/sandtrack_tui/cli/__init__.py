"""`sandtrack` command line: a thin layer over the core.

Each subcommand lives in its own module here, exposing ``register(subparsers)`` which adds its
parser and sets ``func(args) -> int``. Results go to stdout (one JSON object with ``--json``),
progress and logs to stderr. User errors print one line and exit 1; usage errors exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import NotAvailableYet, SandtrackError

COMMANDS = [
    "tui", "new", "sample", "calibrate", "sync", "train", "track", "xyz", "export", "import", "compare", "demo",
    "relink", "repose", "sweep",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sandtrack",
        description="Two camera videos of marker particles -> verified 3D trajectories (mm).",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"sandtrack {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f".cmd_{name}", __name__).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    if not argv or (argv[0] not in COMMANDS and not argv[0].startswith("-")):
        argv = ["tui", *argv]
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except NotAvailableYet as exc:
        print(f"sandtrack {args.command}: {exc}", file=sys.stderr)
        return 2
    except SandtrackError as exc:
        print(f"sandtrack {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"sandtrack {args.command}: interrupted", file=sys.stderr)
        return 130
