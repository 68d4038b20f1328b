"""Camera models and the calibration file (`calibration.toml`).

Conventions (as OpenCV): a camera maps a point X in the *rig frame* (mm) to its own frame by
``x_cam = R @ X + t``; pixels follow from the pinhole model with OpenCV's distortion vector (k1 k2
p1 p2 k3, + rational k4..k6, + thin prism s1..s4, + tilted sensor tau_x tau_y) or the fisheye model
(k1..k4); `lens` names the fitted terms (see `lens.py`). The rig frame is the first camera's frame
unless stated otherwise; ``world_from_rig`` (4x4, mm) maps rig coordinates into the sand-box
world frame (X, Y, Z along the box walls, Y up, Z along the tool's travel).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import tomli_w

from .errors import SandtrackError
from .lens import LENSES, get_lens, lens_of, project, undistort_normalised


@dataclass
class Camera:
    name: str
    width: int
    height: int
    matrix: np.ndarray  # 3x3 intrinsic matrix, px
    distortion: np.ndarray  # pinhole: OpenCV's order, 4, 5, 8, 12 or 14 terms; fisheye: (4,) k1..k4
    rvec: np.ndarray = field(default_factory=lambda: np.zeros(3))  # Rodrigues, rig -> camera
    tvec: np.ndarray = field(default_factory=lambda: np.zeros(3))  # mm
    model: str = "pinhole"  # "pinhole" | "fisheye"
    rmse_px: float | None = None
    lens: str | None = None  # lens model name (lens.LENSES); None: the simplest that holds the coefficients

    def __post_init__(self) -> None:
        self.matrix = np.asarray(self.matrix, dtype=np.float64).reshape(3, 3)
        self.distortion = np.asarray(self.distortion, dtype=np.float64).ravel()
        self.rvec = np.asarray(self.rvec, dtype=np.float64).reshape(3)
        self.tvec = np.asarray(self.tvec, dtype=np.float64).reshape(3)
        if self.model not in ("pinhole", "fisheye"):
            raise SandtrackError(f"camera {self.name}: unknown model {self.model!r} (pinhole or fisheye)")
        if self.lens is None:
            self.lens = lens_of(self.distortion, self.model).name if np.isfinite(self.distortion).all() \
                else ("fisheye" if self.model == "fisheye" else "full")
        elif not isinstance(self.lens, str) or self.lens not in LENSES:
            get_lens(str(self.lens))  # raises with the list of names
        if LENSES[self.lens].family != self.model:
            raise SandtrackError(f"camera {self.name}: lens {self.lens!r} does not fit the {self.model} model")

    @property
    def R(self) -> np.ndarray:
        return cv2.Rodrigues(self.rvec)[0]

    @property
    def rmse_axis_px(self) -> float:
        """The pixel noise per image axis (px) the calibration's RMSE (a 2-D distance) implies: RMSE / √2;
        NaN when not known."""
        r = self.rmse_px
        return float(r) / float(np.sqrt(2.0)) if r is not None and np.isfinite(r) else float("nan")

    @property
    def center_mm(self) -> np.ndarray:
        """Camera centre in the rig frame (mm)."""
        return -self.R.T @ self.tvec

    @property
    def projection_matrix(self) -> np.ndarray:
        """3x4 P = K [R | t] for undistorted pixels."""
        return self.matrix @ np.hstack([self.R, self.tvec[:, None]])

    def project(self, points_mm: np.ndarray) -> np.ndarray:
        """Project (N, 3) rig-frame points to (N, 2) distorted pixels."""
        pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
        if len(pts) == 0:
            return np.zeros((0, 2))
        return project(rotate(pts, self.R) + self.tvec, self.matrix, self.distortion, self.model)

    def undistort(self, pixels: np.ndarray) -> np.ndarray:
        """Distorted pixels (N, 2) -> undistorted pixels (N, 2) of the same K (NaN where the lens
        model cannot be inverted)."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        if len(px) == 0:
            return np.zeros((0, 2))
        K = self.matrix
        yd = (px[:, 1] - K[1, 2]) / K[1, 1]
        xd = (px[:, 0] - K[0, 2] - K[0, 1] * yd) / K[0, 0]
        x, y = undistort_normalised(xd, yd, self.distortion, self.model)
        return np.stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]], axis=1)

    def to_dict(self) -> dict:
        d = {
            "model": self.model,
            "lens": self.lens,
            "size": [int(self.width), int(self.height)],
            "matrix": self.matrix.tolist(),
            "distortion": self.distortion.tolist(),
            "rotation": self.rvec.tolist(),
            "translation_mm": self.tvec.tolist(),
        }
        if self.rmse_px is not None:
            d["rmse_px"] = float(self.rmse_px)
        return d

    @classmethod
    def from_dict(cls, name: str, d: dict) -> Camera:
        try:
            w, h = d["size"]
            cam = cls(
                name=name,
                width=int(w),
                height=int(h),
                matrix=np.array(d["matrix"], dtype=float),
                distortion=np.array(d.get("distortion", [0, 0, 0, 0, 0]), dtype=float),
                rvec=np.array(d.get("rotation", [0, 0, 0]), dtype=float),
                tvec=np.array(d.get("translation_mm", [0, 0, 0]), dtype=float),
                model=d.get("model", "pinhole"),
                rmse_px=None if d.get("rmse_px") is None else float(d["rmse_px"]),
                lens=d.get("lens"),
            )
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise SandtrackError(f"camera {name}: malformed entry ({exc})") from None
        cam.check()
        return cam

    def check(self) -> None:
        """Raise SandtrackError unless the size is positive and every number finite (file readers)."""
        if not (self.width > 0 and self.height > 0):
            raise SandtrackError(f"camera {self.name}: image size must be positive, not {self.width}x{self.height}")
        for what, a in (("matrix", self.matrix), ("distortion", self.distortion), ("rotation", self.rvec),
                        ("translation", self.tvec)):
            if not np.isfinite(a).all():
                raise SandtrackError(f"camera {self.name}: {what} has a value that is not a finite number")
        ok = {"pinhole": (0, 4, 5, 8, 12, 14), "fisheye": (4,)}[self.model]
        if len(self.distortion) not in ok:
            raise SandtrackError(f"camera {self.name}: {len(self.distortion)} distortion coefficients for the "
                                 f"{self.model} model (expected {' or '.join(map(str, ok))})")
        lens = LENSES[self.lens]
        extra = [i for i in np.nonzero(self.distortion)[0] if i >= len(lens.free) or not lens.free[i]]
        if extra:
            raise SandtrackError(f"camera {self.name}: the distortion has terms the {lens.name!r} lens model does "
                                 f"not fit (entries {', '.join(str(i + 1) for i in extra)})")


