"""`sandtrack track`: not available in this version yet."""

from .common import add_json_flag, not_available


def register(sub) -> None:
    p = sub.add_parser("track", help="(track: not available yet)")
    p.add_argument("args", nargs="*")
    add_json_flag(p)
    p.set_defaults(func=not_available("sandtrack track"))
