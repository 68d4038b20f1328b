"""The tracker on real footage recorded by others: honesty (what it reports `tracked` is right).

../shared/data/caliscope_4cam: four real webcams (1280 x 720, 48 frames each at ~6 fps) filming a
hand-held ChArUco board (white squares on black, ArUco markers), with Caliscope's own corner
detections per frame (xy.csv). The board's contrast points are tracked as a user would track
markers: the plain white squares (~40-110 px, a `bright` model: brightness contrast, no colour) and
the X-corners where two black squares meet (a `texture` model: no blob). Each is seeded in the
first frame its camera sees the board (the box around the square, or a box of half a square
around the corner), then tracked forward through the clip: the board moves by up to ~100 px between
frames, turns and leaves the view, so the tracker must flag what it is not sure of.

Truth per frame: placed by a homography fitted to Caliscope's detected corners of that frame
(undistorted with Caliscope's own calibration, distorted back; groundtruth.board_points_from_corners):
a corner itself; a square's image centroid (its outline placed so, what a blob tracker measures; under
perspective the projected centre lies up to ~2 px from it). Frames where Caliscope found fewer than
6 corners have no truth and are not scored.
Figures per kind of point: reported `tracked` on frames with truth, the share within 3 px
(target >= 95 %), the share of truth frames reported tracked (coverage), mean / p95 error. The same
runs on the clips converted to grey 8-bit PNG and 16-bit TIFF image folders (the grey paths).
What real footage here cannot test: markers of 8-15 px, sand, crowds of identical markers, stereo
gating (the four views are tracked one by one).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sandtrack_tui.calibration.caliscope import import_caliscope  # noqa: E402
from sandtrack_tui.groundtruth import board_points_from_corners  # noqa: E402
from sandtrack_tui.store import Project  # noqa: E402
from sandtrack_tui.tracking.run import seed_marker, track_project  # noqa: E402
from sandtrack_tui.video import FrameSource  # noqa: E402

DATA = ROOT.parent / "shared" / "data" / "caliscope_4cam"
SQUARE_M = 0.054
COLS, ROWS = 4, 5
FIRST_SYNC = 416  # sync_index of frame 0 of every file
CLICK_OFF = (1.5, -1.0)
OUTLINE = 25  # points per side of a square's outline


def truth_points(cam_id: int) -> tuple[dict, np.ndarray, np.ndarray]:
    """({frame: (N, 2) px}, board points (N, 2) m, kinds (N,): 'square' or 'corner') for one camera.
    A square's point is the centroid of its image (its outline placed by the homography and the lens:
    what a blob's coverage centroid measures; under perspective it is not the projected centre)."""
    cal = import_caliscope(DATA / "camera_array.toml")
    camera = cal.cameras[f"cam_{cam_id}"]
    xy = pd.read_csv(DATA / "xy.csv")
    xy = xy[xy.cam_id == cam_id].assign(frame=lambda d: d.sync_index - FIRST_SYNC)
    squares = [((c + 0.5) * SQUARE_M, (r + 0.5) * SQUARE_M) for r in range(ROWS) for c in range(COLS)]
    corners = [((c + 1) * SQUARE_M, (r + 1) * SQUARE_M) for r in range(ROWS - 1) for c in range(COLS - 1)]
    t = np.linspace(-0.5, 0.5, OUTLINE, endpoint=False)
    edge = np.concatenate([np.c_[t, np.full_like(t, -0.5)], np.c_[np.full_like(t, 0.5), t],
                           np.c_[-t, np.full_like(t, 0.5)], np.c_[np.full_like(t, -0.5), -t]]) * SQUARE_M
    outlines = np.concatenate([np.asarray(sq) + edge for sq in squares])
    placed = board_points_from_corners(xy, camera, np.concatenate([outlines, corners]))
    n_out = len(outlines)
    truth = {}
    for f, px in placed.items():
        cents = []
        for k in range(len(squares)):
            m = cv2.moments(px[k * len(edge):(k + 1) * len(edge)].astype(np.float32))
            cents.append((m["m10"] / m["m00"], m["m01"] / m["m00"]))
        truth[f] = np.concatenate([np.array(cents), px[n_out:]])
    pts = np.array(squares + corners)
    kinds = np.array(["square"] * len(squares) + ["corner"] * len(corners))
    return truth, pts, kinds


def _plain(img: np.ndarray, centre: np.ndarray, side: float) -> bool:
    """A plain (marker-free) square: light and uniform around its centre."""
    h = max(int(0.3 * side), 2)
    x, y = int(round(centre[0])), int(round(centre[1]))
    if x - h < 0 or y - h < 0 or x + h >= img.shape[1] or y + h >= img.shape[0]:
        return False
    lum = cv2.cvtColor(img[y - h:y + h + 1, x - h:x + h + 1], cv2.COLOR_BGR2GRAY).astype(float)
    return lum.mean() > 90 and lum.std() < 20


def _x_corner(img: np.ndarray, centre: np.ndarray, side: float) -> bool:
    """A corner where two markers' black borders meet diagonally between two plain squares: four
    small quadrants next to it, alike across each diagonal, dark against light."""
    a, b = 1, max(int(round(0.12 * side)), 3)
    x, y = int(round(centre[0])), int(round(centre[1]))
    if x - b < 0 or y - b < 0 or x + b >= img.shape[1] or y + b >= img.shape[0]:
        return False
    lum = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(float)
    q = [lum[y - b:y - a, x - b:x - a], lum[y - b:y - a, x + a:x + b], lum[y + a:y + b, x - b:x - a],
         lum[y + a:y + b, x + a:x + b]]
    m = [float(v.mean()) for v in q]
    return abs(m[0] - m[3]) < 30 and abs(m[1] - m[2]) < 30 and abs(m[0] - m[1]) > 50


