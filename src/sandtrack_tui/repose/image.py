"""Angle of repose from a side photo of a heap (or every few frames of a video).

The outline (`silhouette.heap_outline`) is split at the apex into the left and right flank. Per flank
the toe level is the outline's height at its outer end, the heap height is toe minus apex, and only the
straight middle part is fitted: outline points between `band` = (0.2, 0.8) of that height, leaving out
the toe and the rounded top as the usual standards do. The fit is a robust line (`fit.robust_line`),
first over the band's upper half, then extended down the band in steps of 5 % of the height while the
outline's median there stays within 1.5 % of the heap's height (or 2.5 x its scatter) of the line:
from a camera above the heap the plate's rim curves away below the flank and is left out (the band
used is reported). The fitted part's lower and upper halves are fitted too, to show whether the
flank is straight.

Geometry
- Without a calibration the image is taken as a square-pixel view with level rows: the angle is the
  line's slope. A tilted (rolled) camera changes the two flanks in opposite directions, so their mean
  is almost unaffected; a camera looking up or down at the heap changes both (about +0.5 deg for a
  10 deg tilt at 35 deg): keep the camera level, at the heap's mid-height, and far enough that the
  heap does not fill the view.
- With a calibrated camera (`calibration.toml`: intrinsics and its pose in a world frame whose +Y is
  up) the outline is undistorted first, and the angle is exact under perspective: the silhouette of a
  flank is where the camera's rays graze the heap, so the plane through the camera centre and the
  fitted image line is the plane tangent to the heap along that flank, and a plane tangent to a cone
  with a vertical axis dips at the cone's angle. The angle is that plane's dip from horizontal. A
  calibration of the intrinsics alone (identity world transform) corrects the lens and the pixel
  aspect and takes the camera as level.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import Calibration, Camera
from ..errors import SandtrackError
from .fit import LineFit, Settled, robust_line, settled_value, slope_angle_deg
from .silhouette import Outline, heap_outline

BAND = (0.2, 0.8)
TOE_FRACTION = 0.02  # outermost share of a flank's columns whose median height is its toe level
MIN_HEIGHT_PX = 12
MIN_BAND_POINTS = 12
STRAIGHT_STEP = 0.05  # the band is extended downwards in steps of this share of the height
STRAIGHT_FRACTION = 0.015  # ... while the outline's median there stays this share of the height from the line,
STRAIGHT_SIGMAS = 2.5  # or this many times the outline's scatter about it
TILT_WARN_DEG = 1.5


@dataclass
class Flank:
    side: str
    angle_deg: float
    sigma_deg: float
    points: int
    inliers: int
    rms_px: float
    lower_deg: float | None  # the band's lower half fitted alone
    upper_deg: float | None
    intercept_px: float  # outline line y = intercept + slope * x (undistorted pixels with a calibration)
    slope: float
    x_range_px: tuple[float, float]
    toe_px: tuple[float, float]  # outer end of the flank (x, y)
    band: tuple[float, float]  # part of the height fitted (the lower limit rises where the outline curves)

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class ImageResult:
    source: str
    angle_deg: float
    sigma_deg: float
    flanks: dict[str, Flank]
    geometry: str  # "image rows level" | "calibrated camera NAME"
    apex_px: tuple[float, float]
    height_px: float
    base_width_px: float | None
    base_tilt_deg: float | None
    height_mm: float | None = None
    base_width_mm: float | None = None
    band: tuple[float, float] = BAND
    warnings: list[str] = field(default_factory=list)
    outline: Outline | None = None

    def to_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k not in ("outline", "flanks")}
        d["kind"] = "image"
        d["flanks"] = {k: f.to_dict() for k, f in self.flanks.items()}
        return d


class CameraGeometry:
    """Image line -> dip of the plane through the camera centre and that line (module docstring)."""

    def __init__(self, calibration: Calibration, camera: str | None = None, image_size: tuple[int, int] | None = None):
        name = camera or calibration.names[0]
        if name not in calibration.cameras:
            raise SandtrackError(f"camera {name!r} is not in the calibration ({', '.join(calibration.names)})")
        cam = calibration.cameras[name]
        if image_size is not None and (cam.width, cam.height) != tuple(image_size):
            sx, sy = image_size[0] / cam.width, image_size[1] / cam.height
            if abs(sx - sy) > 1e-3 * max(sx, sy):
                raise SandtrackError(f"the image is {image_size[0]}x{image_size[1]} px but camera {name!r} was "
                                     f"calibrated at {cam.width}x{cam.height} (another aspect ratio)")
            K = cam.matrix.copy()
            K[:2] *= sx
            cam = Camera(cam.name, image_size[0], image_size[1], K, cam.distortion, cam.rvec, cam.tvec, cam.model)
        self.name = name
        self.camera = cam
        up_world = np.array([0.0, 1.0, 0.0])
        self.up_cam = cam.R @ (calibration.world_from_rig[:3, :3].T @ up_world)
        self.up_cam /= np.linalg.norm(self.up_cam)

    def undistort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        u = self.camera.undistort(np.column_stack([x, y]))
        return u[:, 0], u[:, 1]

    def dip_deg(self, intercept: float, slope: float) -> float:
        n = self.camera.matrix.T @ np.array([slope, -1.0, intercept])
        c = abs(float(n @ self.up_cam)) / float(np.linalg.norm(n))
        return float(np.degrees(np.arccos(np.clip(c, 0.0, 1.0))))


def _angle(fit: LineFit, geometry: CameraGeometry | None) -> tuple[float, float]:
    if geometry is None:
        return slope_angle_deg(fit)
    a, b = fit.intercept, fit.slope
    ang = geometry.dip_deg(a, b)
    ea, eb = 1e-3 * (1 + abs(a)), 1e-6 * (1 + abs(b))
    grad = np.array([(geometry.dip_deg(a + ea, b) - geometry.dip_deg(a - ea, b)) / (2 * ea),
                     (geometry.dip_deg(a, b + eb) - geometry.dip_deg(a, b - eb)) / (2 * eb)])
    return ang, float(np.sqrt(max(grad @ fit.cov @ grad, 0.0)))


def _band_fit(xu, yu, y, toe_y: float, height: float, lo: float, hi: float, side: str):
    """Robust line over the outline points between lo and hi of the height: first chosen by their own
    rows, then again by column, where that first line lies in the band (a cut on the outline's own rows
    drops its high points at the top of the band and its low ones at the bottom, and flattens the fit)."""
    rel = (toe_y - y) / height
    for _ in range(2):
        sel = (rel >= lo) & (rel <= hi)
        if sel.sum() < MIN_BAND_POINTS:
            raise SandtrackError(f"the {side} flank has only {int(sel.sum())} outline points in the fitted band")
        fit = robust_line(xu[sel], yu[sel])
        rel = (toe_y - (fit.intercept + fit.slope * xu)) / height
    return fit, (rel >= lo) & (rel <= hi), rel


def _fit_flank(side: str, x, y, xu, yu, toe_y: float, apex_y: float, band, geometry) -> Flank:
    """The flank's straight part: the upper half of the band first, then down the band in steps while the
    outline stays on the line (a camera above the heap sees the plate's rim curve away below the flank)."""
    height = toe_y - apex_y
    lo, hi = band
    used = 0.5 * (lo + hi)
    fit, sel, rel = _band_fit(xu, yu, y, toe_y, height, used, hi, side)
    for step in np.arange(used - STRAIGHT_STEP, lo - 1e-9, -STRAIGHT_STEP):
        seg = (rel >= step) & (rel < used)
        if seg.sum() >= 3:
            off = float(np.median(yu[seg] - (fit.intercept + fit.slope * xu[seg])))
            if abs(off) > max(STRAIGHT_FRACTION * height, STRAIGHT_SIGMAS * fit.scale):
                break
        used = float(step)
        fit, sel, rel = _band_fit(xu, yu, y, toe_y, height, used, hi, side)
    ang, sig = _angle(fit, geometry)
    halves = []
    mid = 0.5 * (used + hi)
    for part in (sel & (rel < mid), sel & (rel >= mid)):
        try:
            halves.append(_angle(robust_line(xu[part], yu[part]), geometry)[0])
        except SandtrackError:
            halves.append(None)
    outer = x[0] if side == "left" else x[-1]
    xs = xu[sel]
    return Flank(side, ang, sig, int(sel.sum()), int(fit.inliers.sum()), fit.scale, halves[0], halves[1],
                 fit.intercept, fit.slope, (float(xs.min()), float(xs.max())), (float(outer), float(toe_y)),
                 (round(used, 3), hi))


def measure_outline(outline: Outline, side: str = "both", band=BAND, geometry: CameraGeometry | None = None,
                    scale_mm_per_px: float | None = None, source: str = "image") -> ImageResult:
    """Flank angles from a heap outline (see module docstring)."""
    x, y = outline.x, outline.y
    if len(x) < 30:
        raise SandtrackError("the heap's outline is too short to measure (under 30 columns)")
    k = max(2, len(x) // 200)
    smooth = np.convolve(np.pad(y, k, mode="edge"), np.ones(2 * k + 1) / (2 * k + 1), "valid")
    i_apex = int(np.argmin(smooth))
    apex = (float(x[i_apex]), float(smooth[i_apex]))
    xu, yu = geometry.undistort(x, y) if geometry is not None else (x, y)
    warnings = []
    sides = ["left", "right"] if side == "both" else [side]
    flanks: dict[str, Flank] = {}
    toes = {}
    for s in ("left", "right"):
        sel = x < apex[0] if s == "left" else x > apex[0]
        n_toe = max(3, int(TOE_FRACTION * sel.sum()))
        ys = y[sel]
        toes[s] = float(np.median(ys[:n_toe] if s == "left" else ys[-n_toe:])) if sel.sum() >= 3 else None
        if s not in sides:
            continue
        if s in outline.touches:
            warnings.append(f"the heap reaches the image's {s} border: its {s} flank is left out")
            continue
        if toes[s] is None or toes[s] - apex[1] < MIN_HEIGHT_PX:
            warnings.append(f"the {s} flank is too short in the image to measure")
            continue
        flanks[s] = _fit_flank(s, x[sel], y[sel], xu[sel], yu[sel], toes[s], apex[1], band, geometry)
    if "top" in outline.touches:
        warnings.append("the heap reaches the image's top border: its apex is cut off")
    if not flanks:
        raise SandtrackError("no flank could be measured" + (f" ({'; '.join(warnings)})" if warnings else ""))
    angles = [f.angle_deg for f in flanks.values()]
    sigma = float(np.sqrt(sum(f.sigma_deg ** 2 for f in flanks.values())) / len(flanks))
    usable = [toes[s] for s in flanks]
    height = float(np.mean(usable) - apex[1])
    width = tilt = None
    if toes["left"] is not None and toes["right"] is not None and not outline.touches & {"left", "right"}:
        width = float(x[-1] - x[0])
        tilt = float(np.degrees(np.arctan2(toes["right"] - toes["left"], x[-1] - x[0])))
        if geometry is None and abs(tilt) > TILT_WARN_DEG:
            warnings.append(f"the toes are {tilt:+.1f} deg off level (camera roll or a tilted plate?): the mean of "
                            "both flanks is nearly unaffected, a single flank is not")
    res = ImageResult(source, float(np.mean(angles)), sigma, flanks,
                      "image rows level" if geometry is None else f"calibrated camera {geometry.name}",
                      apex, height, width, tilt, band=tuple(band), warnings=warnings, outline=outline)
    if scale_mm_per_px:
        res.height_mm = height * scale_mm_per_px
        res.base_width_mm = None if width is None else width * scale_mm_per_px
    return res


def measure_image(img: np.ndarray, side: str = "both", band=BAND, calibration: Calibration | None = None,
                  camera: str | None = None, scale_mm_per_px: float | None = None,
                  source: str = "image") -> ImageResult:
    outline = heap_outline(img)
    geometry = None
    if calibration is not None:
        geometry = CameraGeometry(calibration, camera, (img.shape[1], img.shape[0]))
    return measure_outline(outline, side, band, geometry, scale_mm_per_px, source)


def read_image(path: str | Path) -> np.ndarray:
    import cv2

    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"file not found: {p}")
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        raise SandtrackError(f"{p}: not a readable image")
    return img


@dataclass
class SeriesResult:
    """The angle over time (video frames or DEM output steps) and its settled value."""

    source: str
    kind: str  # "video" | "dump"
    time_s: np.ndarray
    angle_deg: np.ndarray  # NaN where a sample could not be measured
    left_deg: np.ndarray
    right_deg: np.ndarray
    sigma_deg: np.ndarray
    settled: Settled | None
    time_unit: str = "s"
    failures: dict = field(default_factory=dict)  # reason -> count
    last: object = None  # the last measured sample's full result

    @property
    def angle(self) -> float:
        return float("nan") if self.settled is None else self.settled.angle_deg

    def to_dict(self) -> dict:
        rows = [{"time": float(t), "angle_deg": float(a), "left_deg": float(lt), "right_deg": float(r),
                 "sigma_deg": float(s)}
                for t, a, lt, r, s in zip(self.time_s, self.angle_deg, self.left_deg, self.right_deg, self.sigma_deg,
                                          strict=True)]
        return {"source": self.source, "kind": self.kind, "time_unit": self.time_unit,
                "angle_deg": self.angle,
                "settled": None if self.settled is None else dict(self.settled.__dict__),
                "samples": rows, "failures": self.failures,
                "last": None if self.last is None else self.last.to_dict()}


def measure_video(path: str | Path, every_s: float | None = None, max_samples: int = 120, progress=None,
                  should_stop=None, **kw) -> SeriesResult:
    """The angle in frames every `every_s` seconds (default: at most `max_samples` evenly spread)."""
    from ..video import FrameSource

    with FrameSource(path, cache_mb=64) as src:
        n = src.frame_count
        if n == 0:
            raise SandtrackError(f"{path}: no frames")
        step = max(1, int(round(every_s * src.fps)) if every_s else int(np.ceil(n / max_samples)))
        idx = list(range(0, n, step))
        if idx[-1] != n - 1:
            idx.append(n - 1)
        times, ang, left, right, sig = [], [], [], [], []
        failures: dict[str, int] = {}
        last = None
        for k, i in enumerate(idx):
            if should_stop is not None and should_stop():
                break
            times.append(float(src.times_s[i] - src.times_s[0]))
            try:
                r = measure_image(src.frame(i), source=f"{path} frame {i}", **kw)
                ang.append(r.angle_deg)
                left.append(r.flanks["left"].angle_deg if "left" in r.flanks else np.nan)
                right.append(r.flanks["right"].angle_deg if "right" in r.flanks else np.nan)
                sig.append(r.sigma_deg)
                last = r
            except SandtrackError as exc:
                reason = str(exc).split(":")[0]
                failures[reason] = failures.get(reason, 0) + 1
                ang.append(np.nan)
                left.append(np.nan)
                right.append(np.nan)
                sig.append(np.nan)
            if progress is not None:
                progress(k + 1, len(idx))
    t = np.array(times)
    a = np.array(ang)
    if not np.isfinite(a).any():
        raise SandtrackError(f"{path}: no frame showed a measurable heap ({', '.join(failures) or 'stopped'})")
    return SeriesResult(str(path), "video", t, a, np.array(left), np.array(right), np.array(sig),
                        settled_value(t, a), failures=failures, last=last)
