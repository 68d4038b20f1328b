"""`sandtrack sample OUT --preset repose`: heaps of known angle, photographed and as DEM particle files.

Writes under OUT/repose/ (see `README` below, also written there) and OUT/ground_truth/repose.json:
a list of ``{"file": path relative to OUT, "angle_deg": true angle, ...}`` (flank angles, the
camera file, the settling curve for the video). The photos are taken with the study's side camera
(GoPro intrinsics, 1920 x 1080) on a tripod, level, at the heaps' mid-height; lighting and backdrop
change from photo to photo. Deterministic for a seed.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np

from ..camera import Calibration
from ..errors import SandtrackError
from .heap import Heap, Shot, render_heap
from .heap_particles import DT_S, heap_particles, write_exchange_csv, write_liggghts_dump

LEVEL = dict(distance_mm=450.0, camera_height_mm=50.0, target_height_mm=50.0)
HIGH = dict(distance_mm=420.0, camera_height_mm=170.0, target_height_mm=35.0)
LIGHT_GREY, DARK, BLUE_GREY = (0.74, 0.75, 0.76), (0.06, 0.06, 0.07), (0.55, 0.47, 0.40)
# (angle, backdrop colour, backdrop distance behind the axis, lamp position): lamp low at the left with a
# long shadow, in front, near the camera with the shadow on a close backdrop, high, behind, at the right
PHOTOS = [
    (25.0, LIGHT_GREY, -300.0, (-600.0, 250.0, 300.0)),
    (28.0, DARK, -200.0, (-200.0, 300.0, 600.0)),
    (31.0, LIGHT_GREY, -130.0, (260.0, 140.0, 520.0)),
    (34.0, BLUE_GREY, -250.0, (-100.0, 700.0, 250.0)),
    (37.0, LIGHT_GREY, -600.0, (-250.0, 300.0, -400.0)),
    (40.0, DARK, -200.0, (500.0, 350.0, 300.0)),
]
ASYM = (29.0, 37.0)
SETTLE = (41.0, 33.0, 0.5, 2.5, 4.0)  # from angle, to angle, start (s), end (s), duration (s)
VIDEO_FPS = 10.0
JPEG_QUALITY = 92

README = """# Heaps of known angle of repose (rendered)

Rendered by `sandtrack sample OUT --preset repose --seed {seed}`. True angles in `../ground_truth/repose.json`.

