"""Harder cases of the rig's twin, for the tracker: other markers, other sand, crowds, speed, blur, shake.

Each variant renders the same sand box, tool and light as the sample (render.py, scene.py) through a
window of the true cameras (a crop, optionally zoomed: a longer lens), with exact ground truth:

- marker styles: blue paint (the sample's), red, white, black, grey glass beads (STYLES);
- sand tones: the sample's dry sand, light, dark, wet (SAND_TONES);
- layouts: the sample's 8 scripted markers, a dense layer of identical beads that touch (`dense`: two
  patches of hexagonally packed beads beside the tool's lane, carried by the sand), or a few hundred
  identical beads scattered in and beside the lane (`scattered`: some touching, pushed by the tool);
- tool speed (markers pushed at up to ~25 px per frame), motion blur (the exposure is sampled),
  marker size (8-15 px: zoom, radius);
- camera shake and pan: the image moves by a known small rotation of the camera each frame (a
  rendered margin, warped and cropped), the truth moved with it;
- output as H.264 video, a folder of JPEG frames, or a folder of 16-bit grey TIFF frames.

The cases themselves are listed in catalog.py. `render_sandbox(variant, out_dir)` writes
``experiment/CAMERA.mp4`` (or ``experiment/CAMERA/`` image folders), ``ground_truth/markers_CAMERA.csv``
(frame, marker, x_px, y_px, visible, visible_fraction), ``ground_truth/cameras.toml`` (the true
cameras of the windows, when the view does not shake) and ``variant.json``. Deterministic for a seed.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.spatial import cKDTree

from ..camera import Calibration, Camera
from ..errors import SandtrackError
from .render import BLUE_PAINT, CameraView, MarkerStyle, SandShader, update_g3
from .rig import FPS, TOOL_X, true_calibration, world_cameras
from .scene import (
    MARKER_RADIUS,
    SAND_Y,
    SHANK_CHORD,
    SHANK_HALF_X,
    MarkerScript,
    SurfaceGrid,
    Timeline,
    visible_fraction,
)
from .textures import SAND_BGR, Textures

STYLES = {
    "blue": BLUE_PAINT,
    "red": MarkerStyle(albedo=(0.08, 0.10, 0.62)),
    "white": MarkerStyle(albedo=(0.80, 0.82, 0.82), spec=0.08),
    "black": MarkerStyle(albedo=(0.045, 0.045, 0.05), spec=0.35, shininess=40),
    "glass": MarkerStyle(albedo=(0.42, 0.45, 0.44), spec=0.9, shininess=120, ior=1.52),
}
SAND_TONES = {
    "dry": tuple(float(v) for v in SAND_BGR),
    "light": (0.66, 0.76, 0.83),
    "dark": (0.17, 0.21, 0.26),
    "wet": (0.27, 0.38, 0.50),
}
# Centres of the windows of the true cameras holding the markers (the sample's markers: side x 715-1106,
# y 450-734; the dense layer: side x 752-831, y 486-706, front x 828-1027, y 475-530; the scattered
# beads: side x 539-1104, y 451-786, front x 704-1081, y 412-677).
WINDOW_CENTRE = {"scripted": {"side": (910.0, 590.0), "front": (920.0, 560.0)},
                 "dense": {"side": (792.0, 596.0), "front": (928.0, 502.0)},
                 "scattered": {"side": (822.0, 618.0), "front": (893.0, 545.0)}}
VISIBLE_MIN_FRACTION = 0.5


@dataclass(frozen=True)
class Variant:
    name: str
    style: str = "blue"
    sand: str = "dry"
    layout: str = "scripted"  # "scripted" (the sample's 8 markers) | "dense" | "scattered" (LAYOUTS)
    speed_mm_s: float = 100.0
    radius_mm: float = MARKER_RADIUS
    zoom: float = 1.0  # focal length x zoom
    size: tuple = (480, 320)  # window, px
    frames: int | None = None  # None: as the sample, until the tool is 260 mm past the last marker row
    start_s: float = 0.0  # scene time of the first frame (the tool starts at 1.2 s)
    shutter: float = 0.0  # exposure, fraction of the frame time (motion blur)
    shake_px: float = 0.0  # camera shake, rms px
    pan_px: float = 0.0  # camera pan, px per frame (along x)
    cameras: tuple = ("side", "front")
    output: str = "mp4"  # "mp4" | "jpeg" | "tiff16"
    note: str = ""


LAST_ROW_Z = {"scripted": 650.0, "dense": 545.0, "scattered": 690.0}


def frame_count(v: Variant) -> int:
    """Frames of a variant: from its start until the tool has passed the last marker row by 260 mm
    (the sample's span at the sample's speed: 440 frames)."""
    if v.frames is not None:
        return v.frames
    end_s = Timeline().tool_start_s + (LAST_ROW_Z[v.layout] + 260.0 - 150.0) / v.speed_mm_s
    return int(round((end_s - v.start_s) * FPS))


# -- geometry -------------------------------------------------------------------------------------

def window_camera(cam: Camera, size: tuple, zoom: float, margin: int = 0, layout: str = "scripted"
                  ) -> tuple[Camera, tuple]:
    """The camera seeing a `size` window (plus `margin` px around) of `cam`'s image around the
    layout's markers, zoomed about its principal point; returns it and the window's origin in the
    zoomed image."""
    w, h = size
    K = cam.matrix.copy()
    K[0, 0] *= zoom
    K[1, 1] *= zoom
    cx, cy = WINDOW_CENTRE[layout][cam.name]
    zx, zy = cam.matrix[0, 2] + zoom * (cx - cam.matrix[0, 2]), cam.matrix[1, 2] + zoom * (cy - cam.matrix[1, 2])
    x0, y0 = int(round(zx - w / 2)) - margin, int(round(zy - h / 2)) - margin
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(cam.name, w + 2 * margin, h + 2 * margin, K, cam.distortion, cam.rvec, cam.tvec), (x0, y0)


def window_calibration(v: Variant) -> Calibration:
    """The true rig (rig frame = side camera) seen through the variant's windows."""
    cal = true_calibration()
    cams = {}
    for name in v.cameras:
        cams[name], _ = window_camera(cal.cameras[name], v.size, v.zoom, layout=v.layout)
    return Calibration(cams, cal.world_from_rig, report={"source": f"sandtrack twin variant {v.name}: true cameras"})


