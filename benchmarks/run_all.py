"""Run every benchmark (`make bench`) and print one table; also writes benchmarks/out/results.json.

Each `bench_*.py` module exposes `run() -> dict` of figures. Run a subset with
`python benchmarks/run_all.py video tracking`.
"""

from __future__ import annotations

import datetime
import importlib
import json
import subprocess
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def commit() -> str:
    """The checkout's commit, "+changes" when tracked files differ from it (what the figures were measured at)."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=HERE, capture_output=True, text=True).stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD")
        return (head + ("+changes" if git("status", "--porcelain", "--untracked-files=no") else "")) or "unknown"
    except OSError:
        return "unknown"


def main(names: list[str]) -> int:
    modules = sorted(p.stem for p in HERE.glob("bench_*.py"))
    if names:
        modules = [m for m in modules if m.removeprefix("bench_") in names]
    results: dict[str, dict] = {}
    failed = 0
    for name in modules:
        t0 = time.perf_counter()
        print(f"== {name}", file=sys.stderr, flush=True)
        try:
            figures = importlib.import_module(name).run()
        except Exception:  # a failing benchmark must not hide the others
            traceback.print_exc()
            figures = {"error": "failed (see log)"}
            failed += 1
        figures["bench_seconds"] = round(time.perf_counter() - t0, 1)
        results[name.removeprefix("bench_")] = figures
    out = HERE / "out"
    out.mkdir(exist_ok=True)
    measured = {"date": datetime.date.today().isoformat(), "commit": commit()}
    (out / "results.json").write_text(json.dumps({"_measured": measured, **results}, indent=2, default=str))
    print("| benchmark | figure | value |")
    print("| --- | --- | --- |")
    for bench, figures in results.items():
        for key, value in figures.items():
            if isinstance(value, float):
                value = f"{value:.4g}"
            print(f"| {bench} | {key} | {value} |")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