- `heap_01.jpg` ... `heap_06.jpg`: side photos of heaps of {angles} deg (1920 x 1080, the study's side
  camera, level, {dist:.0f} mm from the heap's axis at {height:.0f} mm above the plate: `camera.toml`).
  Each photo has its own lamp (low at the side, in front, near the camera casting the heap's shadow
  on a close backdrop, high, behind) and backdrop (light grey, black, blue-grey).
- `heap_asym.jpg`: a heap whose left flank stands at {al} deg and right flank at {ar} deg.
- `heap_high.jpg`: the {high_angle} deg heap seen from above ({hh:.0f} mm high, looking down at the axis):
  perspective changes the angles seen in the image; `camera_high.toml` corrects it
  (`sandtrack repose heap_high.jpg --calibration camera_high.toml`).
- `heap_NN.liggghts`, `heap_asym.liggghts`, `heap_high.liggghts`: the same heaps as DEM particles
  (LIGGGHTS `dump custom`: id type x y z vx vy vz radius, metres, z up; 5 mm spheres with a 20 %
  spread of radii, a loose random packing, a few particles rolled off onto the plate);
  `heap_NN.csv`: the same particles as exchange CSVs (particle_id, time_s, x, y, z; metres).
- `settling.mp4` ({fps:g} fps, 960 x 540) and `settling.liggghts` (one step per 0.5 s, DEM time step
  {dt:g} s): a heap settling from {s0} to {s1} deg between {t0} and {t1} s, still afterwards.
- Frame: origin on the plate at the heap's axis, Y up, X to the right in the photos, Z towards the
  camera (dumps: x = X, y = -Z, z = Y).
"""


def _angles(seed: int) -> list[float]:
    rng = np.random.default_rng(seed + 4321)
    return [round(a + (rng.uniform(-0.5, 0.5) if seed else 0.0), 3) for a, *_ in PHOTOS]


def _heap(angle_l: float, angle_r: float | None = None, seed: int = 0, height: float = 75.0) -> Heap:
    return Heap(height_mm=height, angle_left_deg=angle_l, angle_right_deg=angle_l if angle_r is None else angle_r,
                rough_seed=seed)


def _settle_angle(t: np.ndarray) -> np.ndarray:
    a0, a1, t0, t1, _ = SETTLE
    u = np.clip((np.asarray(t, float) - t0) / (t1 - t0), 0.0, 1.0)
    return a1 + (a0 - a1) * 0.5 * (1 + np.cos(np.pi * u))


def _camera_file(path: Path, shot: Shot) -> None:
    cam = shot.camera()
    world_from_rig = np.eye(4)
    world_from_rig[:3, :3] = cam.R.T
    world_from_rig[:3, 3] = cam.center_mm
    from ..camera import Camera

    rig_cam = Camera(cam.name, cam.width, cam.height, cam.matrix, cam.distortion)
    Calibration({cam.name: rig_cam}, world_from_rig,
                report={"source": "sandtrack sample --preset repose: true camera (ground truth)",
                        "world": "origin on the plate at the heap's axis, Y up"}).save(path)


def _dump(path: Path, heap: Heap, seed: int, diameter: float) -> tuple[np.ndarray, np.ndarray]:
    P, rad = heap_particles(heap, seed=seed, diameter_mm=diameter)
    write_liggghts_dump(path, [(200000, P, rad)])
    return P, rad


def _mean_slice_angle(heap: Heap) -> float:
    """What the mean over radial slices should find: the flank angle averaged over the azimuth."""
    phi = (np.arange(3600) + 0.5) * (2 * np.pi / 3600)
    return float(np.degrees(np.arctan(heap.slope(np.cos(phi)))).mean())


def render_repose(out_dir: str | Path, seed: int = 0, log=lambda msg: None, quick: bool = False) -> dict:
    """Render the preset; `quick`: the same files small and coarse (tests of the file layout)."""
    from .textures import Textures
    from .writer import AUDIO_RATE, Mp4Writer

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise SandtrackError(f"{out} exists and is not a folder")
    rep, gt = out / "repose", out / "ground_truth"
    try:
        rep.mkdir(parents=True, exist_ok=True)
        gt.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SandtrackError(f"cannot create {out}: {exc.strerror or exc}") from None
    t0 = time.perf_counter()
    tex = Textures(seed)
    truth: list[dict] = []
    size = dict(width=480, height=270) if quick else {}
    diameter = 9.0 if quick else 5.0
    level = Shot(**LEVEL, **size)
    _camera_file(rep / "camera.toml", level)
    from .rig import pixel_rays

    level_rays = pixel_rays(level.camera())  # one tripod position for every level photo
    angles = _angles(seed)
    for k, ((_, backdrop, back_z, lamp), angle) in enumerate(zip(PHOTOS, angles, strict=True)):
        heap = _heap(angle, seed=seed + k)
        shot = Shot(**LEVEL, **size, backdrop_bgr=backdrop, backdrop_z_mm=back_z, lamp_mm=lamp)
        name = f"heap_{k + 1:02d}"
        cv2.imwrite(str(rep / f"{name}.jpg"), render_heap(heap, shot, seed + k, tex, level_rays),
                    [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        P, _ = _dump(rep / f"{name}.liggghts", heap, seed + k, diameter)
        write_exchange_csv(rep / f"{name}.csv", 2.0, P)
        truth += [{"file": f"repose/{name}.jpg", "angle_deg": angle, "angle_left_deg": angle,
                   "angle_right_deg": angle, "kind": "photo", "camera": "repose/camera.toml"},
                  {"file": f"repose/{name}.liggghts", "angle_deg": angle, "kind": "dump"},
                  {"file": f"repose/{name}.csv", "angle_deg": angle, "kind": "csv"}]
        log(f"  {name}: {angle:g} deg ({time.perf_counter() - t0:.0f} s)")
    heap = _heap(*ASYM, seed=seed + 10)
    asym = Shot(**LEVEL, **size, lamp_mm=(-350.0, 450.0, 450.0))
    cv2.imwrite(str(rep / "heap_asym.jpg"), render_heap(heap, asym, seed + 10, tex, level_rays),
                [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    _dump(rep / "heap_asym.liggghts", heap, seed + 10, diameter)
    truth += [{"file": "repose/heap_asym.jpg", "angle_deg": heap.angle_deg, "angle_left_deg": ASYM[0],
               "angle_right_deg": ASYM[1], "kind": "photo", "camera": "repose/camera.toml"},
              {"file": "repose/heap_asym.liggghts", "angle_deg": _mean_slice_angle(heap), "angle_left_deg": ASYM[0],
               "angle_right_deg": ASYM[1], "kind": "dump",
               "note": "angle_deg: the flank angle averaged over the azimuth (what the mean of radial slices finds)"}]
    high_angle = angles[3]
    heap = _heap(high_angle, seed=seed + 3)
    high = Shot(**HIGH, **size, lamp_mm=(-300.0, 500.0, 400.0))
    _camera_file(rep / "camera_high.toml", high)
    cv2.imwrite(str(rep / "heap_high.jpg"), render_heap(heap, high, seed + 11, tex),
                [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    truth.append({"file": "repose/heap_high.jpg", "angle_deg": high_angle, "angle_left_deg": high_angle,
                  "angle_right_deg": high_angle, "kind": "photo", "camera": "repose/camera_high.toml",
                  "note": "seen from above: measure with the camera file"})
    log(f"  photos and dumps done ({time.perf_counter() - t0:.0f} s); settling video")
    # the settling heap: video and multi-step dump
    a0, a1, ts0, ts1, duration = SETTLE
    vshot = Shot(**LEVEL, width=240 if quick else 960, height=136 if quick else 540, backdrop_bgr=LIGHT_GREY,
                 lamp_mm=(-400.0, 380.0, 420.0))
    rays = pixel_rays(vshot.camera())
    n = 4 if quick else int(round(duration * VIDEO_FPS))
    times = np.arange(n) / VIDEO_FPS
    silent = np.zeros(int(duration * AUDIO_RATE), np.float32)

    def settle_height(angle: float) -> float:  # the same volume (cone: height^3 / tan^2) at every angle
        return 75.0 * (np.tan(np.radians(angle)) / np.tan(np.radians(a1))) ** (2 / 3)

    still = None
    with Mp4Writer(rep / "settling.mp4", vshot.width, vshot.height, VIDEO_FPS, silent, crf=20) as w:
        for i, t in enumerate(times):
            ang = float(_settle_angle(t))
            key = round(ang, 9)
            if still is None or still[0] != key:
                still = (key, render_heap(_heap(ang, seed=seed + 20, height=settle_height(ang)), vshot, seed + 20,
                                          tex, rays))
            noise = np.random.default_rng(seed + 1000 + i).normal(0.0, 1.5, still[1].shape)
            w.write(np.clip(still[1] + noise, 0, 255).astype(np.uint8))
    steps = []
    for k, t in enumerate(np.arange(0.0, duration + 1e-9, 0.5)):
        ang = float(_settle_angle(t))
        P, rad = heap_particles(_heap(ang, height=settle_height(ang)), seed=seed + 30 + k, diameter_mm=diameter)
        steps.append((int(round(t / DT_S)), P, rad))
    write_liggghts_dump(rep / "settling.liggghts", steps)
    curve = [[round(float(t), 3), round(float(_settle_angle(t)), 4)] for t in times]
    truth += [{"file": "repose/settling.mp4", "angle_deg": a1, "settled_from_s": ts1, "angle_over_time": curve,
               "kind": "video", "camera": None},
              {"file": "repose/settling.liggghts", "angle_deg": a1, "settled_from_s": ts1, "dt_s": DT_S,
               "angle_over_time": [[round(s * DT_S, 3), round(float(_settle_angle(s * DT_S)), 4)]
                                   for s, _, _ in steps], "kind": "dump"}]
    (gt / "repose.json").write_text(json.dumps(truth, indent=1) + "\n")
    (rep / "README.md").write_text(README.format(
        seed=seed, angles=", ".join(f"{a:g}" for a in angles), dist=LEVEL["distance_mm"],
        height=LEVEL["camera_height_mm"], al=ASYM[0], ar=ASYM[1], high_angle=f"{high_angle:g}",
        hh=HIGH["camera_height_mm"], fps=VIDEO_FPS, dt=DT_S, s0=a0, s1=a1, t0=ts0, t1=ts1))
    sizes = {str(p.relative_to(out)): p.stat().st_size for p in sorted(rep.rglob("*")) if p.is_file()}
    sizes["ground_truth/repose.json"] = (gt / "repose.json").stat().st_size
    return {"out_dir": str(out), "preset": "repose", "seed": seed, "render_s": round(time.perf_counter() - t0, 1),
            "heaps": len(truth), "total_bytes": int(sum(sizes.values())), "files": sizes}
