"""Missed markers among touching lookalikes (a dense layer): carried by their neighbours, given back
by one assignment of all of them to the layer's beads.

Identical touching beads cannot be told apart by how they look, only by where they are. The sand
carries a layer's beads together, so a bead the tracker missed is where its neighbours' motion took
it: each frame it moves by the median move of the measured markers near it (with fewer than two of
them, where it went is not known any more: it stays flagged until the operator places it). The beads detected in
the frame (detection.py: every bead like the marker, touching ones split) that no tracked marker
explains are then assigned to the missed markers at once (Hungarian method on the distance). A pair
counts only when it is unambiguous: the bead within `gate` of where the marker was carried, and no
other bead near that place nor other missed marker near that bead within `margin` more than the
pair's own distance. Anything else stays flagged for the operator.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

MIN_NEIGHBOURS = 2  # measured neighbours a missed marker's carried position needs


def carried(missed: np.ndarray, measured_from: np.ndarray, measured_to: np.ndarray, reach: float,
            min_neighbours: int = MIN_NEIGHBOURS) -> np.ndarray:
    """Positions (n, 2) of missed markers moved by the median move (to - from) of the measured markers
    within `reach` of them; NaN for a missed marker with fewer than `min_neighbours` of them (where
    the sand took it is not known)."""
    out = np.array(missed, dtype=float).reshape(-1, 2)
    if not len(out):
        return out
    measured_from = np.asarray(measured_from, float).reshape(-1, 2)
    moves = np.asarray(measured_to, float).reshape(-1, 2) - measured_from
    d = np.hypot(out[:, None, 0] - measured_from[None, :, 0], out[:, None, 1] - measured_from[None, :, 1])
    for i in range(len(out)):
        near = d[i] <= reach
        if near.sum() < min_neighbours:
            out[i] = np.nan
        else:
            out[i] += np.median(moves[near], axis=0)
    return out


def assign(markers: np.ndarray, beads: np.ndarray, gate: float, margin: float) -> tuple[dict, list]:
    """Missed markers (n, 2) to beads (m, 2): ({marker index: bead index} of the unambiguous pairs,
    [marker index] of markers with a bead in their gate but a rival as near)."""
    markers = np.asarray(markers, float).reshape(-1, 2)
    beads = np.asarray(beads, float).reshape(-1, 2)
    if not len(markers) or not len(beads):
        return {}, []
    d = np.hypot(markers[:, None, 0] - beads[None, :, 0], markers[:, None, 1] - beads[None, :, 1])
    d = np.where(np.isfinite(d), d, np.inf)
    big = 1e9
    rows, cols = linear_sum_assignment(np.where(d <= gate, d, big))
    pairs, ambiguous = {}, []
    for r, c in zip(rows, cols, strict=True):
        if d[r, c] > gate:
            continue
        limit = d[r, c] + margin
        rival_bead = np.delete(d[r], c).min(initial=np.inf) < limit
        rival_marker = np.delete(d[:, c], r).min(initial=np.inf) < limit
        if rival_bead or rival_marker:
            ambiguous.append(int(r))
        else:
            pairs[int(r)] = int(c)
    return pairs, ambiguous


def packed_coverage(radius: float, at_least: float, rim_px: float = 1.5, slack: float = 0.18) -> float:
    """Marker coverage (in discs) a bead shows in the centroid's window (radius + rim_px) when six
    beads like it touch it all round: its own disc plus the six neighbours' slivers inside the window
    (a small bead's window holds relatively more of them), plus `slack` for the soft rims; never below
    `at_least`. More than that: a bead partly hidden behind or merged with another."""
    big = radius + rim_px
    d = 2.0 * radius
    a = big * big * math.acos((d * d + big * big - radius * radius) / (2 * d * big))
    b = radius * radius * math.acos((d * d + radius * radius - big * big) / (2 * d * radius))
    c = 0.5 * math.sqrt(max((-d + big + radius) * (d + big - radius) * (d - big + radius) * (d + big + radius), 0.0))
    return max(at_least, 1.0 + 6.0 * (a + b - c) / (math.pi * radius * radius) + slack)
