"""A synthetic DEM parameter sweep with a known answer: heaps as LIGGGHTS dumps and tracer trajectories.

Three parameters as in the study's design (restitution e, rolling friction mu_r, Poisson's ratio nu).
Each run's heap has the angle `true_angle(e, mu_r, nu)` (a smooth function, quadratic in mu_r), its
tracers move `true_scale(...)` times as far as the experiment's (the trajectory error grows with the
distance from the parameters that reproduce the experiment).
"""

from __future__ import annotations

import itertools
import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).parent))
from compare_synth import make_case  # noqa: E402

LEVELS = {"restitution": [0.3, 0.5, 0.7], "rolling_friction": [0.05, 0.1, 0.2, 0.3, 0.4],
          "poisson": [0.2, 0.25, 0.3]}


def true_angle(e, mu, nu):
    return 22.0 + 55.0 * mu - 60.0 * mu * mu - 4.0 * (e - 0.5) + 10.0 * (nu - 0.25) + 6.0 * (e - 0.5) * mu


def true_scale(e, mu, nu):
    return 1.0 + 1.2 * (mu - 0.22) + 0.4 * (e - 0.45)


def make_sweep(out: Path, levels: dict | None = None, height_mm: float = 40.0, diameter_mm: float = 3.5,
               trajectories: bool = True, seed: int = 0) -> tuple[Path, pd.DataFrame, float]:
    """Write dumps (+ trajectory CSVs) and RUNS.csv under `out`; returns (RUNS.csv, table, target angle).
    The experiment is the run with e = 0.45, mu_r = 0.22, nu = 0.25 (not on the grid)."""
    from sandtrack_tui import dem as D
    from sandtrack_tui.twin.heap import Heap
    from sandtrack_tui.twin.heap_particles import heap_particles, write_liggghts_dump

    levels = levels or LEVELS
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    exp = None
    for k, (e, mu, nu) in enumerate(itertools.product(*levels.values())):
        ang = float(true_angle(e, mu, nu))
        heap = Heap(height_mm=height_mm, angle_left_deg=ang, angle_right_deg=ang, top_mm=6.0, toe_mm=7.0)
        P, rad = heap_particles(heap, seed=seed + k, diameter_mm=diameter_mm, spilled=10, rounds=25)
        name = f"run{k + 1:02d}"
        write_liggghts_dump(out / f"{name}.liggghts", [(100000, P, rad)])
        row = {"run": name, "restitution": e, "rolling_friction": mu, "poisson": nu, "repose": f"{name}.liggghts",
               "true_angle_deg": ang}
        if trajectories:
            exp, dem = make_case(shift_s=0.1, n=6, seed=seed, duration_s=4.0, dem_scale=true_scale(e, mu, nu))
            D.write_exchange_csv(dem, out / f"{name}_tracers.csv", units="mm")
            row["trajectories"] = f"{name}_tracers.csv"
        rows.append(row)
    table = pd.DataFrame(rows)
    table.drop(columns="true_angle_deg").to_csv(out / "runs.csv", index=False)
    if exp is not None:
        exp, _ = make_case(shift_s=0.1, n=6, seed=seed, duration_s=4.0)
        exp.to_csv(out / "experiment.csv", index=False)
    return out / "runs.csv", table, float(true_angle(0.45, 0.22, 0.25))
