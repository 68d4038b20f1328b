"""Synthetic marker clips with exact ground truth, for tests and quick benchmarks.

Sand-like textured background, blue anti-aliased discs (shaded like small spheres) that move with
known sub-pixel centres, a grey tool passing over them, optional dust on the markers, burial
(a marker fading under sand) and two markers passing close to each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import pandas as pd

SAND_BGR = np.array([110.0, 150.0, 185.0])
MARKER_BGR = np.array([175.0, 95.0, 35.0])
TOOL_BGR = np.array([100.0, 100.0, 104.0])


@dataclass
class MarkerPath:
    marker: int
    xy: np.ndarray  # (n_frames, 2) true centres, px
    radius: float = 5.0
    fade: np.ndarray | None = None  # (n_frames,) 1 = fully shown, 0 = buried


@dataclass
class Clip:
    frames: list[np.ndarray]
    truth: pd.DataFrame  # frame, marker, x_px, y_px, visible_frac, visible
    seeds: pd.DataFrame  # marker, frame, x, y, w, h
    fps: float = 50.0
    tool_boxes: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.frames)

    def frame(self, i: int) -> np.ndarray:
        return self.frames[i]

    def __getitem__(self, i: int) -> np.ndarray:
        return self.frames[i]

    @property
    def times_s(self) -> np.ndarray:
        return np.arange(len(self.frames)) / self.fps

    def index_at(self, t: float) -> int:
        return int(np.clip(round(t * self.fps), 0, len(self.frames) - 1))


def sand_texture(h: int, w: int, rng: np.random.Generator, sand_bgr: np.ndarray = SAND_BGR) -> np.ndarray:
    lum = cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 0.8) * 30
    lum += cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 5) * 60
    chroma = cv2.GaussianBlur(rng.normal(0, 1, (h, w, 3)).astype(np.float32), (0, 0), 1.0) * 6
    img = np.asarray(sand_bgr, np.float64)[None, None, :] * (1 + lum[..., None] / 255.0) + chroma
    return img.astype(np.float32)


def _disc_alpha(h: int, w: int, cx: float, cy: float, r: float, ss: int = 4):
    """Coverage (0..1) of a disc and its pixel box; supersampled ss x ss."""
    x0, x1 = max(int(np.floor(cx - r - 1)), 0), min(int(np.ceil(cx + r + 2)), w)
    y0, y1 = max(int(np.floor(cy - r - 1)), 0), min(int(np.ceil(cy + r + 2)), h)
    if x1 <= x0 or y1 <= y0:
        return None
    off = (np.arange(ss) + 0.5) / ss - 0.5
    xs = (np.arange(x0, x1)[:, None] + off[None, :]).ravel()
    ys = (np.arange(y0, y1)[:, None] + off[None, :]).ravel()
    d2 = (xs[None, :] - cx) ** 2 + (ys[:, None] - cy) ** 2
    inside = (d2 <= r * r).astype(np.float32)
    alpha = inside.reshape(y1 - y0, ss, x1 - x0, ss).mean(axis=(1, 3))
    shade = 1.0 - 0.35 * np.clip(d2 / (r * r), 0, 1)
    shade = shade.reshape(y1 - y0, ss, x1 - x0, ss).mean(axis=(1, 3))
    return (y0, y1, x0, x1), alpha, shade


def _smeared_alpha(h: int, w: int, p: MarkerPath, f: int, exposure: float, steps: int = 9):
    """_disc_alpha averaged over positions within the exposure around frame f (linear between frames)."""
    n = len(p.xy)
    acc = None
    for k in range(steps):
        t = f + exposure * (k / (steps - 1) - 0.5)
        i = int(np.clip(np.floor(t), 0, n - 2))
        a = t - i
        cx, cy = (1 - a) * p.xy[i] + a * p.xy[i + 1]
        out = _disc_alpha(h, w, cx, cy, p.radius)
        if out is None:
            continue
        box, alpha, shade = out
        if acc is None:
            acc = []
        acc.append((box, alpha, shade))
    if not acc:
        return None
    y0, x0 = min(b[0][0] for b in acc), min(b[0][2] for b in acc)
    y1, x1 = max(b[0][1] for b in acc), max(b[0][3] for b in acc)
    alpha = np.zeros((y1 - y0, x1 - x0), np.float64)
    shade = np.zeros_like(alpha)
    for (by0, by1, bx0, bx1), a, s in acc:
        alpha[by0 - y0:by1 - y0, bx0 - x0:bx1 - x0] += a / steps
        shade[by0 - y0:by1 - y0, bx0 - x0:bx1 - x0] += a * s / steps
    return (y0, y1, x0, x1), alpha, np.where(alpha > 0, shade / np.maximum(alpha, 1e-9), 1.0)


def render(paths: list[MarkerPath], n_frames: int, size=(360, 480), seed: int = 0, noise: float = 3.0,
           dusty: float = 0.0, tool: tuple | None = None, fps: float = 50.0, marker_bgr=MARKER_BGR,
           sand_bgr=SAND_BGR, exposure: float = 0.0, view_shift: np.ndarray | None = None) -> Clip:
    """Render a clip. tool = (y0, y1, width, x_start, speed_px_per_frame) of a grey bar moving right.
    marker_bgr, sand_bgr: colours; exposure: motion blur, the share of a frame's move each marker is
    smeared over; view_shift (n_frames, 2): the whole image moved by (dx, dy) px (truth moved too)."""
    rng = np.random.default_rng(seed)
    h, w = size
    bg = sand_texture(h, w, rng, sand_bgr)
    marker_bgr, sand_bgr = np.asarray(marker_bgr, np.float64), np.asarray(sand_bgr, np.float64)
    colour = (1 - dusty) * marker_bgr + dusty * sand_bgr
    speckle = {p.marker: rng.random((64, 64)) < 0.5 * dusty for p in paths}
    frames, rows, tool_boxes = [], [], []
    for f in range(n_frames):
        img = bg.copy()
        tool_box = None
        if tool is not None:
            ty0, ty1, tw, tx, tv = tool
            xa = int(round(tx + tv * f))
            tool_box = (xa, ty0, xa + tw, ty1)
        tool_boxes.append(tool_box)
        for p in paths:
            cx, cy = p.xy[f]
            out = _smeared_alpha(h, w, p, f, exposure) if exposure > 0 else _disc_alpha(h, w, cx, cy, p.radius)
            fade = 1.0 if p.fade is None else float(p.fade[f])
            vis_frac = 0.0
            if out is not None:
                (y0, y1, x0, x1), alpha, shade = out
                a = alpha * fade
                col = colour[None, None, :] * shade[..., None]
                if dusty > 0:
                    sp = speckle[p.marker][(np.arange(y0, y1) - int(cy)) % 64][:, (np.arange(x0, x1) - int(cx)) % 64]
                    col = np.where(sp[..., None], sand_bgr * 0.95, col)
                img[y0:y1, x0:x1] = a[..., None] * col + (1 - a[..., None]) * img[y0:y1, x0:x1]
                covered = np.zeros_like(alpha)
                if tool_box is not None:
                    yy, xx = np.mgrid[y0:y1, x0:x1]
                    covered = ((xx >= tool_box[0]) & (xx < tool_box[2]) & (yy >= tool_box[1]) & (yy < tool_box[3]))
                total = alpha.sum()
                vis_frac = float((alpha * (1 - covered)).sum() / total * fade) if total > 0 else 0.0
            rows.append((f, p.marker, cx, cy, vis_frac))
        if tool_box is not None:
            xa, ya, xb, yb = tool_box
            xa, xb = max(xa, 0), min(xb, w)
            if xb > xa:
                img[ya:yb, xa:xb] = TOOL_BGR * (1 + 0.05 * rng.normal(0, 1, (yb - ya, xb - xa, 1)))
        if view_shift is not None:
            M = np.float32([[1, 0, view_shift[f][0]], [0, 1, view_shift[f][1]]])
            img = cv2.warpAffine(img, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            rows[-len(paths):] = [(r[0], r[1], r[2] + view_shift[f][0], r[3] + view_shift[f][1], r[4])
                                  for r in rows[-len(paths):]]
        img += rng.normal(0, noise, img.shape).astype(np.float32)
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    truth = pd.DataFrame(rows, columns=["frame", "marker", "x_px", "y_px", "visible_frac"])
    truth["visible"] = truth["visible_frac"] >= 0.5
    seeds = pd.DataFrame([(p.marker, 0, p.xy[0, 0], p.xy[0, 1], 2 * p.radius + 4, 2 * p.radius + 4) for p in paths],
                         columns=["marker", "frame", "x", "y", "w", "h"])
    return Clip(frames=frames, truth=truth, seeds=seeds, fps=fps, tool_boxes=tool_boxes)


def standard_paths(n_frames: int, size=(360, 480), seed: int = 1) -> list[MarkerPath]:
    """Six markers: still, drifting, wobbling, pushed (sudden start), and two passing close."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames, dtype=np.float64)
    h, w = size
    paths = []
    paths.append(MarkerPath(1, np.stack([np.full_like(t, 0.30 * w + 0.37), np.full_like(t, 0.25 * h + 0.21)], 1)))
    paths.append(MarkerPath(2, np.stack([0.15 * w + 0.83 * t, 0.55 * h + 0.31 * t], 1), radius=4.6))
    paths.append(MarkerPath(3, np.stack([0.60 * w + 6 * np.sin(t / 7.0), 0.30 * h + 4 * np.cos(t / 5.0)], 1),
                            radius=5.5))
    start = n_frames // 3
    v = np.clip(t - start, 0, None)
    push = np.minimum(v * 3.5, 3.5 * 12 + 0.0 * v)  # 3.5 px/frame for 12 frames, then rests
    paths.append(MarkerPath(4, np.stack([0.45 * w + push, 0.72 * h + 0.3 * push], 1)))
    # Two markers passing each other ~14 px apart.
    paths.append(MarkerPath(5, np.stack([0.70 * w - 1.1 * t, 0.80 * h + 0.0 * t], 1), radius=4.8))
    paths.append(MarkerPath(6, np.stack([0.70 * w - 1.1 * n_frames + 1.1 * t, 0.80 * h - 14.0 + 0 * t], 1),
                            radius=4.8))
    for p in paths:
        p.xy = p.xy + rng.normal(0, 0.15, p.xy.shape)  # jitter: markers are never perfectly smooth
    return paths


