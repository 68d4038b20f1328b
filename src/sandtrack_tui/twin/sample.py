"""Render the sample project: calibration and experiment videos of both cameras plus exact ground truth.

`render_sample(out_dir, seed, preset)` writes::

    board.toml, README.md
    calibration/side.mp4, calibration/front.mp4, calibration/reference.toml
    experiment/side.mp4, experiment/front.mp4
    ground_truth/cameras.toml, sync.json, markers_side.csv, markers_front.csv, trajectories.csv,
                 tool.csv, calibration_corners_side.csv, calibration_corners_front.csv,
                 calibration_board_poses.csv, scene.json
    dem/particles.csv, dem/differences.json

The videos of each camera are rendered by one worker process (two at a time), H.264 encoding on a thread of
its own; the result only depends on the seed.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import tomli_w

from ..board import BoardSpec
from ..errors import SandtrackError
from .audio import record, scene_sound
from .board_motion import REF_ORIGIN, SHUTTER_S, BoardMotion, BoardRenderer, corner_truth
from .render import CameraView, SandShader, update_g3
from .rig import FPS, HEIGHT, PLACEMENT, WIDTH, true_calibration, world_cameras
from .scene import (
    MARKER_IDS,
    MARKER_RADIUS,
    TOOL_DEPTH,
    TOOL_SPEED,
    TOOL_TRAVEL,
    TOOL_X,
    TOOL_Z0,
    MarkerScript,
    SurfaceGrid,
    Timeline,
    shank_box,
    visible_fraction,
)
from .writer import AUDIO_RATE, Mp4Writer

BOARD = BoardSpec(type="charuco", columns=8, rows=5, square_mm=25.0, dictionary="DICT_4X4_50")
OFFSET_S = 0.4373  # experiment: the front camera started recording this much later than the side camera
CAL_OFFSET_FRAMES = 13  # calibration session: front started 13 frames (0.26 s) later
FRONT_AUDIO_START_S = 0.05  # the front experiment file's audio track starts 50 ms after its video
VISIBLE_MIN_FRACTION = 0.5
DEM_TIME_SHIFT_S = 0.24
REF_FRAME = 20  # calibration frame showing the flat reference pose in both videos
DEM_RATE_HZ = 100.0
DEM_DRIFT_MM_PER_S = {3: (0.0, 0.0, 1.5), 6: (-1.0, 0.0, 0.8)}


@dataclass(frozen=True)
class Preset:
    name: str
    exp_frames: int  # per camera
    exp_start_s: float  # scene time of the side camera's first experiment frame
    cal_frames: int  # per camera
    exp_crf: int = 23
    cal_crf: int = 26


PRESETS = {
    "small": Preset("small", exp_frames=440, exp_start_s=0.0, cal_frames=400),
    "full": Preset("full", exp_frames=440, exp_start_s=0.0, cal_frames=2100),
    # for tests: a few frames around the tool meeting the markers
    "tiny": Preset("tiny", exp_frames=4, exp_start_s=5.3, cal_frames=4),
}


# -- workers ---------------------------------------------------------------------------------------

def _make_view(camera: str, seed: int) -> CameraView:
    from .textures import Textures

    tex = Textures(seed)
    return CameraView(world_cameras()[camera], tex, SandShader(tex), seed)


def _camera_worker(args) -> tuple[dict, dict]:
    """Both videos of one camera: the calibration session first (it needs the untouched sand), then the
    experiment (which digs the furrow into the view's canvas)."""
    camera, seed, preset, cal_path, exp_path = args
    cv2.setNumThreads(1)
    view = _make_view(camera, seed)
    cal = _calibration_worker((camera, seed, preset, cal_path), view)
    exp = _experiment_worker((camera, seed, preset, exp_path), view)
    exp["cpu_s"] = time.process_time()  # this worker process's CPU time (s), for the log
    return exp, cal


def _experiment_worker(args, view: CameraView | None = None) -> dict:
    camera, seed, preset, out_path = args
    cv2.setNumThreads(1)
    pr = PRESETS[preset]
    tl = Timeline()
    cams = world_cameras()
    cam = cams[camera]
    view = view or _make_view(camera, seed)
    surf = SurfaceGrid(seed)
    g3 = np.zeros(surf.H.shape + (3,), np.float32)
    script = MarkerScript(seed, tl)
    rng = np.random.default_rng(seed + (3 if camera == "side" else 4))
    start = pr.exp_start_s + (OFFSET_S if camera == "front" else 0.0)
    n = pr.exp_frames
    scene = scene_sound(seed, start + n / FPS + 2.0, tl.clap_s, tl.tool_start_s, tl.tool_end_s)
    a0 = FRONT_AUDIO_START_S if camera == "front" else 0.0
    audio = record(scene, start + a0, int(round((n / FPS - a0) * AUDIO_RATE)), seed, 0 if camera == "side" else 1)
    rows, traj, tool = [], [], []
    other = cams["front"] if camera == "side" else None
    still = None  # (scene key, drawn frame before noise, visible fractions) of the last frame drawn
    with Mp4Writer(out_path, WIDTH, HEIGHT, FPS, audio, audio_start_s=a0, crf=pr.exp_crf) as w:
        for i in range(n):
            t_file = i / FPS
            tau = start + t_file
            zt = float(tl.tool_z(tau))
            if surf.zt != zt:
                r, c = surf.set_tool(zt)
                update_g3(surf, g3, r, c)
                view.update_surface(surf, g3, r, c)
            mk = script.positions(tau, surf)
            key = (zt, *(mk[mid].tobytes() for mid in MARKER_IDS))
            if still is None or still[0] != key:
                img = view.canvas.copy()
                view.draw_tool(img, zt, surf)
                view.draw_markers(img, mk, surf, zt)
                fracs = {mid: (visible_fraction(cam, mk[mid], zt, surf, mk.values()),
                               None if other is None else visible_fraction(other, mk[mid], zt, surf, mk.values()))
                         for mid in MARKER_IDS}
                still = (key, img, fracs)
            # else: the tool is parked and nothing moves: the same picture and visibility as the frame before
            _, img, fracs = still
            w.write(view.add_noise(img, int(rng.integers(1 << 30))))
            for mid in MARKER_IDS:
                P = mk[mid]
                px = cam.project(P[None])[0]
                frac, frac_o = fracs[mid]
                rows.append((i, t_file, tau, mid, *P, *px, int(frac >= VISIBLE_MIN_FRACTION), frac))
                if other is not None:
                    traj.append((i, t_file, mid, *P, int(frac >= VISIBLE_MIN_FRACTION),
                                 int(frac_o >= VISIBLE_MIN_FRACTION)))
            if camera == "side":
                tool.append((i, t_file, tau, TOOL_X, zt, TOOL_DEPTH,
                             TOOL_SPEED if tl.tool_start_s < tau < tl.tool_end_s else 0.0))
    return {"camera": camera, "rows": rows, "traj": traj, "tool": tool, "frames": n}


def _calibration_worker(args, view: CameraView | None = None, rest_origin=REF_ORIGIN) -> dict:
    """One camera's calibration video; the board lies flat at `rest_origin` (mm, world) at first."""
    camera, seed, preset, out_path = args
    cv2.setNumThreads(1)
    pr = PRESETS[preset]
    tl = Timeline()
    cam = world_cameras()[camera]
    view = view or _make_view(camera, seed)
    motion = BoardMotion(BOARD, seed, rest_origin)
    painter = BoardRenderer(BOARD)
    rng = np.random.default_rng(seed + (5 if camera == "side" else 6))
    start = CAL_OFFSET_FRAMES / FPS if camera == "front" else 0.0
    n = pr.cal_frames
    scene = scene_sound(seed + 1000, start + n / FPS + 2.0, tl.clap_s)
    audio = record(scene, start, int(round(n / FPS * AUDIO_RATE)), seed + 1000, 0 if camera == "side" else 1)
    corners, poses = [], []
    obj = BOARD.corner_points_mm()
    still = None  # (poses key, drawn frame before noise) of the last frame drawn
    with Mp4Writer(out_path, WIDTH, HEIGHT, FPS, audio, crf=pr.cal_crf) as w:
        for i in range(n):
            t_file = i / FPS
            tau = start + t_file
            R, t = motion.pose(tau)
            # motion blur: several poses within the exposure when the board moves fast
            Ra, ta = motion.pose(tau - SHUTTER_S / 2)
            Rb, tb = motion.pose(tau + SHUTTER_S / 2)
            disp = np.abs(cam.project(obj @ Ra.T + ta) - cam.project(obj @ Rb.T + tb)).max()
            k = int(np.clip(np.ceil(disp / 1.5), 1, 7))
            sub = [motion.pose(tau + SHUTTER_S * (j / (k - 1) - 0.5)) for j in range(k)] if k > 1 else [(R, t)]
            key = b"".join(a.tobytes() for pose in sub for a in pose)
            if still is None or still[0] != key:  # else the board has not moved (it lies on the sand at first)
                img = view.canvas.copy()
                painter.draw(view, img, sub)
                still = (key, img)
            w.write(view.add_noise(still[1], int(rng.integers(1 << 30))))
            ids, px, Xw = corner_truth(BOARD, cam, R, t)
            for cid, p, X in zip(ids, px, Xw, strict=True):
                corners.append((i, int(cid), p[0], p[1], *X))
            rvec = cv2.Rodrigues(R)[0].ravel()
            poses.append((camera, i, t_file, tau, *rvec, *t, k, round(float(disp), 3)))
    return {"camera": camera, "corners": corners, "poses": poses, "frames": n}


# -- main ------------------------------------------------------------------------------------------

@contextlib.contextmanager
def _environment(**values: str):
    """Environment variables set for the child processes started inside the block. One BLAS thread per render
    worker: each worker already has a core, and BLAS threads waiting for work would spin on the other one."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def render_sample(out_dir: str | Path, seed: int = 0, preset: str = "small", workers: int = 2,
                  log=lambda msg: None) -> dict:
    if preset == "repose":
        from .repose_sample import render_repose

        return render_repose(out_dir, seed, log)
    if preset not in PRESETS:
        raise SandtrackError(f"unknown preset {preset!r} (small, full or repose)")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise SandtrackError(f"{out} exists and is not a folder")
    try:
        for sub in ("calibration", "experiment", "ground_truth", "dem"):
            (out / sub).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SandtrackError(f"cannot create {out}: {exc.strerror or exc}") from None
    t0 = time.perf_counter()
    jobs = [(cam, seed, preset, str(out / "calibration" / f"{cam}.mp4"), str(out / "experiment" / f"{cam}.mp4"))
            for cam in ("side", "front")]
    log(f"rendering the videos of {len(jobs)} cameras ({preset} preset, seed {seed}) with {workers} worker(s)")
    if workers <= 1:
        results = [_camera_worker(a) for a in jobs]
        _write_dem(out, seed)
    else:
        # spawn, never fork: native thread pools (torch, OpenCV, FFmpeg) are invisible to threading.active_count()
        # and a forked child can hang on a lock one of them held
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx) as ex:
            with _environment(OPENBLAS_NUM_THREADS="1"):  # the workers start on submit and inherit it
                futs = [ex.submit(_camera_worker, a) for a in jobs]
            _write_dem(out, seed)  # meanwhile
            results = []
            for f in as_completed(futs):
                results.append(f.result())
                log(f"  done: {results[-1][0]['camera']} camera after {time.perf_counter() - t0:.0f} s "
                    f"({results[-1][0]['cpu_s']:.0f} s CPU)")
    exp = {r[0]["camera"]: r[0] for r in results}
    cal = {r[1]["camera"]: r[1] for r in results}
    _write_ground_truth(out, seed, preset, exp, cal)
    two_view = _two_view_count(cal)
    _write_readme(out, seed, preset, exp, cal, two_view)
    render_s = time.perf_counter() - t0
    sizes = {str(p.relative_to(out)): p.stat().st_size for p in sorted(out.rglob("*")) if p.is_file()}
    return {
        "out_dir": str(out),
        "preset": preset,
        "seed": seed,
        "render_s": round(render_s, 1),
        "experiment_frames": exp["side"]["frames"],
        "calibration_frames": cal["side"]["frames"],
        "two_view_corner_observations": two_view,
        "offset_s": OFFSET_S,
        "total_bytes": int(sum(sizes.values())),
        "files": sizes,
    }


def two_view_observations(preset: str, seed: int = 0) -> int:
    """Corners seen by both cameras at the same instant over a preset's calibration session (from the
    geometry alone, without rendering)."""
    pr = PRESETS[preset]
    cams = world_cameras()
    motion = BoardMotion(BOARD, seed)
    total = 0
    for i in range(CAL_OFFSET_FRAMES, pr.cal_frames):  # side frame i and front frame i - offset
        R, t = motion.pose(i / FPS)
        ids_s = corner_truth(BOARD, cams["side"], R, t)[0]
        ids_f = corner_truth(BOARD, cams["front"], R, t)[0]
        total += len(np.intersect1d(ids_s, ids_f))
    return total


def _two_view_count(cal) -> int:
    import pandas as pd  # not needed by the render workers
    side = pd.DataFrame(cal["side"]["corners"], columns=["frame", "corner_id", "x", "y", "X", "Y", "Z"])
    front = pd.DataFrame(cal["front"]["corners"], columns=["frame", "corner_id", "x", "y", "X", "Y", "Z"])
    front = front.assign(frame=front["frame"] + CAL_OFFSET_FRAMES)  # same instant as that side frame
    return int(len(side.merge(front, on=["frame", "corner_id"])))


def _write_ground_truth(out: Path, seed: int, preset: str, exp: dict, cal: dict) -> None:
    import pandas as pd  # not needed by the render workers
    gt = out / "ground_truth"
    tl = Timeline()
    pr = PRESETS[preset]
    BOARD.save(out / "board.toml")
    calib = true_calibration()
    calib.report = {"source": "sandtrack sample: true rig (ground truth)", "seed": seed}
    calib.save(gt / "cameras.toml")
    mcols = ["frame", "time_s", "scene_time_s", "marker", "X_mm", "Y_mm", "Z_mm", "x_px", "y_px", "visible",
             "visible_fraction"]
    for cam in ("side", "front"):
        df = pd.DataFrame(exp[cam]["rows"], columns=mcols)
        df.to_csv(gt / f"markers_{cam}.csv", index=False, float_format="%.4f")
    traj = pd.DataFrame(exp["side"]["traj"], columns=["frame", "time_s", "marker", "X_mm", "Y_mm", "Z_mm",
                                                      "visible_side", "visible_front"])
    traj.to_csv(gt / "trajectories.csv", index=False, float_format="%.4f")
    tool = pd.DataFrame(exp["side"]["tool"], columns=["frame", "time_s", "scene_time_s", "tool_X_mm", "tool_Z_mm",
                                                      "depth_mm", "speed_mm_s"])
    tool.to_csv(gt / "tool.csv", index=False, float_format="%.4f")
    ccols = ["frame", "corner_id", "x_px", "y_px", "X_mm", "Y_mm", "Z_mm"]
    for cam in ("side", "front"):
        pd.DataFrame(cal[cam]["corners"], columns=ccols).to_csv(
            gt / f"calibration_corners_{cam}.csv", index=False, float_format="%.4f")
    poses = pd.DataFrame(cal["side"]["poses"] + cal["front"]["poses"],
                         columns=["camera", "frame", "time_s", "scene_time_s", "rx", "ry", "rz", "tx_mm", "ty_mm",
                                  "tz_mm", "blur_samples", "blur_px"])
    poses.to_csv(gt / "calibration_board_poses.csv", index=False, float_format="%.6f")
    ref_frame = REF_FRAME
    (out / "calibration" / "reference.toml").write_text(tomli_w.dumps({
        "frame": ref_frame,
        "origin_mm": [float(v) for v in REF_ORIGIN],
        "board_axes_in_world": {"x": [1.0, 0.0, 0.0], "y": [0.0, 0.0, 1.0], "z": [0.0, -1.0, 0.0]},
        "note": "In this frame of both calibration videos the board lies flat on the sand (it stays there for "
                "the first 1.6 s of the session). World = board frame rotated so that board x -> world +X, "
                "board y -> world +Z, board z -> world -Y, with the board origin at origin_mm.",
    }))
    sync = {
        "offset_s": OFFSET_S,
        "fps": FPS,
        "convention": "front started offset_s later than side: an event at side time t appears at front time "
                      "t - offset_s",
        "clap_time_side_s": tl.clap_s - pr.exp_start_s,
        "clap_time_front_s": tl.clap_s - pr.exp_start_s - OFFSET_S,
        "scene_time_of_side_start_s": pr.exp_start_s,
        "front_audio_start_s": FRONT_AUDIO_START_S,
        "side_audio_start_s": 0.0,
        "acoustic_delay_s": 0.0,
        "audio_rate_hz": AUDIO_RATE,
        "calibration": {
            "offset_s": CAL_OFFSET_FRAMES / FPS,
            "offset_frames": CAL_OFFSET_FRAMES,
            "clap_time_side_s": tl.clap_s,
            "clap_time_front_s": tl.clap_s - CAL_OFFSET_FRAMES / FPS,
        },
    }
    (gt / "sync.json").write_text(json.dumps(sync, indent=2) + "\n")
    scene = {
        "seed": seed,
        "preset": preset,
        "box_mm": {"X": 500.0, "Y": 500.0, "Z": 1500.0},
        "sand_surface_Y_mm": 240.0,
        "world_origin": "inner corner of the box at floor level; X across, Y up, Z along the tool's travel",
        "camera_centres_world_mm": {k: list(v["center"]) for k, v in PLACEMENT.items()},
        "tool": {"path_X_mm": TOOL_X, "start_Z_mm": TOOL_Z0, "travel_mm": TOOL_TRAVEL, "speed_mm_s": TOOL_SPEED,
                 "depth_mm": TOOL_DEPTH, "start_scene_s": tl.tool_start_s, "end_scene_s": tl.tool_end_s,
                 "shank_box_at_Z0": shank_box(TOOL_Z0).tolist()},
        "marker_radius_mm": MARKER_RADIUS,
        "visible_rule": f"visible = 1 when at least {VISIBLE_MIN_FRACTION:.0%} of the marker's silhouette is seen "
                        "(inside the image, not behind the tool, not under or behind sand)",
        "board_reference_origin_mm": [float(v) for v in REF_ORIGIN],
    }
    (gt / "scene.json").write_text(json.dumps(scene, indent=2) + "\n")


def _write_readme(out: Path, seed: int, preset: str, exp: dict, cal: dict, two_view: int) -> None:
    from .readme import readme_text

    tl = Timeline()
    pr = PRESETS[preset]
    drift = ", ".join(f"{k}: {list(v)} mm/s" for k, v in DEM_DRIFT_MM_PER_S.items())
    text = readme_text(
        out_name=out.name, seed=seed, preset=preset, tool_depth=TOOL_DEPTH, tool_x=TOOL_X, tool_speed=TOOL_SPEED,
        tool_travel=TOOL_TRAVEL, tool_z0=TOOL_Z0, tool_z1=TOOL_Z0 + TOOL_TRAVEL, tool_start=tl.tool_start_s,
        tool_end=tl.tool_end_s, fps=FPS, cal_frames=cal["side"]["frames"], exp_frames=exp["side"]["frames"],
        dem_rate=DEM_RATE_HZ, offset=OFFSET_S, clap_side=tl.clap_s - pr.exp_start_s,
        clap_front=tl.clap_s - pr.exp_start_s - OFFSET_S, front_audio=FRONT_AUDIO_START_S,
        cal_offset_frames=CAL_OFFSET_FRAMES, cal_offset=CAL_OFFSET_FRAMES / FPS, clap_side_cal=tl.clap_s,
        ref_frame=REF_FRAME, ref_origin=[float(v) for v in REF_ORIGIN], dem_shift=DEM_TIME_SHIFT_S,
        drifting=", ".join(str(k) for k in DEM_DRIFT_MM_PER_S), drift_text=drift, two_view=two_view,
    )
    (out / "README.md").write_text(text)


def _write_dem(out: Path, seed: int) -> None:
    import pandas as pd  # not needed by the render workers
    tl = Timeline()
    script = MarkerScript(seed, tl)
    surf = SurfaceGrid(seed)
    t_dem = np.arange(0.0, TOOL_TRAVEL / TOOL_SPEED + 0.5 + 1e-9, 1.0 / DEM_RATE_HZ)
    pos = script.positions_over(tl.tool_start_s + t_dem - DEM_TIME_SHIFT_S, surf)
    parts = []
    for mid in MARKER_IDS:
        p = pos[mid] + np.outer(t_dem, DEM_DRIFT_MM_PER_S.get(mid, (0.0, 0.0, 0.0)))
        parts.append(pd.DataFrame({"particle_id": mid, "time_s": np.round(t_dem, 6), "x": p[:, 0], "y": p[:, 1],
                                   "z": p[:, 2]}))
    df = pd.concat(parts, ignore_index=True).sort_values(["particle_id", "time_s"])
    df.to_csv(out / "dem" / "particles.csv", index=False, float_format="%.4f")
    diff = {
        "time_shift_s": DEM_TIME_SHIFT_S,
        "time_origin": "time_s = 0 when the tool starts moving (scene time "
                       f"{tl.tool_start_s} s = side experiment time {tl.tool_start_s} s)",
        "relation": "dem(t) = truth(t - time_shift_s) + drift_mm_per_s * t, t = DEM time_s; truth(t) = "
                    "ground_truth/trajectories.csv position at side time tool_start_s + t",
        "tool_start_side_time_s": tl.tool_start_s,
        "drift_mm_per_s": {str(k): list(v) for k, v in DEM_DRIFT_MM_PER_S.items()},
        "drifting_particles": sorted(DEM_DRIFT_MM_PER_S),
        "exact_particles": [m for m in MARKER_IDS if m not in DEM_DRIFT_MM_PER_S],
        "rate_hz": DEM_RATE_HZ,
        "units": "mm, s; x, y, z = world X, Y, Z (same origin and axes as ground_truth)",
    }
    (out / "dem" / "differences.json").write_text(json.dumps(diff, indent=2) + "\n")


def preset_names() -> list[str]:
    return list(PRESETS)


def describe_preset(name: str) -> dict:
    return asdict(PRESETS[name])
