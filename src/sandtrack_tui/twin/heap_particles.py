"""Particles of the rendered heaps, written as a DEM code would: LIGGGHTS ``dump custom`` and the exchange CSV.

The heap (`heap.Heap`, the same shape the photos show) is filled with spheres of a spread of radii by
random sequential addition (random places, kept when the sphere rests on or above the plate, its top
stays under the heap's surface and it overlaps no sphere placed before): a loose random packing
without a lattice's terraces. The highest centres lie a radius and a random gap under the surface,
so the surface of the centres has the heap's angle. A few particles have rolled off onto the plate beyond
the toe, as in any poured heap.

Files are in SI units with z up, as LIGGGHTS writes them: dump x = world X, dump y = -world Z,
dump z = world Y (up).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .heap import Heap

DT_S = 1e-5  # the DEM time step written into the ground truth (dumps carry step numbers only)


def _inside(heap: Heap, P: np.ndarray, rad: np.ndarray) -> np.ndarray:
    r = np.hypot(P[:, 0], P[:, 2])
    c = P[:, 0] / np.maximum(r, 1e-9)
    surface = np.where(r < heap.base_radius(c), heap.profile(r, c), 0.0)
    return (P[:, 1] >= rad) & (P[:, 1] + rad <= surface)


def heap_particles(heap: Heap, seed: int = 0, diameter_mm: float = 5.0, spread: float = 0.2,
                   spilled: int = 40, rounds: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 3) world mm, radii (n,) mm) filling `heap` (random sequential addition)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    R, H = heap.max_radius(), heap.height_mm
    r_max = 0.5 * diameter_mm * (1 + spread)
    P = np.zeros((0, 3))
    rad = np.zeros(0)
    volume = np.pi * R * R * H / 3
    batch = int(2 * volume / diameter_mm ** 3) + 100
    for _ in range(rounds):
        c = np.column_stack([rng.uniform(-R, R, batch), rng.uniform(0, H, batch), rng.uniform(-R, R, batch)])
        cr = 0.5 * diameter_mm * (1 + spread * (2 * rng.random(batch) - 1))
        ok = _inside(heap, c, cr)
        c, cr = c[ok], cr[ok]
        if len(P):  # no overlap with the particles placed so far
            d, j = cKDTree(P).query(c, k=8, distance_upper_bound=2 * r_max)
            clash = (d < cr[:, None] + np.where(np.isfinite(d), rad[np.minimum(j, len(rad) - 1)], 0.0))
            ok = ~clash.any(axis=1)
            c, cr = c[ok], cr[ok]
        if len(c) > 1:  # nor among themselves: of a clashing pair, the later one goes
            pairs = cKDTree(c).query_pairs(2 * r_max, output_type="ndarray")
            if len(pairs):
                dd = np.linalg.norm(c[pairs[:, 0]] - c[pairs[:, 1]], axis=1)
                bad = pairs[dd < cr[pairs[:, 0]] + cr[pairs[:, 1]]]
                ok = np.ones(len(c), bool)
                ok[bad.max(axis=1)] = False
                c, cr = c[ok], cr[ok]
        P, rad = np.vstack([P, c]), np.concatenate([rad, cr])
    # spilled particles lying on the plate
    phi = rng.uniform(0, 2 * np.pi, spilled)
    rr = heap.base_radius(np.cos(phi)) * (1.0 + 0.25 * rng.random(spilled))
    rs = 0.5 * diameter_mm * (1 + spread * (2 * rng.random(spilled) - 1))
    S = np.column_stack([rr * np.cos(phi), rs, rr * np.sin(phi)])
    return np.vstack([P, S]), np.concatenate([rad, rs])


def _to_dem(P_mm: np.ndarray) -> np.ndarray:
    return np.column_stack([P_mm[:, 0], -P_mm[:, 2], P_mm[:, 1]]) / 1000.0


def write_liggghts_dump(path: str | Path, steps: list[tuple[int, np.ndarray, np.ndarray]]) -> None:
    """`steps`: (timestep, positions world mm, radii mm) per output step."""
    with open(path, "w") as fh:
        for step, P, rad in steps:
            q = _to_dem(P)
            lo, hi = q.min(axis=0) - 0.01, q.max(axis=0) + 0.01
            fh.write(f"ITEM: TIMESTEP\n{step}\nITEM: NUMBER OF ATOMS\n{len(q)}\nITEM: BOX BOUNDS ff ff ff\n")
            for k in range(3):
                fh.write(f"{lo[k]:.6f} {hi[k]:.6f}\n")
            fh.write("ITEM: ATOMS id type x y z vx vy vz radius\n")
            ids = np.arange(1, len(q) + 1)
            data = np.column_stack([ids, np.ones(len(q)), q, np.zeros((len(q), 3)), rad / 1000.0])
            np.savetxt(fh, data, fmt=["%d", "%d", "%.6f", "%.6f", "%.6f", "%.1f", "%.1f", "%.1f", "%.7f"])


def write_exchange_csv(path: str | Path, time_s: float, P_mm: np.ndarray) -> None:
    q = _to_dem(P_mm)
    with open(path, "w") as fh:
        fh.write("particle_id,time_s,x,y,z\n")
        ids = np.arange(1, len(q) + 1)
        np.savetxt(fh, np.column_stack([ids, np.full(len(q), time_s), q]), fmt=["%d", "%.6f", "%.6f", "%.6f", "%.6f"],
                   delimiter=",")