# -- the dense layer ------------------------------------------------------------------------------

class DenseLayer:
    """Identical beads hexagonally packed in two patches beside the tool's lane, carried by the sand:
    pushed outward and forward and lifted by the mound as the tool passes, as a smooth field (close
    beads move alike, so neighbours stay neighbours), riding on the sand surface."""

    def __init__(self, seed: int, timeline: Timeline, radius: float, cols: int = 7, rows: int = 4):
        rng = np.random.default_rng(seed + 29)
        self.timeline, self.radius = timeline, radius
        pitch = 2 * radius * 1.04  # touching, with a hair of sand between
        self.p0 = {}
        k = 1
        for side in (-1, 1):
            for r in range(rows):
                for c in range(cols):
                    x_rel = side * (3.2 * radius + pitch * (c + 0.5 * (r % 2)))
                    z = 525.0 + r * pitch * np.sqrt(3) / 2
                    self.p0[k] = np.array([TOOL_X + x_rel, SAND_Y + radius, z]) + np.r_[rng.normal(0, 0.1), 0,
                                                                                       rng.normal(0, 0.1)]
                    k += 1
        s = np.array([-200.0, -90.0, -40.0, 0.0, 40.0, 90.0, 300.0])
        ramp = np.array([0.0, 0.0, 0.25, 0.6, 0.9, 1.0, 1.0])
        lift = np.array([0.0, 0.0, 0.5, 1.0, 0.3, 0.0, 0.0])
        self._ramp = PchipInterpolator(s, ramp, extrapolate=True)
        self._lift = PchipInterpolator(s, lift, extrapolate=True)
        self._jit = {k: rng.normal(0, 0.04) for k in self.p0}

    def positions(self, t: float, surface: SurfaceGrid) -> dict[int, np.ndarray]:
        zt = float(self.timeline.tool_z(t))
        out = {}
        for k, p in self.p0.items():
            x_rel = p[0] - TOOL_X
            s = float(np.clip(zt - p[2], -200.0, 300.0))
            a = float(self._ramp(s)) * (1 + self._jit[k])
            near = np.exp(-(x_rel / 95.0) ** 2)
            x = p[0] + np.sign(x_rel) * 14.0 * near * a
            z = p[2] + 12.0 * np.exp(-(x_rel / 70.0) ** 2) * a
            y = surface.height_at(x, z, zt) + self.radius + 1.5 * near * float(self._lift(s))
            out[k] = np.array([x, y, z])
        return out


