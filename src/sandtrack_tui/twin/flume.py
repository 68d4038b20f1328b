"""The bedload flume twin: a quasi-2D backlit channel of glass beads seen side-on, with exact truth.

A camera looks through the glass wall of a narrow, tilted channel lit from behind: a packed bed of
~6 mm black glass beads (each dark with a small bright centre, where the backlight passes through the
glass), water flowing over it, beads rolling on the bed and hopping over it (saltation), the bed
creeping, beads entering the view upstream and leaving it downstream. The beads are simulated
(flume_physics.py: a DEM with drag, lift and gravity in water) and drawn (flume_optics.py).

`render_flume(Flume(...), out_dir)` writes ``experiment/side/`` (a folder of 16-bit grey TIFF frames,
12-bit data, or 8-bit grey PNG), ``ground_truth/markers_side.csv`` and ``variant.json``. Every bead
that shows in the frame has a row per frame: frame, marker, x_px, y_px (its centre at mid-exposure),
visible (visible_fraction >= 0.5), visible_fraction (the share of its silhouette inside the frame and
not behind a bead nearer the camera), X_mm, Y_mm, Z_mm (its centre: downstream from the view's left
edge, up from the channel floor, across from the front wall), state (resting, rolling or saltating),
vx_px, vy_px (px per frame at mid-exposure) and diameter_px. A bead gets a new marker id each time it
enters the view from upstream (the channel is periodic, out of view: a bead that comes round again
is, to the camera, a new bead). Deterministic for a seed.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..errors import SandtrackError
from .flume_optics import BeadLook, Optics, SideCamera, apply_bead, backlight, lamp, sensor
from .flume_physics import FlumePhysics, FlumeRun, simulate

VISIBLE_MIN_FRACTION = 0.5
ROLLING_PX = 0.5  # px per frame: a bead in contact and slower than this is resting (the bed creeps slower)
CAMERA = "side"


@dataclass(frozen=True)
class Flume:
    name: str = "flume"
    size: tuple = (1280, 320)  # px
    px_per_mm: float = 4.0  # at the channel's mid-plane: 6 mm beads are 24 px
    fps: float = 130.0
    frames: int = 300
    floor_mm: float = 4.0  # height of the view's bottom edge above the channel floor
    domain: float = 1.5  # the periodic channel's length, in view widths
    output: str = "tiff16"  # "tiff16" (12-bit data in 16-bit TIFF) | "png8"
    physics: FlumePhysics = field(default_factory=FlumePhysics)
    optics: Optics = field(default_factory=Optics)
    cameras: tuple = (CAMERA,)
    note: str = "a bedload flume of glass beads"

    @property
    def view_mm(self) -> tuple[float, float]:
        return self.size[0] / self.px_per_mm, self.size[1] / self.px_per_mm

    @property
    def length_mm(self) -> float:
        return self.domain * self.view_mm[0]


def flume_camera(spec: Flume) -> SideCamera:
    x0 = (spec.length_mm - spec.view_mm[0]) / 2
    return SideCamera(spec.size, spec.px_per_mm, x0, spec.floor_mm, spec.physics.channel_mm, spec.optics.camera_mm)


# -- truth ----------------------------------------------------------------------------------------

_K = np.arange(256) + 0.5
_DISC = np.stack([np.sqrt(_K / 256) * np.cos(_K * np.pi * (3 - np.sqrt(5))),
                  np.sqrt(_K / 256) * np.sin(_K * np.pi * (3 - np.sqrt(5)))], axis=1)  # equal-area points


def visible_fractions(u: np.ndarray, v: np.ndarray, r: np.ndarray, depth: np.ndarray, size: tuple) -> np.ndarray:
    """Per bead (projected centres u, v, radii r px, distance from the camera), the share of its
    silhouette inside the frame and not covered by the silhouette of a bead nearer the camera."""
    w, h = size
    out = np.zeros(len(u))
    tree = cKDTree(np.c_[u, v])
    reach = 2 * float(r.max()) if len(r) else 0.0
    for i in range(len(u)):
        pts = np.c_[u[i] + r[i] * _DISC[:, 0], v[i] + r[i] * _DISC[:, 1]]
        ok = (pts[:, 0] >= -0.5) & (pts[:, 0] <= w - 0.5) & (pts[:, 1] >= -0.5) & (pts[:, 1] <= h - 0.5)
        if not ok.any():
            continue
        for j in tree.query_ball_point((u[i], v[i]), reach):
            if j != i and depth[j] < depth[i] and np.hypot(u[j] - u[i], v[j] - v[i]) < r[i] + r[j]:
                ok &= (pts[:, 0] - u[j]) ** 2 + (pts[:, 1] - v[j]) ** 2 > r[j] ** 2
        out[i] = ok.mean()
    return out


class MarkerIds:
    """A marker id per pass of a bead through the view: a bead coming round the periodic channel
    again is a new marker; ids are given in order of appearance (left to right within a frame)."""

    def __init__(self):
        self.ids: dict[tuple[int, int], int] = {}

    def __call__(self, beads: np.ndarray, wraps: np.ndarray, order: np.ndarray) -> np.ndarray:
        out = np.zeros(len(beads), np.int64)
        for k in np.argsort(order, kind="stable"):
            key = (int(beads[k]), int(wraps[k]))
            if key not in self.ids:
                self.ids[key] = len(self.ids) + 1
            out[k] = self.ids[key]
        return out


def frame_truth(run: FlumeRun, f: int, cam: SideCamera, spec: Flume, ids: MarkerIds) -> dict:
    """The truth rows of frame f (as columns), for the beads whose silhouette reaches into the frame."""
    P = run.pos[f, run.mid]
    u, v, r = cam.project(P, run.radius)
    w, h = spec.size
    show = (u + r > -0.5) & (u - r < w - 0.5) & (v + r > -0.5) & (v - r < h - 0.5)
    idx = np.nonzero(show)[0]
    depth = P[idx, 2] - cam.centre[2]
    frac = visible_fractions(u[idx], v[idx], r[idx], depth, spec.size)
    vx, vy = cam.velocity(P[idx], run.vel[f, idx], spec.fps)
    speed = np.hypot(vx, vy)
    free = run.contact_steps[f, idx] == 0
    state = np.where(~run.mobile[idx], "resting", np.where(free, "saltating",
                                                             np.where(speed >= ROLLING_PX, "rolling", "resting")))
    x0 = cam.centre[0] - spec.view_mm[0] / 2
    return {"frame": np.full(len(idx), f), "marker": ids(idx, run.wraps[f, idx], u[idx]),
            "x_px": u[idx], "y_px": v[idx], "visible": (frac >= VISIBLE_MIN_FRACTION).astype(int),
            "visible_fraction": np.round(frac, 4), "X_mm": P[idx, 0] - x0, "Y_mm": P[idx, 1], "Z_mm": P[idx, 2],
            "state": state, "vx_px": vx, "vy_px": vy, "diameter_px": 2 * r[idx]}


# -- pictures -------------------------------------------------------------------------------------

class FlumeCamera:
    """Draws the frames of a simulated run."""

    def __init__(self, spec: Flume, run: FlumeRun, seed: int):
        self.spec, self.run = spec, run
        self.cam = flume_camera(spec)
        rng = np.random.default_rng(seed + 307)
        self.look = BeadLook.draw(len(run.radius), rng)
        w, h = spec.size
        self.light = backlight(spec.size, spec.optics, rng)
        self.gain = 1 + spec.optics.prnu * rng.standard_normal((h, w))
        self.phase = float(rng.uniform(0, 2 * np.pi))
        self.noise = np.random.default_rng(seed + 311)

    def _blur(self, z: np.ndarray) -> np.ndarray:
        o = self.spec.optics
        return o.defocus_px + o.defocus_per_mm * np.abs(z - self.cam.mid_z)

    def transmission(self, f: int) -> np.ndarray:
        """The beads' transmission (H x W) over frame f's exposure."""
        run, cam, look = self.run, self.cam, self.look
        w, h = self.spec.size
        P = run.pos[f]  # (S, N, 3)
        u, v, r = cam.project(P, run.radius[None, :])
        blur = self._blur(P[..., 2])
        near = (u + r + 6 > 0) & (u - r - 6 < w) & (v + r + 6 > 0) & (v - r - 6 < h)
        shown = np.nonzero(near.any(axis=0))[0]
        m = run.mid
        moved = np.hypot(u[:, shown] - u[m, shown], v[:, shown] - v[m, shown]).max(axis=0)
        still = np.ones((h, w))
        moving = []
        for k, i in enumerate(shown):
            if moved[k] < 0.02:
                apply_bead(still, u[m, i], v[m, i], r[m, i], blur[m, i], look.body[i], look.spot[i],
                           look.spot_size[i])
            else:
                moving.append(i)
        if not moving:
            return still
        acc = np.zeros((h, w))
        for s in range(P.shape[0]):
            t = np.ones((h, w))
            for i in moving:
                apply_bead(t, u[s, i], v[s, i], r[s, i], blur[s, i], look.body[i], look.spot[i], look.spot_size[i])
            acc += t
        return still * acc / P.shape[0]

    def frame(self, f: int) -> np.ndarray:
        """Frame f as the sensor's digital numbers."""
        o = self.spec.optics
        t0 = f / self.spec.fps - o.exposure_s / 2
        light = self.light * lamp(t0, o, self.phase) * self.transmission(f)
        return sensor(light, o, self.gain, self.noise)


