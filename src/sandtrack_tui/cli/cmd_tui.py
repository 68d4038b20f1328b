"""`sandtrack [tui] [PROJECT]`: the terminal UI (not available yet)."""

from .common import not_available


def register(sub) -> None:
    p = sub.add_parser("tui", help="open the terminal UI (default)")
    p.add_argument("project", nargs="?", help="project file; the bundled sample project if omitted")
    p.set_defaults(func=not_available("the terminal UI"))