class ScatteredLayer:
    """A few hundred identical beads scattered over the sand in and beside the tool's lane (about a
    third of them dropped against another: touching pairs and clusters), pushed by the tool. The sand's
    surface flows round the advancing tool: each bead moves with the velocity of a source that travels
    just behind the shank's front (the flow round a half-body HALF_WIDTH_MM wide: a bead in the lane is
    carried ahead of the shank, then slides off to one side), fading with the distance across the lane
    as the disturbed zone does and nil behind the tool, where the sand has settled. Beads never pass
    through each other (overlaps are pushed apart every step) nor into the shank, and ride on the sand
    surface. Trajectories are integrated once (STEPS_PER_FRAME per frame) over the tool's whole travel."""

    COUNT = 300
    REGION_X = (TOOL_X - 95.0, TOOL_X + 95.0)
    REGION_Z = (440.0, 690.0)
    HALF_WIDTH_MM = 45.0
    REACH_MM = 70.0
    STEPS_PER_FRAME = 8

    def __init__(self, seed: int, timeline: Timeline, radius: float):
        rng = np.random.default_rng(seed + 53)
        self.timeline, self.radius = timeline, radius
        xz = self._scatter(rng)
        self.dt = 1.0 / (FPS * self.STEPS_PER_FRAME)
        self.t0 = timeline.tool_start_s
        n = int(np.ceil((timeline.tool_end_s - self.t0) / self.dt)) + 2
        self.track = np.empty((n, len(xz), 2))
        for k in range(n):
            self.track[k] = xz
            xz = self._step(xz, self.t0 + k * self.dt)

    def _scatter(self, rng) -> np.ndarray:
        gap = 2 * self.radius * 1.02  # touching, with a hair of sand between
        pts: list[np.ndarray] = []
        while len(pts) < self.COUNT:
            for _ in range(500):
                if pts and rng.random() < 0.35:
                    a = rng.uniform(0, 2 * np.pi)
                    p = pts[int(rng.integers(len(pts)))] + gap * 1.001 * np.array([np.cos(a), np.sin(a)])
                else:
                    p = np.array([rng.uniform(*self.REGION_X), rng.uniform(*self.REGION_Z)])
                inside = self.REGION_X[0] <= p[0] <= self.REGION_X[1] and self.REGION_Z[0] <= p[1] <= self.REGION_Z[1]
                if inside and (not pts or np.hypot(*(np.array(pts) - p).T).min() >= gap):
                    pts.append(p)
                    break
            else:
                raise SandtrackError("the scattered layout's region is too small for its beads")
        return np.array(pts)

    def _step(self, xz: np.ndarray, t: float) -> np.ndarray:
        tl = self.timeline
        zt = float(tl.tool_z(t))
        moving = tl.tool_start_s <= t < tl.tool_end_s
        out = xz.copy()
        if moving:
            b = self.HALF_WIDTH_MM
            stagnation = self.radius + 2.0  # ahead of the shank's front, where the beads it pushes ride
            xi = xz[:, 0] - TOOL_X
            eta = xz[:, 1] - (zt + stagnation - b / np.pi)
            r2 = np.maximum(xi**2 + eta**2, (b / np.pi) ** 2)
            behind = xz[:, 1] - zt
            fade = np.exp(-((xi / self.REACH_MM) ** 2)) * np.clip((behind + 60.0) / 45.0, 0.0, 1.0)
            k = tl.speed_mm_s * b / np.pi * fade / r2 * self.dt
            out[:, 0] += k * xi
            out[:, 1] += k * eta
        self._separate(out, zt)
        return out

    def _separate(self, xz: np.ndarray, zt: float) -> None:
        """Push overlapping beads apart (a few sweeps) and out of the shank's footprint, in place."""
        gap = 2 * self.radius
        for _ in range(3):
            pairs = cKDTree(xz).query_pairs(gap, output_type="ndarray")
            if len(pairs) == 0:
                break
            d = xz[pairs[:, 1]] - xz[pairs[:, 0]]
            dist = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
            push = 0.5 * (gap - dist)[:, None] * d / dist[:, None]
            np.add.at(xz, pairs[:, 0], -push)
            np.add.at(xz, pairs[:, 1], push)
        xi = xz[:, 0] - TOOL_X
        inside = (np.abs(xi) < SHANK_HALF_X + self.radius) & (xz[:, 1] > zt - SHANK_CHORD - self.radius) & \
            (xz[:, 1] < zt + self.radius)
        xz[inside, 0] = TOOL_X + np.where(xi[inside] >= 0, 1, -1) * (SHANK_HALF_X + self.radius)

    def positions(self, t: float, surface: SurfaceGrid) -> dict[int, np.ndarray]:
        g = float(np.clip((t - self.t0) / self.dt, 0, len(self.track) - 1.000001))
        k = int(g)
        xz = self.track[k] + (g - k) * (self.track[k + 1] - self.track[k])
        zt = float(self.timeline.tool_z(t))
        return {i + 1: np.array([x, surface.height_at(x, z, zt) + self.radius, z]) for i, (x, z) in enumerate(xz)}


