"""The calibration session: a ChArUco board held by hand and moved through the working volume.

The board first lies flat on the sand, aligned with the box (the world-frame reference pose), then is
lifted and moved smoothly: near and far, tilted up to about 60 degrees, sometimes partly out of a
camera's view, fast enough now and then to blur. Pose = world_from_board: ``X_w = R @ X_b + t`` with
board coordinates in mm as OpenCV's ChArUco board (x along the columns, y down the rows, z into the
board, the printed face towards -z).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..board import BoardSpec
from .rig import LIGHT_DIR, SAND_Y

PLATE_MARGIN_MM = 12.0  # white border of the printed board on its plate
PLATE_THICKNESS_MM = 3.0
BOARD_PPM = 4.0  # texture resolution, px per mm
# Reference pose: flat on the sand, board x along world +X, board y along world +Z, board z = world -Y.
R_REF = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
REF_ORIGIN = np.array([150.0, SAND_Y + PLATE_THICKNESS_MM, 520.0])
FLAT_UNTIL_S = 1.6
LIFT_S = 1.0
SHUTTER_S = 1.0 / 200.0


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


class BoardMotion:
    def __init__(self, board: BoardSpec, seed: int, rest_origin=REF_ORIGIN):
        """rest_origin: the board's origin (mm, world) while it lies flat on the sand at first."""
        self.board = board
        rng = np.random.default_rng(seed + 71)
        w, h = board.size_mm
        self.half = np.array([w / 2, h / 2, 0.0])
        self.rest_origin = np.asarray(rest_origin, dtype=float).copy()
        self.ref_center = self.rest_origin + R_REF @ self.half
        # sums of sinusoids: (amplitude, frequency Hz, phase) per parameter
        def comp(amps, f_lo, f_hi):
            return [(a, rng.uniform(f_lo, f_hi), rng.uniform(0, 2 * np.pi)) for a in amps]

        self.params = {
            "x": comp([85, 40, 12], 0.04, 0.22),
            "y": comp([40, 18, 6], 0.05, 0.25),
            "z": comp([110, 45, 10], 0.04, 0.22),
            "ax": comp([np.radians(24), np.radians(10)], 0.05, 0.3),
            "az": comp([np.radians(26), np.radians(10)], 0.05, 0.3),
            "yaw": comp([np.radians(35), np.radians(15)], 0.03, 0.2),
        }
        self.mean = {"x": 250.0, "y": 315.0, "z": 610.0, "ax": np.radians(24), "az": np.radians(10), "yaw": 0.0}
        # quick jerks of the hand (motion blur), some far enough to leave a camera's view partly
        # the first ones are fixed so that even short sessions move partly out of each camera's view
        self.flicks = [(3.0, 1.3, np.array([-20.0, -10.0, -240.0])), (4.9, 1.5, np.array([30.0, 20.0, 175.0])),
                       (6.7, 1.0, np.array([110.0, 0.0, -90.0]))]
        self.tilts = [(4.0, 1.4, np.radians(30), 0.0), (6.0, 1.2, 0.0, np.radians(22)),
                      (7.4, 0.6, np.radians(-20), np.radians(-20))]
        for _ in range(int(200 / 2.5)):
            ang = rng.uniform(0, 2 * np.pi)
            self.flicks.append((rng.uniform(8.0, 200.0), rng.uniform(0.6, 1.2), rng.uniform(30, 130) *
                                np.array([np.cos(ang), 0.3 * rng.standard_normal(), np.sin(ang)])))

    def _value(self, key, t):
        v = self.mean[key]
        for a, f, p in self.params[key]:
            v = v + a * np.sin(2 * np.pi * f * t + p)
        return v

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """world_from_board (R, t) at scene time t (s)."""
        w = float(np.clip((t - FLAT_UNTIL_S) / LIFT_S, 0, 1))
        w = w * w * (3 - 2 * w)
        if w <= 0:
            return R_REF.copy(), self.rest_origin.copy()
        jerk = np.zeros(3)
        for t0, dur, amp in self.flicks:
            if t0 <= t <= t0 + dur:
                jerk += amp * np.sin(np.pi * (t - t0) / dur) ** 2
        v = {k: self._value(k, t) for k in self.params}
        center = np.array([v["x"], v["y"], v["z"]]) + jerk
        # the plate (half-diagonal ~135 mm) stays inside the box, clear of the walls
        center[0] = np.clip(center[0], 150.0, 350.0)
        center[2] = np.clip(center[2], 200.0, 1300.0)
        ax, az = v["ax"], v["az"]
        for t0, dur, dax, daz in self.tilts:
            if t0 <= t <= t0 + dur:
                bump = np.sin(np.pi * (t - t0) / dur) ** 2
                ax, az = ax + dax * bump, az + daz * bump
        tilt = np.hypot(ax, az)
        lim = np.radians(62)
        if tilt > lim:
            ax, az = ax * lim / tilt, az * lim / tilt
        R_motion = _rx(ax) @ _rz(az) @ _ry(v["yaw"]) @ R_REF
        # blend from the flat pose: interpolate the parameters
        R = _rx(w * ax) @ _rz(w * az) @ _ry(w * v["yaw"]) @ R_REF if w < 1 else R_motion
        c = (1 - w) * self.ref_center + w * center
        # keep the plate above the sand
        corners = c + (R @ (self._plate_corners() - self.half).T).T
        low = corners[:, 1].min() - (SAND_Y + 4.0)
        if low < 0 and w > 0:
            c = c - np.array([0, low, 0]) * w
        return R, c - R @ self.half

    def _plate_corners(self):
        w, h = self.board.size_mm
        m = PLATE_MARGIN_MM
        return np.array([[-m, -m, 0], [w + m, -m, 0], [w + m, h + m, 0], [-m, h + m, 0]], float)

    def plate_corners_world(self, R, t):
        return self._plate_corners() @ R.T + t