def rotate(points: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(N, 3) points times R^T, row by row (einsum: numpy's matmul took 15 times longer on N x 3)."""
    return np.einsum("ij,kj->ik", points, R)


def euler_angles_deg(R: np.ndarray) -> tuple[float, float, float]:
    """Rotation as three successive rotations about X, Y, Z (R = Rz @ Ry @ Rx), in degrees."""
    sy = math.hypot(R[0, 0], R[1, 0])
    if sy > 1e-9:
        ax = math.atan2(R[2, 1], R[2, 2])
        ay = math.atan2(-R[2, 0], sy)
        az = math.atan2(R[1, 0], R[0, 0])
    else:
        ax = math.atan2(-R[1, 2], R[1, 1])
        ay = math.atan2(-R[2, 0], sy)
        az = 0.0
    return math.degrees(ax), math.degrees(ay), math.degrees(az)


@dataclass
class CameraUncertainty:
    """Covariance of a camera's calibrated parameters (from its bundle adjustment: (JᵀWJ)⁻¹ σ² at the
    solution, the board poses marginalised, raised to the per-view sandwich where there are views enough;
    `bundle.parameter_covariance`). parameters: names in `triangulation_sd` terms (rx ry rz
    tx ty tz: the pose, fx fy cx cy: the camera matrix, dK: the K-th distortion coefficient)."""

    parameters: list[str]
    covariance: np.ndarray  # (P, P) in the parameters' units (rad, mm, px, 1)
    sigma_px: float | None = None  # the fit's residual sd
    # the camera's own pixel noise per image axis (x, y), apart from the known points' shared error
    # (calibration.known_point_errors); None where not separated
    noise_px: list[float] | None = None
    # the lens model that fitted the left-out views better where a simpler one was kept: the covariance
    # holds the spread between the two (calibration.model_choice)
    better_lens: str | None = None
    # the allowance for a shift all corners of one view share, which the view's board pose absorbs so that no
    # residual shows it: its sd in pixels per image axis (world_uncertainty.SHARED_VIEW_ERROR times noise_px,
    # set by a calibration from videos); None where not allowed for
    view_shared_px: list[float] | None = None

    def __post_init__(self) -> None:
        self.parameters = [str(p) for p in self.parameters]
        if self.noise_px is not None:
            self.noise_px = [float(v) for v in np.asarray(self.noise_px, float).reshape(2)]
        if self.view_shared_px is not None:
            self.view_shared_px = [float(v) for v in np.asarray(self.view_shared_px, float).reshape(2)]
        self.covariance = np.asarray(self.covariance, dtype=np.float64).reshape(len(self.parameters),
                                                                               len(self.parameters))

    def to_dict(self) -> dict:
        d = {"parameters": list(self.parameters), "covariance": self.covariance.tolist()}
        if self.sigma_px is not None:
            d["sigma_px"] = float(self.sigma_px)
        if self.noise_px is not None:
            d["noise_px"] = list(self.noise_px)
        if self.better_lens is not None:
            d["better_lens"] = self.better_lens
        if self.view_shared_px is not None:
            d["view_shared_px"] = list(self.view_shared_px)
        return d

    @classmethod
    def from_dict(cls, name: str, d: dict) -> CameraUncertainty:
        try:
            unc = cls(list(d["parameters"]), np.array(d["covariance"], dtype=float),
                      None if d.get("sigma_px") is None else float(d["sigma_px"]), d.get("noise_px"),
                      None if d.get("better_lens") is None else str(d["better_lens"]), d.get("view_shared_px"))
        except (KeyError, TypeError, ValueError) as exc:
            raise SandtrackError(f"uncertainty of camera {name}: malformed entry ({exc})") from None
        if not np.isfinite(unc.covariance).all():
            raise SandtrackError(f"uncertainty of camera {name}: a covariance value is not a finite number")
        if unc.noise_px is not None and not (np.isfinite(unc.noise_px).all() and min(unc.noise_px) >= 0):
            raise SandtrackError(f"uncertainty of camera {name}: noise_px must be two finite numbers ≥ 0")
        if unc.view_shared_px is not None and not (np.isfinite(unc.view_shared_px).all()
                                                   and min(unc.view_shared_px) >= 0):
            raise SandtrackError(f"uncertainty of camera {name}: view_shared_px must be two finite numbers ≥ 0")
        return unc


@dataclass
class RigUncertainty:
    """The calibration's parameters taken together, with the world frame that depends on them.

    parameters: "CAMERA/NAME" in `CameraUncertainty` terms, every camera's; covariance: their joint (P, P)
    covariance (the bundle adjustment's, correlations between cameras kept). The world frame moves with
    them: a small change δθ of the parameters moves a world point X by ω × X + τ with ψ = (ω, τ) =
    world_jacobian @ δθ (rad, mm; (6, P)), because the world frame is refitted to its reference (a board
    lying in a reference frame, or known points) seen through the changed cameras. world_covariance: ψ's own
    (6, 6) covariance from the reference's measurement (its detections' noise), apart from the cameras'."""

    parameters: list[str]
    covariance: np.ndarray
    world_jacobian: np.ndarray
    world_covariance: np.ndarray

    def __post_init__(self) -> None:
        self.parameters = [str(p) for p in self.parameters]
        n = len(self.parameters)
        self.covariance = np.asarray(self.covariance, dtype=np.float64).reshape(n, n)
        self.world_jacobian = np.asarray(self.world_jacobian, dtype=np.float64).reshape(6, n)
        self.world_covariance = np.asarray(self.world_covariance, dtype=np.float64).reshape(6, 6)

    def world_frame_sd(self) -> dict | None:
        """The world frame's own sd, the cameras' part included: its rotation (mrad, about X, Y, Z) and the
        motion of the world origin (mm); None where nothing moves it (the world is the rig frame)."""
        if not (self.world_jacobian.any() or self.world_covariance.any()):
            return None
        C = self.world_jacobian @ self.covariance @ self.world_jacobian.T + self.world_covariance
        sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
        return {"rotation_sd_mrad": [float(v) for v in 1e3 * sd[:3]], "origin_sd_mm": [float(v) for v in sd[3:]]}

    def camera_parameters(self, camera: str) -> tuple[list[str], np.ndarray]:
        """(names, global column of each) of one camera's parameters."""
        prefix = camera + "/"
        cols = [i for i, p in enumerate(self.parameters) if p.startswith(prefix)]
        return [self.parameters[i][len(prefix):] for i in cols], np.array(cols, dtype=np.int64)

    def to_dict(self) -> dict:
        return {"parameters": list(self.parameters), "covariance": self.covariance.tolist(),
                "world_jacobian": self.world_jacobian.tolist(), "world_covariance": self.world_covariance.tolist()}

    @classmethod
    def from_dict(cls, d: dict, cameras) -> RigUncertainty:
        try:
            unc = cls(list(d["parameters"]), np.array(d["covariance"], dtype=float),
                      np.array(d["world_jacobian"], dtype=float), np.array(d["world_covariance"], dtype=float))
        except (KeyError, TypeError, ValueError) as exc:
            raise SandtrackError(f"rig_uncertainty: malformed entry ({exc})") from None
        if not all(np.isfinite(a).all() for a in (unc.covariance, unc.world_jacobian, unc.world_covariance)):
            raise SandtrackError("rig_uncertainty: a value is not a finite number")
        unknown = sorted({p.split("/")[0] for p in unc.parameters} - set(cameras))
        if unknown:
            raise SandtrackError(f"rig_uncertainty: parameters of unknown camera(s) {', '.join(unknown)}")
        return unc


@dataclass
class Calibration:
    """A calibrated rig: cameras (rig frame, mm) and the rig -> sand-box world transform; `uncertainty`:
    per camera, the covariance of its parameters (absent in files written before it was kept);
    `rig_uncertainty`: the same jointly, with the world frame's (absent where not known)."""

    cameras: dict[str, Camera]
    world_from_rig: np.ndarray = field(default_factory=lambda: np.eye(4))
    report: dict = field(default_factory=dict)
    uncertainty: dict[str, CameraUncertainty] = field(default_factory=dict)
    # all cameras' parameters together and the world frame's dependence on them (None: each camera alone,
    # the world frame taken as exact)
    rig_uncertainty: RigUncertainty | None = None
    # per camera, the image region its calibration points covered (calibration/region.py: the convex hull's
    # half-planes, px); a camera without one: not known
    regions: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.world_from_rig = np.asarray(self.world_from_rig, dtype=np.float64).reshape(4, 4)

    @property
    def names(self) -> list[str]:
        return list(self.cameras)

    def to_world(self, points_rig: np.ndarray) -> np.ndarray:
        p = np.asarray(points_rig, dtype=np.float64).reshape(-1, 3)
        return rotate(p, self.world_from_rig[:3, :3]) + self.world_from_rig[:3, 3]

    def to_rig(self, points_world: np.ndarray) -> np.ndarray:
        p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        R, t = self.world_from_rig[:3, :3], self.world_from_rig[:3, 3]
        return rotate(p - t, R.T)

    def project_world(self, camera: str, points_world: np.ndarray) -> np.ndarray:
        return self.cameras[camera].project(self.to_rig(points_world))

    def to_toml(self) -> str:
        doc = {
            "units": "mm",
            "convention": "OpenCV: x_cam = R(rotation, Rodrigues) @ X_rig + translation_mm; "
            "X_world = world_from_rig @ [X_rig, 1]",
            "cameras": {n: c.to_dict() for n, c in self.cameras.items()},
            "world": {
                "world_from_rig": self.world_from_rig.tolist(),
                "angles_deg_xyz": list(euler_angles_deg(self.world_from_rig[:3, :3])),
            },
        }
        if self.uncertainty:
            doc["uncertainty"] = {n: u.to_dict() for n, u in self.uncertainty.items() if n in self.cameras}
        if self.rig_uncertainty is not None:
            doc["rig_uncertainty"] = self.rig_uncertainty.to_dict()
        if self.regions:
            doc["calibrated_region"] = {n: {"halfplanes_px": np.asarray(r, float).tolist()}
                                        for n, r in self.regions.items() if n in self.cameras}
        if self.report:
            doc["report"] = _plain(self.report)
        return tomli_w.dumps(doc)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_toml())

    @classmethod
    def from_toml(cls, text: str, source: str = "calibration") -> Calibration:
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SandtrackError(f"{source}: not a valid TOML file ({exc})") from None
        cams = doc.get("cameras")
        if not isinstance(cams, dict) or not cams:
            raise SandtrackError(f"{source}: no [cameras.NAME] tables found")
        cameras = {name: Camera.from_dict(name, d) for name, d in cams.items()}
        world = doc.get("world", {})
        world = world.get("world_from_rig", np.eye(4).tolist()) if isinstance(world, dict) else None
        try:
            world = np.array(world, dtype=float).reshape(4, 4)
        except (ValueError, TypeError):
            raise SandtrackError(f"{source}: world_from_rig must be a 4x4 matrix") from None
        if not np.isfinite(world).all():
            raise SandtrackError(f"{source}: world_from_rig has a value that is not a finite number")
        unc = doc.get("uncertainty", {})
        unc = {n: CameraUncertainty.from_dict(n, d) for n, d in unc.items() if n in cameras and isinstance(d, dict)} \
            if isinstance(unc, dict) else {}
        rig_unc = doc.get("rig_uncertainty")
        rig_unc = RigUncertainty.from_dict(rig_unc, cameras) if isinstance(rig_unc, dict) else None
        return cls(cameras=cameras, world_from_rig=world, report=doc.get("report", {}), uncertainty=unc,
                   rig_uncertainty=rig_unc, regions=_regions(doc.get("calibrated_region"), cameras, source))

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        p = Path(path)
        if not p.is_file():
            raise SandtrackError(f"calibration file not found: {p}")
        try:
            text = p.read_text()
        except UnicodeDecodeError as exc:
            raise SandtrackError(f"{p}: not a valid TOML file ({exc})") from None
        return cls.from_toml(text, source=str(p))


def _regions(doc, cameras, source: str) -> dict[str, np.ndarray]:
    """[calibrated_region.CAMERA] halfplanes_px = [[nx, ny, d], ...] of the cameras in the file."""
    out = {}
    for name, d in (doc.items() if isinstance(doc, dict) else ()):
        if name not in cameras or not isinstance(d, dict):
            continue
        try:
            r = np.array(d.get("halfplanes_px", []), dtype=float).reshape(-1, 3)
        except (ValueError, TypeError):
            raise SandtrackError(f"{source}: calibrated_region.{name}: halfplanes_px must be rows of three "
                                 "numbers") from None
        if len(r) < 3 or not np.isfinite(r).all():
            raise SandtrackError(f"{source}: calibrated_region.{name}: needs three or more finite half-planes")
        out[name] = r
    return out


def _plain(obj):
    """Make a report TOML-serialisable (numpy scalars/arrays -> Python, None dropped)."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items() if v is not None}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj if v is not None]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
