"""README's performance table, written from the committed figures in benchmarks/results.json.

    python benchmarks/render_table.py            # print the table
    python benchmarks/render_table.py --readme   # write it into README.md ("## Performance")
    python benchmarks/render_table.py --update [benchmarks/out/results.json]
        # take the figures a fresh `make bench` (or `run_all.py NAME`) produced, keep the others,
        # then write README's table

results.json holds one entry per row of the table:

    {"id": "tracking_sample", "what": "tracking, sample: mean / p95 error, false locks",
     "figure": "{mean} / {p95} px, {locks}", "peer": "TrackerMIL {mil} px mean", "target": "≤ 0.3 / 0.6 px, 0",
     "bench": "tracking", "measured": {"date": "2026-11-28", "commit": "14eb529"},
     "figures": {"mean": {"key": "mean_error_px", "value": 0.198, "format": ".3f"}, ...}}

`figure` and `peer` are the cells' text with a `{name}` for each figure. A figure comes from exactly one
place: `key`, the benchmark's output (`bench`, the row's unless the figure names its own; a nested key is a
path with "/", list items by their index), or `quoted` (the source of a figure the project does not measure:
a peer's own publication), or `source` (how a figure not written by a benchmark was measured).
`format` is a Python format spec for a number (`min_s`: seconds as "3 min 5 s"), `scale` multiplies the
benchmark's value first (e.g. 100 for a fraction shown in %); a list is shown as "a / b"; a text value as it is.
A peer cell with a quoted figure ends in ", quoted".
`measured` is the date and commit a figure was measured at: the row's, unless the figure carries its own
(`--update` writes it on each figure it takes). `link` replaces the default link to the row's benchmark.
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results.json"
FRESH = HERE / "out" / "results.json"
README = ROOT / "README.md"
HEADER = "| what | figure | peer on the same data | target | bench |\n| --- | --- | --- | --- | --- |"
MAX_ROW = 200  # bytes (UTF-8) per table row: "±", "–" and "≤" count two or three
PLACES = ("key", "quoted", "source")


def load(path: Path = RESULTS) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def dump(doc: dict) -> str:
    """results.json's own layout: one line per field of a row and per figure, so that a re-measured
    figure is a one-line change."""
    lines = ["{", f' "about": {_j(doc["about"])},', ' "rows": [']
    for i, row in enumerate(doc["rows"]):
        fields = [f'  "{k}": {_j(v)}' for k, v in row.items() if k != "figures"]
        figures = [f'   "{name}": {_j(fig)}' for name, fig in row["figures"].items()]
        fields.append('  "figures": {\n' + ",\n".join(figures) + "\n  }")
        lines.append(" {\n" + ",\n".join(fields) + "\n }" + ("," if i < len(doc["rows"]) - 1 else ""))
    lines += [" ]", "}"]
    return "\n".join(lines) + "\n"


def _j(value) -> str:
    return json.dumps(value, ensure_ascii=False)


# -- rendering ------------------------------------------------------------------------------------
def show(fig: dict) -> str:
    """A figure's value as the table shows it."""
    value, fmt = fig["value"], fig.get("format", "")
    if isinstance(value, list):
        return " / ".join(show({**fig, "value": v}) for v in value)
    if isinstance(value, str) or value is None:
        return value or ""
    value = value * fig.get("scale", 1)
    if fmt == "min_s":
        minutes, seconds = divmod(round(value), 60)
        return f"{minutes} min {seconds} s" if minutes else f"{seconds} s"
    if fmt == "d":
        return str(round(value))
    return format(value, fmt)


def cell(text: str, figures: dict) -> str:
    return re.sub(r"\{(\w+)\}", lambda m: show(figures[m.group(1)]), text)


def link(row: dict) -> str:
    return row.get("link") or f"[{row['bench']}](benchmarks/bench_{row['bench']}.py)"


def peer_cell(row: dict) -> str:
    """The peer's figures, marked "(quoted)" when one of them was not measured by the project."""
    text = row.get("peer", "")
    quoted = any("quoted" in row["figures"][name] for name in re.findall(r"\{(\w+)\}", text))
    return cell(text, row["figures"]) + (", quoted" if quoted else "")


def render_row(row: dict) -> str:
    figures = row["figures"]
    cells = [row["what"], cell(row["figure"], figures), peer_cell(row), row.get("target", ""), link(row)]
    return "| " + " | ".join(cells) + " |"


