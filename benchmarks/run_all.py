"""Run every benchmark (`make bench`) and print one table; also writes benchmarks/out/results.json.

Each `bench_*.py` module exposes `run() -> dict` of figures. Run a subset with
`python benchmarks/run_all.py video tracking`.
"""

from __future__ import annotations

import importlib
import json
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


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
    (out / "results.json").write_text(json.dumps(results, indent=2, default=str))
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