class _Frames:
    def __init__(self, folder: Path, spec: Flume):
        self.folder, self.spec, self.n = folder, spec, 0
        folder.mkdir(parents=True, exist_ok=True)

    def write(self, dn: np.ndarray) -> None:
        bits = self.spec.optics.bits
        if self.spec.output == "png8":  # the camera's 8-bit mode: the top 8 bits
            cv2.imwrite(str(self.folder / f"{self.n:05d}.png"), (dn >> (bits - 8)).astype(np.uint8))
        else:  # 12-bit data in 16-bit TIFF, scaled to the 16-bit range as cameras store it
            cv2.imwrite(str(self.folder / f"{self.n:05d}.tif"), (dn.astype(np.uint16) << (16 - bits)))
        self.n += 1


# -- the whole render ------------------------------------------------------------------------------

def render_flume(spec: Flume, out_dir: str | Path, seed: int = 0, log=lambda msg: None) -> dict:
    """Simulate and draw the flume into out_dir (see the module notes); returns what was written."""
    import pandas as pd

    if spec.output not in ("tiff16", "png8"):
        raise SandtrackError(f"flume output must be tiff16 or png8, not {spec.output!r}")
    out = Path(out_dir)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        (out / "ground_truth").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SandtrackError(f"cannot create {out}: {exc.strerror or exc}") from None
    o = spec.optics
    log(f"rendering twin variant {spec.name}: simulating the beads ({spec.frames} frames)")
    run = simulate(spec.physics, spec.length_mm, spec.frames, spec.fps, o.exposure_s, o.samples, seed, log=log)
    sim_cpu = time.process_time() - c0
    log(f"rendering twin variant {spec.name}: drawing {spec.frames} frames")
    camera = FlumeCamera(spec, run, seed)
    ids = MarkerIds()
    rows = []
    frames = _Frames(out / "experiment" / CAMERA, spec)
    for f in range(spec.frames):
        frames.write(camera.frame(f))
        rows.append(pd.DataFrame(frame_truth(run, f, camera.cam, spec, ids)))
    truth = pd.concat(rows, ignore_index=True)
    truth.to_csv(out / "ground_truth" / f"markers_{CAMERA}.csv", index=False, float_format="%.4f")
    info = {**asdict(spec), "frames": spec.frames, "seed": seed, "fps": spec.fps,
            "render_s": round(time.perf_counter() - t0, 1), "render_cpu_s": round(time.process_time() - c0, 1),
            "simulation_cpu_s": round(sim_cpu, 1), "steps_per_frame": run.steps_per_frame,
            "videos": {CAMERA: str(Path("experiment") / CAMERA)}, "scale_px_per_mm": spec.px_per_mm,
            "beads_simulated": int(run.mobile.sum()), "beads_glued": int((~run.mobile).sum()),
            **summary(truth),
            "visible_rule": f"visible = 1 when at least {VISIBLE_MIN_FRACTION:.0%} of the bead's silhouette is seen "
                            "(inside the frame, not behind a bead nearer the camera)",
            "state_rule": f"saltating: touched no bead nor the floor during the frame's {run.steps_per_frame} steps; "
                          f"rolling: in contact and moving at least {ROLLING_PX} px per frame; else resting"}
    (out / "variant.json").write_text(json.dumps(info, indent=2) + "\n")
    return info


def summary(truth) -> dict:
    """Figures of a flume render's truth: beads per frame, how many move, how fast, how many ids."""
    per_frame = truth.groupby("frame")
    speed = np.hypot(truth.vx_px, truth.vy_px)
    return {"markers": int(truth.marker.nunique()),
            "beads_per_frame": round(float(per_frame.size().mean()), 1),
            "visible_per_frame": round(float(per_frame.visible.sum().mean()), 1),
            "rolling_per_frame": round(float((truth.state == "rolling").groupby(truth.frame).sum().mean()), 1),
            "saltating_per_frame": round(float((truth.state == "saltating").groupby(truth.frame).sum().mean()), 1),
            "speed_px_per_frame_p99": round(float(np.percentile(speed, 99)), 1) if len(speed) else 0.0,
            "speed_px_per_frame_max": round(float(speed.max()), 1) if len(speed) else 0.0}
