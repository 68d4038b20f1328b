"""Caliscope's calibration files: `camera_array.toml` ([cameras.N] tables) and the older
`config.toml` ([cam_N] tables). Both store OpenCV world -> camera poses with the translation in
metres; the rotation is a 3x3 matrix or a Rodrigues 3-vector. Caliscope's world frame becomes this
project's world frame; the rig frame is the first camera's.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import tomli_w

from ..camera import Calibration, Camera
from ..errors import SandtrackError
from ..lens import TERMS, standard_approximation
from ..tomlfile import read_toml
from .geometry import inv_T, to_T


def _rotation(value, source: str) -> np.ndarray:
    r = np.asarray(value, dtype=float)
    if r.size == 9:
        r = r.reshape(3, 3)
        with np.errstate(over="ignore", invalid="ignore"):
            ok = np.isfinite(r).all() and np.allclose(r @ r.T, np.eye(3), atol=1e-4) and np.linalg.det(r) > 0
        if not ok:
            raise SandtrackError(f"{source}: a 3x3 rotation is not a rotation matrix")
        return r
    if r.size == 3:
        return cv2.Rodrigues(r.reshape(3, 1))[0]
    raise SandtrackError(f"{source}: rotation must be a 3x3 matrix or a 3-vector")


def _tables(doc: dict) -> list[tuple[str, dict]]:
    if isinstance(doc.get("cameras"), dict):
        items = [(str(k), v) for k, v in doc["cameras"].items() if isinstance(v, dict)]
    else:
        items = [(k[4:], v) for k, v in doc.items() if k.startswith("cam_") and isinstance(v, dict)]
    return sorted(items, key=lambda kv: (not kv[0].isdecimal(), int(kv[0]) if kv[0].isdecimal() else 0, kv[0]))


def import_caliscope(path: str | Path, names: list[str] | None = None) -> Calibration:
    """Read camera_array.toml or config.toml. `names` renames the cameras in id order
    (default cam_<id>); cameras marked `ignore = true` or without extrinsics are skipped."""
    p = Path(path)
    doc = read_toml(p, "Caliscope")
    tables = [(k, v) for k, v in _tables(doc) if not v.get("ignore", False)
              and v.get("rotation") is not None and v.get("translation") is not None]
    if len(tables) < 1:
        raise SandtrackError(f"{p}: no calibrated cameras ([cameras.N] or [cam_N] with rotation and translation)")
    if names and len(names) > len(tables):
        raise SandtrackError(f"{p}: {len(tables)} calibrated camera(s), but {len(names)} names were given")
    T_cw: dict[str, np.ndarray] = {}
    cams: dict[str, Camera] = {}
    for i, (cid, d) in enumerate(tables[: len(names) if names else None]):
        name = names[i] if names else f"cam_{cid}"
        try:
            size = d.get("size") or d.get("resolution")
            T = np.eye(4)
            T[:3, :3] = _rotation(d["rotation"], str(p))
            T[:3, 3] = np.asarray(d["translation"], dtype=float).ravel() * 1000.0
            dist = np.asarray(d.get("distortions", [0, 0, 0, 0, 0]), dtype=float).ravel()
            model = "fisheye" if d.get("fisheye", False) else "pinhole"
            if model == "pinhole" and len(dist) < 5:
                dist = np.concatenate([dist, np.zeros(5 - len(dist))])
            cams[name] = Camera(name=name, width=int(size[0]), height=int(size[1]),
                                matrix=np.asarray(d["matrix"], dtype=float), distortion=dist, model=model,
                                rmse_px=float(d["error"]) if d.get("error") is not None else None)
        except (KeyError, TypeError, ValueError, IndexError, OverflowError) as exc:
            raise SandtrackError(f"{p}: camera {cid} is malformed ({exc})") from None
        if not np.isfinite(T).all():
            raise SandtrackError(f"{p}: camera {cid} has a pose value that is not a finite number")
        T_cw[name] = T
    first = next(iter(cams))
    world_from_rig = inv_T(T_cw[first])
    for n, cam in cams.items():
        T_c_rig = T_cw[n] @ world_from_rig
        cam.rvec = cv2.Rodrigues(np.ascontiguousarray(T_c_rig[:3, :3]))[0].ravel()
        cam.tvec = T_c_rig[:3, 3].copy()
        cam.check()
    if not np.isfinite(world_from_rig).all():
        raise SandtrackError(f"{p}: camera poses too large to use")
    return Calibration(cameras=cams, world_from_rig=world_from_rig,
                       report={"source": f"imported from Caliscope {p.name}"})


def export_caliscope(calibration: Calibration, path: str | Path) -> list[str]:
    """Write a Caliscope camera_array.toml: world -> camera poses (metres), rotation as 3x3 matrix.

    Caliscope keeps five pinhole distortion terms (k1 k2 p1 p2 k3) or the fisheye's four: a camera
    with rational, thin-prism or tilt terms is written with the five-term model closest to its own
    over the image, and the returned notes say what was dropped and by how many pixels that moves a
    point at most."""
    rig_from_world = inv_T(calibration.world_from_rig)
    doc: dict = {"cameras": {}}
    notes = []
    for i, (n, cam) in enumerate(calibration.cameras.items()):
        T = to_T(cam.rvec, cam.tvec) @ rig_from_world
        distortion = cam.distortion
        if cam.model == "pinhole" and len(distortion) > 5 and np.any(distortion[5:]):
            grid = np.stack(np.meshgrid(np.linspace(0, cam.width, 41), np.linspace(0, cam.height, 41)), -1)
            und = cam.undistort(grid.reshape(-1, 2))  # the image's own field, in undistorted pixels
            K = cam.matrix
            xy = np.stack([(und[:, 0] - K[0, 2]) / K[0, 0], (und[:, 1] - K[1, 2]) / K[1, 1]], axis=1)
            distortion, moved = standard_approximation(K, distortion, xy)
            dropped = [t for t, v in zip(TERMS[5:], cam.distortion[5:], strict=False) if v]
            notes.append(f"Caliscope export, camera {n}: the {cam.lens} lens's {' '.join(dropped)} terms do not fit "
                         f"Caliscope's five-term model; written as the closest k1 k2 p1 p2 k3 model "
                         f"(points move by up to {moved:.2f} px over the image)")
        elif cam.model == "pinhole":
            distortion = np.r_[distortion, np.zeros(5)][:5]
        entry = {
            "cam_id": i,
            "name": n,
            "size": [int(cam.width), int(cam.height)],
            "rotation_count": 0,
            "error": float(cam.rmse_px) if cam.rmse_px is not None else 0.0,
            "matrix": cam.matrix.tolist(),
            "distortions": np.asarray(distortion, dtype=float).tolist(),
            "translation": (T[:3, 3] / 1000.0).tolist(),
            "rotation": T[:3, :3].tolist(),
            "ignore": False,
        }
        if cam.model == "fisheye":
            entry["fisheye"] = True
        doc["cameras"][str(i)] = entry
    Path(path).write_text(tomli_w.dumps(doc))
    return notes
