"""The sand-box world frame (mm, Y up).

From the board lying flat in a reference frame: the board lies face up on the sand, its x axis
(columns, OpenCV board frame) along world +X, its y axis (rows) along world +Z, its z axis (into
the board) along world -Y; the board-frame origin sits at world `origin_mm`.

From three or more known points: the rigid transform (Kabsch) that maps their triangulated rig
positions onto their known world positions.

Either way one 4x4 `world_from_rig` is stored, with its three angles (R = Rz Ry Rx) for reference.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import euler_angles_deg
from ..errors import SandtrackError
from ..tomlfile import read_toml
from .geometry import inv_T, kabsch

# columns: board x, y, z axes expressed in world coordinates
WORLD_FROM_BOARD_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def world_from_board_pose(T_rig_board: np.ndarray, origin_mm=(0.0, 0.0, 0.0)) -> np.ndarray:
    """world_from_rig given the board -> rig pose of the reference frame."""
    T_world_board = np.eye(4)
    T_world_board[:3, :3] = WORLD_FROM_BOARD_AXES
    T_world_board[:3, 3] = np.asarray(origin_mm, dtype=float)
    return T_world_board @ inv_T(T_rig_board)


def world_from_known_points(rig_points: np.ndarray, world_points: np.ndarray) -> tuple[np.ndarray, float]:
    """Kabsch fit; returns (world_from_rig, RMS residual mm)."""
    rig_points = np.asarray(rig_points, dtype=float).reshape(-1, 3)
    world_points = np.asarray(world_points, dtype=float).reshape(-1, 3)
    ok = np.isfinite(rig_points).all(1) & np.isfinite(world_points).all(1)
    if ok.sum() < 3:
        raise SandtrackError("the world frame needs at least 3 known points seen by both cameras")
    centred = world_points[ok] - world_points[ok].mean(0)
    if np.linalg.svd(centred, compute_uv=False)[1] < 1e-6 * max(1.0, np.abs(centred).max()):
        raise SandtrackError("the known points lie on one line: use at least 3 points that span a plane")
    T = kabsch(rig_points[ok], world_points[ok])
    res = world_points[ok] - (rig_points[ok] @ T[:3, :3].T + T[:3, 3])
    return T, float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))


def describe(world_from_rig: np.ndarray) -> dict:
    return {"angles_deg_xyz": list(euler_angles_deg(world_from_rig[:3, :3])),
            "translation_mm": world_from_rig[:3, 3].tolist()}


def load_reference(path: str | Path) -> tuple[int, tuple[float, float, float]]:
    """A reference.toml: `frame = N` and optional `origin_mm = [X, Y, Z]`."""
    p = Path(path)
    d = read_toml(p, "reference")
    try:
        frame = int(d["frame"])
        origin = tuple(float(v) for v in d.get("origin_mm", (0.0, 0.0, 0.0)))
    except (KeyError, TypeError, ValueError) as exc:
        raise SandtrackError(f"{p}: needs `frame = N` and optionally `origin_mm = [X, Y, Z]` ({exc})") from None
    if len(origin) != 3:
        raise SandtrackError(f"{p}: origin_mm needs three values")
    return frame, origin  # type: ignore[return-value]


def parse_origin(text: str) -> tuple[float, float, float]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        vals = ()
    if len(vals) != 3:
        raise SandtrackError(f"--reference-origin-mm needs X,Y,Z in mm, not {text!r}")
    return vals  # type: ignore[return-value]
