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
    def __init__(self, board: BoardSpec, seed: int):
        self.board = board
        rng = np.random.default_rng(seed + 71)
        w, h = board.size_mm
        self.half = np.array([w / 2, h / 2, 0.0])
        self.ref_center = REF_ORIGIN + R_REF @ self.half
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
            return R_REF.copy(), REF_ORIGIN.copy()
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
        ob = (C - t) @ R  # R^T (C - t) for row vectors
        db = d @ R
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -ob[..., 2] / db[..., 2]
        u = ob[..., 0] + lam * db[..., 0]
        v = ob[..., 1] + lam * db[..., 1]
        x0, x1, y0, y1 = self.extent
        inside = (lam > 0) & (u >= x0) & (u <= x1) & (v >= y0) & (v <= y1)
        return np.where(inside, lam, np.inf), u, v, ob[..., 2] < 0

    def draw(self, view, img: np.ndarray, poses: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        """Draw the board into `img` (uint8 BGR, in place), averaged over `poses` (motion blur)."""
        pts = np.concatenate([self._corners_world(R, t) for R, t in poses])
        bb = view.image_bbox(pts.min(0) - 5, pts.max(0) + 5, pad=3)
        L = LIGHT_DIR
        feet = pts - L * ((pts[:, 1] - SAND_Y) / L[1])[:, None]
        bbs = view.image_bbox(np.minimum(feet.min(0), pts.min(0)) - 8, np.maximum(feet.max(0), pts.max(0)) + 8, pad=3)
        if bbs is None:
            return img
        y0, y1, x0, x1 = bbs
        ys, xs = slice(y0, y1), slice(x0, x1)
        base = img[ys, xs].astype(np.float32)
        acc = np.zeros_like(base)
        d = view.d[ys, xs].astype(np.float64)
        C = view.C
        depth = view.depth[ys, xs]
        P = view.P[ys, xs].astype(np.float64)
        is_sand = np.isfinite(depth) & (P[..., 1] < SAND_Y + 40)
        inb = np.zeros(depth.shape, bool)
        if bb is not None:
            by0, by1, bx0, bx1 = bb
            inb[by0 - y0 : by1 - y0, bx0 - x0 : bx1 - x0] = True
        for R, t in poses:
            # shadow: does the ray from the sand point towards the lamp cross the plate?
            lam_s, _, _, _ = self._hit(P, np.broadcast_to(L, P.shape), R, t)
            shadow = is_sand & np.isfinite(lam_s)
            out = np.where(shadow[..., None], base * 0.55, base)
            if bb is not None:
                lam, u, v, facing = self._hit(C, d, R, t)
                vis = inb & (lam < depth)
                if vis.any():
                    n_face = -R[:, 2]  # printed face normal (world)
                    if facing:
                        tu = ((u + PLATE_MARGIN_MM) * BOARD_PPM - 0.5).astype(np.float32)
                        tv = ((v + PLATE_MARGIN_MM) * BOARD_PPM - 0.5).astype(np.float32)
                        alb = cv2.remap(self.albedo, tu, tv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                        shade = 0.42 + 0.62 * max(float(n_face @ L), 0.0)
                        col = alb[..., None] * (shade * 255.0) * np.array([0.96, 0.98, 1.0], np.float32)
                    else:
                        shade = 0.35 + 0.5 * max(float(-n_face @ L), 0.0)
                        col = np.broadcast_to(np.array([0.50, 0.52, 0.55], np.float32) * shade * 255.0, out.shape)
                    col = col * view.vignette[ys, xs, None]
                    out = np.where(vis[..., None], col, out)
            acc += out
        img[ys, xs] = np.clip(acc / len(poses), 0, 255).astype(np.uint8)
        return img

    def _corners_world(self, R, t):
        x0, x1, y0, y1 = self.extent
        c = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)
        return c @ R.T + t


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