def render(doc: dict) -> str:
    return "\n".join([HEADER, *(render_row(r) for r in doc["rows"])])


def readme_table(text: str) -> str:
    """The performance table as README has it: from its header to the first line that is not a row."""
    start = text.index(HEADER)
    end = text.find("\n\n", start)
    return text[start:end if end >= 0 else len(text)]


def write_readme(doc: dict, path: Path = README) -> None:
    text = path.read_text(encoding="utf-8")
    path.write_text(text.replace(readme_table(text), render(doc)), encoding="utf-8")


# -- checks ---------------------------------------------------------------------------------------
def problems(doc: dict) -> list[str]:
    """What is wrong with results.json: figures without exactly one origin, names a cell uses but no
    figure gives, figures no cell shows, benchmarks that do not exist, rows too long."""
    out, ids = [], set()
    for row in doc["rows"]:
        rid = row.get("id", "?")
        if rid in ids:
            out.append(f"{rid}: id used twice")
        ids.add(rid)
        used = set(re.findall(r"\{(\w+)\}", row["figure"] + row.get("peer", "")))
        missing = sorted(used - set(row["figures"]))
        out += [f"{rid}: {{{name}}} has no figure" for name in missing]
        for name, fig in row["figures"].items():
            if name not in used:
                out.append(f"{rid}: figure {name} is not shown")
            if sum(p in fig for p in PLACES) != 1:
                out.append(f"{rid}: figure {name} needs exactly one of {', '.join(PLACES)}")
            bench = fig.get("bench", row.get("bench"))
            if "key" in fig and not (HERE / f"bench_{bench}.py").is_file():
                out.append(f"{rid}: figure {name}: no benchmarks/bench_{bench}.py")
        if "link" not in row and not (HERE / f"bench_{row.get('bench')}.py").is_file():
            out.append(f"{rid}: no benchmarks/bench_{row.get('bench')}.py to link")
        size = len(render_row(row).encode()) if not missing else 0
        if size > MAX_ROW:
            out.append(f"{rid}: row of {size} bytes (at most {MAX_ROW})")
    return out


# -- updating from a fresh run --------------------------------------------------------------------
def lookup(figures: dict, key: str):
    """A benchmark's figure by its key: the key itself, else a path of nested keys / list indexes."""
    if key in figures:
        return figures[key]
    value = figures
    for part in key.split("/"):
        if isinstance(value, dict) and part in value:
            value = value[part]
        elif isinstance(value, list) and part.isdigit() and int(part) < len(value):
            value = value[int(part)]
        else:
            raise KeyError(key)
    return value


def update(doc: dict, fresh: dict, date: str, commit: str) -> list[str]:
    """Take every figure `fresh` (run_all.py's output: {bench: {key: value}}) holds; keep the others.
    Returns "row.figure: old -> new" for each figure taken."""
    taken = []
    for row in doc["rows"]:
        for name, fig in row["figures"].items():
            if "key" not in fig:
                continue
            bench = fresh.get(fig.get("bench", row.get("bench")), {})
            try:
                value = lookup(bench, fig["key"])
            except KeyError:
                continue
            if not isinstance(value, (int, float, str, list)) or isinstance(value, bool):
                continue
            before = show(fig)
            fig["value"] = value
            fig["measured"] = {"date": date, "commit": commit}
            taken.append(f"{row['id']}.{name}: {before} -> {show(fig)}")
    return taken


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--readme", action="store_true", help="write the table into README.md")
    ap.add_argument("--update", nargs="?", const=str(FRESH), default=None, metavar="RESULTS",
                    help="take the figures of a fresh run (default benchmarks/out/results.json), then --readme")
    args = ap.parse_args(argv)
    doc = load()
    if args.update:
        fresh = json.loads(Path(args.update).read_text(encoding="utf-8"))
        when = fresh.pop("_measured", None) or {"date": datetime.date.today().isoformat(), "commit": "unknown"}
        taken = update(doc, fresh, when["date"], when["commit"])
        print("\n".join(taken) or "no figure of the table in that run", file=sys.stderr)
        RESULTS.write_text(dump(doc), encoding="utf-8")
    bad = problems(doc)
    if bad:
        print("\n".join(bad), file=sys.stderr)
        return 1
    if args.readme or args.update:
        write_readme(doc)
    else:
        print(render(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