LAYOUTS = {"scripted": MarkerScript, "dense": DenseLayer, "scattered": ScatteredLayer}


# -- rendering ------------------------------------------------------------------------------------

def _shake_path(v: Variant, seed: int) -> np.ndarray:
    """Per frame (dx, dy, angle rad) of the image motion: a smooth random shake plus a steady pan."""
    n = frame_count(v)
    out = np.zeros((n, 3))
    if v.shake_px <= 0 and v.pan_px == 0:
        return out
    rng = np.random.default_rng(seed + 41)
    for j, amp in enumerate((v.shake_px, v.shake_px, v.shake_px / 300.0)):
        raw = rng.normal(0, 1, n + 16)
        smooth = np.convolve(raw, np.hanning(7), mode="same")[8:8 + n]
        out[:, j] = amp * smooth / max(smooth.std(), 1e-9)
    out[:, 0] += v.pan_px * (np.arange(n) - n / 2)
    return out


def _affine(shift: np.ndarray, centre: tuple) -> np.ndarray:
    dx, dy, a = shift
    c, s = np.cos(a), np.sin(a)
    cx, cy = centre
    return np.array([[c, -s, cx - c * cx + s * cy + dx], [s, c, cy - s * cx - c * cy + dy]])


def _writer(v: Variant, path: Path, size: tuple):
    if v.output == "mp4":
        from .writer import Mp4Writer

        return Mp4Writer(path.with_suffix(".mp4"), size[0], size[1], FPS, np.zeros(int(0.1 * 48000), np.float32),
                         crf=20)
    return _FolderWriter(path, v.output)