def _seeds(source, truth: dict, pts: np.ndarray, kinds: np.ndarray, wanted=("square", "corner")) -> list[tuple]:
    """(point index, frame, x, y, box) for the squares and X-corners in the first frame with truth."""
    f0 = min(truth)
    img = source.frame(f0)
    px = truth[f0]
    side = float(np.median([np.hypot(*(px[i] - px[i + 1])) for i in range(COLS - 1)]))
    out = []
    for i, (p, kind) in enumerate(zip(px, kinds, strict=True)):
        if kind not in wanted:
            continue
        if kind == "square" and _plain(img, p, side):
            out.append((i, f0, p[0] + CLICK_OFF[0], p[1] + CLICK_OFF[1], side))
        elif kind == "corner" and _x_corner(img, p, side):
            out.append((i, f0, p[0] + CLICK_OFF[0], p[1] + CLICK_OFF[1], 0.6 * side))
    return out


def track_camera(video: Path, cam_id: int, tmp: Path, label: str, kinds=("square", "corner")) -> pd.DataFrame:
    """Points (index, kind, frame, status, error_px) of one camera's contrast points (`kinds`) tracked
    in `video` (a video or an image folder)."""
    truth, pts, point_kinds = truth_points(cam_id)
    with FrameSource(video) as src:
        seeds = _seeds(src, truth, pts, point_kinds, kinds)
    proj = Project.create(tmp / f"real_{label}_{cam_id}.sandtrack", {"side": video})
    for k, (_point, f, x, y, side) in enumerate(seeds, start=1):
        seed_marker(proj, k, "side", f, x, y, side, side)
    summary = track_project(proj)
    problems = summary["problems"]
    points = proj.points()
    proj.close()
    rows = []
    index = {k: seed[0] for k, seed in enumerate(seeds, start=1)}
    for r in points.itertuples():
        i = index.get(int(r.marker))
        if i is None or r.status == "manual":
            continue
        t = truth.get(int(r.frame))
        err = float(np.hypot(r.x_px - t[i][0], r.y_px - t[i][1])) if t is not None and np.isfinite(r.x_px) \
            else float("nan")
        rows.append((cam_id, i, point_kinds[i], int(r.frame), r.status, err, t is not None))
    models = {m: v["side"]["appearance"]["model"] for m, v in summary["per_marker"].items()}
    df = pd.DataFrame(rows, columns=["camera", "point", "kind", "frame", "status", "error_px", "has_truth"])
    df.attrs["models"] = models
    df.attrs["problems"] = problems
    return df


def figures(df: pd.DataFrame) -> dict:
    out = {}
    for kind, g in df.groupby("kind"):
        scored = g[g.has_truth]
        tracked = scored[scored.status == "tracked"]
        n_truth = int(scored.groupby(["camera", "point"]).size().sum())
        out[kind] = {
            "points": int(g.groupby(["camera", "point"]).ngroups),
            "tracked_with_truth": len(tracked),
            "within_3px_pct": round(100.0 * float((tracked.error_px <= 3.0).mean()), 1) if len(tracked) else None,
            "coverage_pct": round(100.0 * len(tracked) / n_truth, 1) if n_truth else None,
            "flagged_with_truth": int(scored.status.isin(["occluded", "lost"]).sum()),
            "mean_error_px": round(float(tracked.error_px.mean()), 3) if len(tracked) else None,
            "p95_error_px": round(float(tracked.error_px.quantile(0.95)), 3) if len(tracked) else None,
            "tracked_without_truth": int(((g.status == "tracked") & ~g.has_truth).sum()),
        }
    return out


def _grey_folder(video: Path, folder: Path, bits: int) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    with FrameSource(video) as src:
        for i in range(len(src)):
            grey = cv2.cvtColor(src.frame(i), cv2.COLOR_BGR2GRAY)
            if bits == 16:
                cv2.imwrite(str(folder / f"{i:04d}.tif"), grey.astype(np.uint16) * 257)
            else:
                cv2.imwrite(str(folder / f"{i:04d}.png"), grey)
    return folder


def run(cameras=(0, 1, 2, 3)) -> dict:
    if not (DATA / "xy.csv").is_file():
        return {"skipped": f"real footage absent ({DATA})"}
    out: dict = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for label in ("colour", "grey8", "grey16"):
            frames, c0 = [], time.process_time()
            for cam in cameras:
                video = DATA / f"cam_{cam}.mp4"
                if label != "colour":
                    video = _grey_folder(video, tmp / f"{label}_{cam}", 8 if label == "grey8" else 16)
                frames.append(track_camera(video, cam, tmp, label))
            df = pd.concat(frames)
            models = {}
            for f in frames:
                for m in f.attrs["models"].values():
                    models[m] = models.get(m, 0) + 1
            for kind, figs in figures(df).items():
                out.update({f"{label}.{kind}.{k}": v for k, v in figs.items()})
            out[f"{label}.models"] = ",".join(f"{k}:{n}" for k, n in sorted(models.items()))
            out[f"{label}.seed_problems"] = sum(len(f.attrs["problems"]) for f in frames)
            out[f"{label}.cpu_s"] = round(time.process_time() - c0, 2)
    return out


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key}: {value}")
