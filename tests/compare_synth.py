"""Synthetic experiment + DEM trajectories with a known time shift and drifting particles."""

from __future__ import annotations

import numpy as np
import pandas as pd


def particle_paths(times: np.ndarray, n: int = 10, onset_s: float = 1.0, speed_mm_s: float = 200.0,
                   seed: int = 0) -> dict[int, np.ndarray]:
    """Marker id (1..n) -> (len(times), 3) positions: at rest on the sand, then pushed and lifted when
    the tool (moving along X from x=0 at onset_s) reaches them."""
    rng = np.random.default_rng(seed)
    out = {}
    for pid in range(1, n + 1):
        x0 = rng.uniform(40, 400)
        y0 = rng.uniform(-60, 60)
        z0 = rng.uniform(-40, -5)
        t_hit = onset_s + x0 / speed_mm_s
        u = np.clip((times - t_hit) / 0.6, 0, None)
        s = 1 - np.exp(-3 * u)  # smooth push
        push = rng.uniform(30, 80)
        out[pid] = np.column_stack([x0 + push * s, y0 + 0.3 * push * s * np.sign(y0), z0 + 15 * s * np.exp(-2 * u)])
    return out


def make_case(shift_s: float = 0.137, drift: dict[int, float] | None = None, n: int = 10, fps: float = 50.0,
              dem_rate: float = 100.0, duration_s: float = 6.0, noise_mm: float = 0.3, seed: int = 0,
              dem_scale: float = 1.0):
    """(experiment df [marker, time_s, X_mm, Y_mm, Z_mm], dem df [particle_id, time_s, X_mm, Y_mm, Z_mm]).
    DEM time t is experiment time t + shift_s. drift: particle -> mm/s along Y after the tool onset."""
    drift = drift or {}
    rng = np.random.default_rng(seed + 1)
    te = np.arange(int(duration_s * fps)) / fps
    exp_paths = particle_paths(te, n, seed=seed)
    rows = []
    for m, p in exp_paths.items():
        p = p + rng.normal(0, noise_mm, p.shape)
        rows.append(pd.DataFrame({"marker": m, "time_s": te, "X_mm": p[:, 0], "Y_mm": p[:, 1], "Z_mm": p[:, 2]}))
    exp = pd.concat(rows, ignore_index=True)
    td = np.arange(int((duration_s + 1) * dem_rate)) / dem_rate - 0.5  # DEM clock
    dem_paths = particle_paths(td + shift_s, n, seed=seed)
    rows = []
    for pid, p in dem_paths.items():
        p = p.copy()
        if dem_scale != 1.0:
            p = p[0] + (p - p[0]) * dem_scale
        if pid in drift:
            p[:, 1] += drift[pid] * np.clip(td + shift_s - 1.0, 0, None)
        rows.append(pd.DataFrame({"particle_id": pid, "time_s": td, "X_mm": p[:, 0], "Y_mm": p[:, 1],
                                  "Z_mm": p[:, 2]}))
    return exp, pd.concat(rows, ignore_index=True)