class _FolderWriter:
    def __init__(self, folder: Path, kind: str):
        self.folder, self.kind, self.n = folder, kind, 0
        folder.mkdir(parents=True, exist_ok=True)

    def write(self, img: np.ndarray) -> None:
        if self.kind == "jpeg":
            cv2.imwrite(str(self.folder / f"{self.n:05d}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, 88])
        else:  # a 12-bit grey camera's frames stored in 16-bit TIFF
            grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.uint16) * 16
            cv2.imwrite(str(self.folder / f"{self.n:05d}.tif"), grey)
        self.n += 1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _render_camera(v: Variant, camera: str, seed: int, out: Path) -> list[tuple]:
    shake = _shake_path(v, seed)
    margin = int(np.ceil(np.abs(shake[:, :2]).max() + abs(shake[:, 2]).max() * max(v.size) + 4)) if shake.any() \
        else 0
    cam, _ = window_camera(world_cameras()[camera], v.size, v.zoom, margin, v.layout)
    tone = np.array(SAND_TONES[v.sand], np.float32)
    tex = Textures(seed, sand_bgr=tone)
    view = CameraView(cam, tex, SandShader(tex), seed)
    tl = Timeline(speed_mm_s=v.speed_mm_s)
    surf = SurfaceGrid(seed)
    g3 = np.zeros(surf.H.shape + (3,), np.float32)
    layer = LAYOUTS[v.layout](seed, tl, v.radius_mm)
    style = STYLES[v.style]
    rng = np.random.default_rng(seed + (3 if camera == "side" else 4))
    rows = []
    w, h = v.size
    centre = (margin + w / 2, margin + h / 2)
    with _writer(v, out / "experiment" / camera, v.size) as wr:
        for i in range(frame_count(v)):
            tau = v.start_s + i / FPS
            zt = float(tl.tool_z(tau))
            if surf.zt != zt:
                r, c = surf.set_tool(zt)
                update_g3(surf, g3, r, c)
                view.update_surface(surf, g3, r, c)
            mk = layer.positions(tau, surf)
            img = _exposure(view, v, tl, layer, surf, tau, zt, mk, style)
            img = view.add_noise(img, int(rng.integers(1 << 30)))
            M = None
            if margin:
                M = _affine(shake[i], centre)
                M[:, 2] -= margin
                img = cv2.warpAffine(img, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            wr.write(img)
            others = list(mk.values())
            for k, P in mk.items():
                px = cam.project(P[None])[0]
                if M is not None:
                    px = M[:, :2] @ px + M[:, 2]
                frac = visible_fraction(cam, P, zt, surf, others, radius=v.radius_mm) \
                    if (0 <= px[0] < w and 0 <= px[1] < h) else 0.0
                rows.append((i, k, px[0], px[1], int(frac >= VISIBLE_MIN_FRACTION), round(frac, 4), *P))
    return rows


def _exposure(view, v: Variant, tl: Timeline, layer, surf, tau: float, zt: float, mk: dict, style) -> np.ndarray:
    """The frame at scene time tau: tool and markers drawn on the sand, averaged over the exposure
    (sampled finely enough that a marker moves at most ~1.5 px between samples)."""
    def draw(z, markers):
        img = view.canvas.copy()
        view.draw_tool(img, z, surf)
        view.draw_markers(img, markers, surf, z, radius=v.radius_mm, style=style)
        return img

    if v.shutter <= 0:
        return draw(zt, mk)
    half = 0.5 * v.shutter / FPS
    a, b = layer.positions(tau - half, surf), layer.positions(tau + half, surf)
    cam = view.cam
    disp = max(float(np.hypot(*(cam.project(a[k][None])[0] - cam.project(b[k][None])[0]))) for k in a)
    n = int(np.clip(np.ceil(disp / 1.5) + 1, 2, 24))
    acc = np.zeros(view.canvas.shape, np.float32)
    for j in range(n):
        t = tau - half + 2 * half * j / (n - 1)
        acc += draw(float(tl.tool_z(t)), layer.positions(t, surf))
    return np.clip(np.round(acc / n), 0, 255).astype(np.uint8)


def render_sandbox(v: Variant, out_dir: str | Path, seed: int = 0, log=lambda msg: None) -> dict:
    """Render one sand-box case into out_dir (see the module notes); returns what was written."""
    name = v.name
    out = Path(out_dir)
    t0, c0 = time.perf_counter(), time.process_time()
    import pandas as pd

    try:
        (out / "ground_truth").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SandtrackError(f"cannot create {out}: {exc.strerror or exc}") from None
    cols = ["frame", "marker", "x_px", "y_px", "visible", "visible_fraction", "X_mm", "Y_mm", "Z_mm"]
    for camera in v.cameras:
        log(f"rendering twin variant {name}: {camera} camera, {frame_count(v)} frames")
        rows = _render_camera(v, camera, seed, out)
        pd.DataFrame(rows, columns=cols).to_csv(out / "ground_truth" / f"markers_{camera}.csv", index=False,
                                                float_format="%.4f")
    still = v.shake_px <= 0 and v.pan_px == 0
    if still and len(v.cameras) > 1:
        window_calibration(v).save(out / "ground_truth" / "cameras.toml")
    info = {**asdict(v), "frames": frame_count(v), "seed": seed, "fps": FPS,
            "render_s": round(time.perf_counter() - t0, 1), "render_cpu_s": round(time.process_time() - c0, 1),
            "videos": {c: str(Path("experiment") / (c + ".mp4" if v.output == "mp4" else c)) for c in v.cameras},
            "visible_rule": f"visible = 1 when at least {VISIBLE_MIN_FRACTION:.0%} of the marker's silhouette is "
                            "seen (inside the window, not behind the tool, sand or another marker)"}
    (out / "variant.json").write_text(json.dumps(info, indent=2) + "\n")
    return info