def stereo_rig(size=(360, 480)):
    """Two pinhole cameras 25° apart looking at a sand patch ~400 mm away (a Calibration)."""
    from ..camera import Calibration, Camera

    h, w = size
    K = np.array([[700.0, 0, w / 2], [0, 700.0, h / 2], [0, 0, 1]])
    side = Camera("side", w, h, K, np.zeros(5))
    ang = np.deg2rad(-25.0)
    R = np.array([[np.cos(ang), 0, -np.sin(ang)], [0, 1, 0], [np.sin(ang), 0, np.cos(ang)]])
    c_front = np.array([170.0, 0.0, 30.0])  # front camera centre, rig frame (mm)
    front = Camera("front", w, h, K, np.zeros(5), rvec=cv2.Rodrigues(R)[0].ravel(), tvec=-R @ c_front)
    return Calibration(cameras={"side": side, "front": front})


def stereo_paths(n_frames: int, seed: int = 2):
    """3D paths (mm, rig frame) of five markers on a patch ~400 mm in front of the side camera."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames, dtype=np.float64)
    base = np.array([[-40, -20, 400], [-10, 15, 410], [20, -10, 395], [45, 20, 405], [5, -35, 400]], float)
    out = []
    for k, b in enumerate(base):
        v = np.array([0.25 * np.cos(k), 0.2 * np.sin(k), 0.05]) * (k % 3)
        xyz = b[None, :] + t[:, None] * v[None, :] + rng.normal(0, 0.01, (n_frames, 3))
        out.append((k + 1, xyz))
    return out


def render_stereo(n_frames: int, size=(360, 480), seed: int = 0, tool: dict | None = None, noise: float = 3.0):
    """Render both cameras of `stereo_rig` for `stereo_paths`: returns (calibration, {camera: Clip})."""
    cal = stereo_rig(size)
    paths3d = stereo_paths(n_frames, seed + 2)
    clips = {}
    for k, (name, cam) in enumerate(cal.cameras.items()):
        paths = [MarkerPath(m, cam.project(xyz), radius=5.0 * 400 / xyz[0, 2]) for m, xyz in paths3d]
        clips[name] = render(paths, n_frames, size, seed=seed + 10 * k, noise=noise,
                             tool=None if tool is None else tool.get(name))
    return cal, clips


BEAD_BGR = (22.0, 22.0, 25.0)  # black beads of a dense layer


def render_stereo_crowd(centres_mm: np.ndarray, radius_mm: float = 4.0, size=(360, 480), seed: int = 0,
                        shine=(-0.25, -0.3), noise: float = 3.0):
    """Identical black beads (a dense layer: touching lookalikes) seen by both cameras of `stereo_rig`.
    centres_mm: (n_frames, n_beads, 3) bead centres in the rig frame (mm); bead k is marker k + 1 in
    both views' truth. Each bead is a disc of its projected radius (focal length x radius / depth),
    the farther ones drawn first, with a highlight `shine` radii from its centre (a light and views
    that stay put). Returns (calibration, {camera: Clip})."""
    cal = stereo_rig(size)
    centres_mm = np.asarray(centres_mm, float)
    n_frames, n_beads, _ = centres_mm.shape
    clips = {}
    for k, (name, cam) in enumerate(cal.cameras.items()):
        flat = centres_mm.reshape(-1, 3)
        xy = cam.project(flat).reshape(n_frames, n_beads, 2)
        depth = ((cam.R @ flat.T).T + cam.tvec)[:, 2].reshape(n_frames, n_beads)
        r_px = cam.matrix[0, 0] * radius_mm / depth.mean(axis=0)
        order = np.argsort(-depth.mean(axis=0), kind="stable")
        paths = [MarkerPath(int(i) + 1, xy[:, i], radius=float(r_px[i])) for i in order]
        clip = render(paths, n_frames, size, seed=seed + 10 * k, noise=noise, marker_bgr=BEAD_BGR)
        clip.frames = [_with_highlights(f, xy[j], r_px, shine) for j, f in enumerate(clip.frames)]
        clips[name] = clip
    return cal, clips


def _with_highlights(img: np.ndarray, centres: np.ndarray, r_px: np.ndarray, shine) -> np.ndarray:
    """A small highlight on each bead, `shine` radii from its centre, within its disc."""
    out = img.astype(np.float32)
    h, w = img.shape[:2]
    for (cx, cy), r in zip(centres, r_px, strict=True):
        x0, x1 = max(int(cx - r - 2), 0), min(int(cx + r + 3), w)
        y0, y1 = max(int(cy - r - 2), 0), min(int(cy + r + 3), h)
        if x1 <= x0 or y1 <= y0:
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float32)
        disc = np.clip(r + 0.5 - np.hypot(xx - cx, yy - cy), 0, 1)
        spot = np.exp(-((xx - cx - shine[0] * r) ** 2 + (yy - cy - shine[1] * r) ** 2) / 2.0)
        out[y0:y1, x0:x1] += (60.0 * disc * spot)[..., None]
    return np.clip(out, 0, 255).astype(np.uint8)