class BoardRenderer:
    """Draws the board (printed face or plate back) and its shadow into a camera view's static frame."""

    def __init__(self, board: BoardSpec):
        self.board = board
        img = board.render(px_per_mm=BOARD_PPM, margin_mm=PLATE_MARGIN_MM).astype(np.float32) / 255.0
        img = cv2.GaussianBlur(img, (0, 0), 0.9)
        self.albedo = (0.06 + 0.80 * img).astype(np.float32)  # matte print: black ~6 %, white ~86 %
        w, h = board.size_mm
        self.extent = (-PLATE_MARGIN_MM, w + PLATE_MARGIN_MM, -PLATE_MARGIN_MM, h + PLATE_MARGIN_MM)

    def _hit(self, C, d, R, t):
        """Board-plane hits of rays: (distance, u, v, facing) arrays."""
        return self._plane_hit(_times(C - t, R), _times(d, R))  # R^T (C - t), R^T d for row vectors

    def _plane_hit(self, ob, db):
        """As `_hit` from ray origins `ob` and directions `db` in board coordinates."""
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -ob[..., 2] / db[..., 2]
        u = ob[..., 0] + lam * db[..., 0]
        v = ob[..., 1] + lam * db[..., 1]
        x0, x1, y0, y1 = self.extent
        inside = (lam > 0) & (u >= x0) & (u <= x1) & (v >= y0) & (v <= y1)
        return np.where(inside, lam, np.inf), u, v, ob[..., 2] < 0

    def draw(self, view, img: np.ndarray, poses: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Draw the board into `img` (uint8 BGR, in place), averaged over `poses` (motion blur).

        A pose only changes the pixels of its plate and of the plate's shadow on the sand, so each pose is
        computed only on the pixels around those two quadrilaterals; the others keep their value.
        """
        pts = np.concatenate([self._corners_world(R, t) for R, t in poses])
        bb = view.image_bbox(pts.min(0) - 5, pts.max(0) + 5, pad=3)
        L = LIGHT_DIR
        feet = pts - L * ((pts[:, 1] - SAND_Y) / L[1])[:, None]
        bbs = view.image_bbox(np.minimum(feet.min(0), pts.min(0)) - 8, np.maximum(feet.max(0), pts.max(0)) + 8, pad=3)
        if bbs is None:
            return img
        # per pose: the pixel box of its shadow (within the window) and of its plate (within bb)
        boxes = []
        for R, t in poses:
            corners = self._corners_world(R, t)
            foot = corners - L * ((corners[:, 1] - SAND_Y) / L[1])[:, None]
            shadow_box = _intersect(view.image_bbox(foot.min(0) - 3, foot.max(0) + 3, pad=3), bbs)
            plate_box = None
            if bb is not None:
                plate_box = _intersect(view.image_bbox(corners.min(0) - 3, corners.max(0) + 3, pad=3), bb)
            boxes.append((corners, foot, shadow_box, plate_box))
        union = _union([b for _, _, sb, pb in boxes for b in (sb, pb)])
        if union is None:
            return img
        y0, y1, x0, x1 = union
        base = img[y0:y1, x0:x1].astype(np.float32)
        acc = np.zeros_like(base)
        C = view.C
        for (R, t), (corners, foot, shadow_box, plate_box) in zip(poses, boxes, strict=True):
            area = _union([shadow_box, plate_box])
            if area is None:
                acc += base
                continue
            a = _local(area, union)
            out = base[a].copy()
            if shadow_box is not None:
                # shadow: does the ray from the sand point towards the lamp cross the plate?
                ys, xs = _slices(shadow_box)
                near = _quad_mask(view, foot, shadow_box)
                P = view.P[ys, xs][near].astype(np.float64)
                is_sand = np.isfinite(view.depth[ys, xs][near]) & (P[:, 1] < SAND_Y + 40)
                # the lamp's direction in board coordinates, computed as numpy computes it for a broadcast array
                lam_s = self._plane_hit(_times(P - t, R), (np.broadcast_to(L, (2, 3)) @ R)[0])[0]
                shadow = np.zeros(near.shape, bool)
                shadow[near] = is_sand & np.isfinite(lam_s)
                b = base[_local(shadow_box, union)]
                np.copyto(out[_local(shadow_box, area)], b * 0.55, where=shadow[..., None])
            if plate_box is not None:
                ys, xs = _slices(plate_box)
                near = _quad_mask(view, corners, plate_box)
                lam, u, v, facing = self._hit(C, view.d[ys, xs][near].astype(np.float64), R, t)
                vis = lam < view.depth[ys, xs][near]
                if vis.any():
                    iy, ix = np.nonzero(near)
                    iy, ix = iy[vis], ix[vis]
                    n_face = -R[:, 2]  # printed face normal (world)
                    if facing:
                        tu = ((u[vis] + PLATE_MARGIN_MM) * BOARD_PPM - 0.5).astype(np.float32)
                        tv = ((v[vis] + PLATE_MARGIN_MM) * BOARD_PPM - 0.5).astype(np.float32)
                        alb = _remap_points(self.albedo, tu, tv)
                        shade = 0.42 + 0.62 * max(float(n_face @ L), 0.0)
                        col = alb[:, None] * (shade * 255.0) * np.array([0.96, 0.98, 1.0], np.float32)
                    else:
                        shade = 0.35 + 0.5 * max(float(-n_face @ L), 0.0)
                        col = np.array([0.50, 0.52, 0.55], np.float32) * shade * 255.0
                    out[_local(plate_box, area)][iy, ix] = col * view.vignette[ys, xs][iy, ix][:, None]
            before = acc[a].copy()
            acc += base
            acc[a] = before + out
        img[y0:y1, x0:x1] = np.clip(acc / len(poses), 0, 255).astype(np.uint8)
        return img

    def _corners_world(self, R, t):
        x0, x1, y0, y1 = self.extent
        c = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)
        return c @ R.T + t


def _intersect(box, within):
    """Intersection of two pixel boxes (y0, y1, x0, x1), None if empty or either is None."""
    if box is None or within is None:
        return None
    y0, y1 = max(box[0], within[0]), min(box[1], within[1])
    x0, x1 = max(box[2], within[2]), min(box[3], within[3])
    return (y0, y1, x0, x1) if y1 > y0 and x1 > x0 else None


def _union(boxes):
    """Smallest pixel box holding every given box (None entries ignored), None if there is none."""
    boxes = [b for b in boxes if b is not None]
    if not boxes:
        return None
    return (min(b[0] for b in boxes), max(b[1] for b in boxes), min(b[2] for b in boxes), max(b[3] for b in boxes))


def _times(a: np.ndarray, m: np.ndarray, rows: int = 4096) -> np.ndarray:
    """a @ m for row vectors a (..., 3), in blocks of rows: BLAS computes every element the same way, but on one
    thread (a large product would wake BLAS threads that compete with the other render worker for the cores)."""
    if a.ndim != 2 or len(a) <= rows:
        return a @ m
    return np.concatenate([a[i : i + rows] @ m for i in range(0, len(a), rows)])


def _quad_mask(view, quad: np.ndarray, box, margin_px: int = 3) -> np.ndarray:
    """Pixels of `box` within `margin_px` of the image of a planar world quadrilateral (4, 3): its edges are
    projected piecewise (lens distortion bends them slightly)."""
    s = np.linspace(0.0, 1.0, 8, endpoint=False)[:, None]
    outline = np.concatenate([quad[k] + s * (quad[(k + 1) % 4] - quad[k]) for k in range(4)])
    px = view.cam.project(outline) - np.array([box[2], box[0]])
    mask = np.zeros((box[1] - box[0], box[3] - box[2]), np.uint8)
    cv2.fillPoly(mask, [np.round(px * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    mask = cv2.dilate(mask, np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8))
    return mask.astype(bool)


def _remap_points(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookups (cv2.remap, replicated border) at a list of points; same values as a remap of a map image."""
    n = len(x)
    width = 1024
    rows = max(-(-n // width), 1)
    mx = np.zeros(rows * width, np.float32)
    my = np.zeros(rows * width, np.float32)
    mx[:n], my[:n] = x, y
    out = cv2.remap(image, mx.reshape(rows, width), my.reshape(rows, width), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(rows * width, *image.shape[2:])[:n]


def _slices(box):
    return slice(box[0], box[1]), slice(box[2], box[3])


def _local(box, frame):
    """Slices of `box` inside an array covering the pixel box `frame`."""
    return slice(box[0] - frame[0], box[1] - frame[0]), slice(box[2] - frame[2], box[3] - frame[2])


def corner_truth(board: BoardSpec, cam, R_wb, t_wb, world_to_cam_ok=True):
    """True pixels of the board's inner corners seen by `cam` (world-frame extrinsics): (ids, px (N,2), XYZ (N,3))."""
    obj = board.corner_points_mm()
    Xw = obj @ R_wb.T + t_wb
    C = cam.center_mm
    n_face = -R_wb[:, 2]
    view = C - Xw
    cosang = (view @ n_face) / np.linalg.norm(view, axis=1)
    px = cam.project(Xw)
    zc = (Xw - C) @ cam.R[2]
    ok = (cosang > 0.17) & (zc > 0)  # facing the camera, less than ~80 degrees off
    ok &= (px[:, 0] >= 0) & (px[:, 0] <= cam.width - 1) & (px[:, 1] >= 0) & (px[:, 1] <= cam.height - 1)
    ids = np.nonzero(ok)[0]
    return ids, px[ids], Xw[ids]
