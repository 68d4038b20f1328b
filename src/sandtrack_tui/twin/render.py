"""Ray-cast rendering of the sand box for one camera (numpy + OpenCV).

Every pixel is a ray through the true camera model (distortion included). A static layer (flat sand,
walls, room) is computed once per camera; while the tool moves only the image region over the part
of the height field that changed is ray-marched again. The tool's shank, its shadow and the markers
are drawn on a copy of that canvas each frame, then sensor noise is added.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..camera import Camera
from .rig import BOX_MM, LIGHT_DIR, SAND_Y, pixel_rays
from .scene import GRID_MM, MARKER_RADIUS, SurfaceGrid, bilinear, ray_box, shank_box
from .textures import Textures

AMBIENT = 0.40
DIFFUSE = 0.72
Y_MARCH_TOP = SAND_Y + 21.0
Y_MARCH_BOT = SAND_Y - 25.0
MARKER_BGR = np.array([0.70, 0.33, 0.09], np.float32)  # blue paint on wood


@dataclass(frozen=True)
class MarkerStyle:
    """How a marker sphere looks: albedo (BGR), a specular highlight (strength, shininess) and the
    share of the scene behind it that shows through (glass)."""

    albedo: tuple = tuple(float(v) for v in MARKER_BGR)
    spec: float = 0.10
    shininess: int = 30
    transmit: float = 0.0


BLUE_PAINT = MarkerStyle()  # matte paint, diffuse lab light
STEEL_BGR = np.array([0.42, 0.43, 0.44], np.float32)
SHADOW_TOP_Y = 800.0  # the lamp's light reaches the sand past the shank's parts below this height


def _norm(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def wall_shadow(P):
    """Soft shadow of the box walls on sand points P (..., 3): 1 lit, ~0.35 in shadow."""
    L = LIGHT_DIR
    lit = np.ones(P.shape[:-1], np.float32)
    for axis, plane in ((0, 0.0), (0, BOX_MM[0]), (2, 0.0), (2, BOX_MM[2])):
        if abs(L[axis]) < 1e-9:
            continue
        lam = (plane - P[..., axis]) / L[axis]
        ycross = P[..., 1] + lam * L[1]
        s = np.clip((ycross - (BOX_MM[1] - 12.0)) / 24.0, 0.0, 1.0)
        lit = np.where(lam > 0, np.minimum(lit, s), lit)
    return 0.35 + 0.65 * lit


def wall_occlusion(P):
    """Darkening of sand near the walls (ambient occlusion)."""
    dmin = np.minimum.reduce([P[..., 0], BOX_MM[0] - P[..., 0], P[..., 2], BOX_MM[2] - P[..., 2]])
    return 1.0 - 0.22 * np.exp(-np.maximum(dmin, 0) / 18.0)


class CameraView:
    def __init__(self, cam: Camera, textures: Textures, shader: SandShader, seed: int, noise_sigma: float = 2.0):
        self.cam = cam
        self.tex = textures
        self.shader = shader
        self.C, d = pixel_rays(cam)
        self.d = d.astype(np.float32)
        h, w = cam.height, cam.width
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        self.vignette = (1.0 - 0.28 * r2**1.4).astype(np.float32)
        self._static()
        rng = np.random.default_rng(seed + 31 + (0 if cam.name == "side" else 1))
        self.noise = []
        for _ in range(6):
            n = rng.normal(0.0, noise_sigma, (h, w, 3))
            n[..., 1] *= 0.8  # green channel cleaner, as on Bayer sensors
            n = np.round(n).clip(-40, 40).astype(np.int16)
            self.noise.append((np.maximum(n, 0).astype(np.uint8), np.maximum(-n, 0).astype(np.uint8)))

    # -- static layer -------------------------------------------------------------------------
    def _static(self):
        d, C = self.d.astype(np.float64), self.C
        h, w = d.shape[:2]
        # leaving the box volume through a wall plane: inner wall face if below the wall top, else room
        t_exit = np.full((h, w), np.inf)
        wall_axis = np.full((h, w), -1, np.int8)
        for axis, plane in ((0, 0.0), (0, BOX_MM[0]), (2, 0.0), (2, BOX_MM[2])):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (plane - C[axis]) / d[..., axis]
            t = np.where(t > 1e-6, t, np.inf)
            closer = t < t_exit
            t_exit = np.where(closer, t, t_exit)
            wall_axis = np.where(closer, axis, wall_axis)
        y_exit = C[1] + t_exit * d[..., 1]
        is_wall = y_exit <= BOX_MM[1]
        self.t_block = np.where(is_wall, t_exit, np.inf).astype(np.float32)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_sand = np.where(d[..., 1] < 0, (SAND_Y - C[1]) / d[..., 1], np.inf)
        color = np.zeros((h, w, 3), np.float32)
        # room (above the walls): dim lab
        room = (0.16 + 0.08 * np.clip(d[..., 1], -1, 1))[..., None] * np.array([1.0, 1.02, 1.05], np.float32)
        color[:] = room
        # walls
        Pw = C + t_exit[..., None] * d
        along = np.where(wall_axis == 0, Pw[..., 2], Pw[..., 0])
        wood = self.tex.wood_albedo(np.nan_to_num(along), np.nan_to_num(Pw[..., 1]))
        nrm = np.zeros((h, w, 3))
        for axis in (0, 2):
            nrm[..., axis] = np.where(wall_axis == axis, -np.sign(d[..., axis]), 0.0)
        lamb = np.clip(nrm @ LIGHT_DIR, 0, 1)
        dust = 1.0 - 0.25 * np.exp(-np.maximum(Pw[..., 1] - SAND_Y, 0) / 25.0)
        wall_col = wood * ((0.55 + 0.45 * lamb) * dust)[..., None].astype(np.float32)
        color = np.where(is_wall[..., None], wall_col, color)
        depth = np.where(is_wall, t_exit, np.inf)
        # flat sand
        sand = t_sand < t_exit
        # top edges of the walls (18 mm plywood) seen from above
        with np.errstate(divide="ignore", invalid="ignore"):
            t_top = np.where(d[..., 1] < 0, (BOX_MM[1] - C[1]) / d[..., 1], np.inf)
        Pt = C + np.nan_to_num(t_top, posinf=0.0)[..., None] * d
        out = np.maximum.reduce([-Pt[..., 0], Pt[..., 0] - BOX_MM[0], -Pt[..., 2], Pt[..., 2] - BOX_MM[2]])
        on_top = ~is_wall & ~sand & np.isfinite(t_top) & (out > 0) & (out < 18.0)
        top_col = self.tex.wood_albedo(Pt[..., 0] + Pt[..., 2], Pt[..., 0] * 0.0 + 3.0) * 1.25
        color = np.where(on_top[..., None], top_col, color)
        self.t_block = np.where(on_top, t_top, self.t_block).astype(np.float32)
        depth = np.where(on_top, t_top, depth)
        self.t_sand_flat = t_sand
        self.depth = np.where(sand, t_sand, depth).astype(np.float32)
        P = (C + np.where(sand, t_sand, 0)[..., None] * d).astype(np.float32)
        sand_col = self.shade_sand(P)
        color = np.where(sand[..., None], sand_col, color)
        self.P = P
        self.static_color = color
        self.canvas = self._to_u8(color, slice(0, h), slice(0, w))

    def _to_u8(self, color, ys, xs):
        return np.clip(color * self.vignette[ys, xs, None] * 255.0, 0, 255).astype(np.uint8)

    def shade_sand(self, P, g3=None):
        """Colour (h, w, 3) of sand points P (h, w, 3); g3 = (dH/dX, dH/dZ, disturbance) there, or flat."""
        X, Z = P[..., 0], P[..., 2]
        s4 = self.tex.sand_lookup(X, Z)
        c3 = self.shader.lookup(X, Z)
        if g3 is None:
            gx = gz = D = 0.0
            inv = 1.0
        else:
            gx, gz, D = g3[..., 0], g3[..., 1], g3[..., 2]
            inv = 1.0 / np.sqrt(gx * gx + gz * gz + 1.0)
        lamb = np.clip((LIGHT_DIR[1] - gx * LIGHT_DIR[0] - gz * LIGHT_DIR[2]) * inv + s4[..., 3] * (1 - 0.6 * D), 0, 1)
        shade = (AMBIENT * c3[..., 1] + DIFFUSE * lamb * c3[..., 2]) * c3[..., 0] * (1.0 - 0.06 * D)
        # less light reaches down into the furrow
        shade = shade * (1.0 - 0.22 * np.clip((SAND_Y - P[..., 1]) / 20.0, 0.0, 1.0))
        return s4[..., :3] * shade[..., None]

    # -- surface update -----------------------------------------------------------------------
    def image_bbox(self, lo, hi, pad=4, ny=3):
        """Pixel bbox (y0, y1, x0, x1) of a world box, or None if not visible."""
        xs = np.linspace(lo[0], hi[0], 5)
        ys = np.linspace(lo[1], hi[1], ny)
        zs = np.linspace(lo[2], hi[2], 9)
        pts = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), -1).reshape(-1, 3)
        zc = (pts - self.C) @ self.cam.R[2]
        pts = pts[zc > 10]
        if len(pts) == 0:
            return None
        px = self.cam.project(pts)
        x0, y0 = np.floor(px.min(0)) - pad
        x1, y1 = np.ceil(px.max(0)) + pad
        x0, y0 = max(int(x0), 0), max(int(y0), 0)
        x1, y1 = min(int(x1), self.cam.width), min(int(y1), self.cam.height)
        if x1 <= x0 or y1 <= y0:
            return None
        return y0, y1, x0, x1

    def _march(self, d, C, H, t_lo, t_hi, n_steps, n_bisect):
        """First crossing of rays (C + t d) below the height field H between t_lo and t_hi."""

        def f(t):
            X = (C[0] + t * d[..., 0]) / GRID_MM
            Z = (C[2] + t * d[..., 2]) / GRID_MM
            return (C[1] + t * d[..., 1]) - cv2.remap(H, X, Z, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

        lo_t, hi_t = t_lo.copy(), t_hi.copy()
        found = f(t_lo) < 0  # already under: the hit lies at (or before) t_lo
        hi_t[found] = t_lo[found]
        t_prev = t_lo
        for k in range(1, n_steps + 1):
            t = t_lo + (t_hi - t_lo) * (k / n_steps)
            below = (f(t) < 0) & ~found
            lo_t = np.where(below, t_prev, lo_t)
            hi_t = np.where(below, t, hi_t)
            found |= below
            t_prev = t
            if found.all():
                break
        for _ in range(n_bisect):
            mid = 0.5 * (lo_t + hi_t)
            under = f(mid) < 0
            hi_t = np.where(under, mid, hi_t)
            lo_t = np.where(under, lo_t, mid)
        return 0.5 * (lo_t + hi_t), found

    def update_surface(self, surf: SurfaceGrid, g3: np.ndarray, rows: slice, cols: slice):
        """Ray-march again the pixels over a changed window of the height field."""
        lo = np.array([cols.start * GRID_MM, Y_MARCH_BOT, rows.start * GRID_MM])
        hi = np.array([(cols.stop - 1) * GRID_MM, Y_MARCH_TOP, (rows.stop - 1) * GRID_MM])
        bb = self.image_bbox(lo, hi)
        if bb is None:
            return
        y0, y1, x0, x1 = bb
        ys, xs = slice(y0, y1), slice(x0, x1)
        d = self.d[ys, xs]
        C = self.C.astype(np.float32)
        dy = np.minimum(d[..., 1], -1e-6)
        ta = (Y_MARCH_TOP - C[1]) / dy
        tb = (Y_MARCH_BOT - C[1]) / dy
        # coarse pass on every other pixel, then a short bracketed search per pixel
        n = int(np.ceil((Y_MARCH_TOP - Y_MARCH_BOT) / 3.0))
        th, _ = self._march(d[::2, ::2], C, surf.H, ta[::2, ::2], tb[::2, ::2], n, 4)
        k = np.ones((3, 3), np.uint8)
        tmin = cv2.resize(cv2.erode(th, k), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)[: y1 - y0, : x1 - x0]
        tmax = cv2.resize(cv2.dilate(th, k), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)[: y1 - y0, : x1 - x0]
        t_lo = np.maximum(tmin - 3.0, ta)
        t_hi = np.minimum(tmax + 3.0, tb)
        t_hit, found = self._march(d, C, surf.H, t_lo, t_hi, 2, 5)
        sand = found & (t_hit < self.t_block[ys, xs])
        P = C + t_hit[..., None] * d
        g = cv2.remap(g3, P[..., 0] / GRID_MM, P[..., 2] / GRID_MM, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        col = self.shade_sand(P, g)
        col = np.where(sand[..., None], col, self.static_color[ys, xs])
        self.canvas[ys, xs] = self._to_u8(col, ys, xs)
        self.depth[ys, xs] = np.where(sand, t_hit, self.t_block[ys, xs])
        self.P[ys, xs] = np.where(sand[..., None], P, self.P[ys, xs])

    # -- per frame ----------------------------------------------------------------------------
    def draw_tool(self, img: np.ndarray, zt: float, surf: SurfaceGrid) -> np.ndarray:
        """Draw the tool's shank and its soft shadow on the sand."""
        box = shank_box(zt)
        L = LIGHT_DIR
        self.shank_t = None
        # shadow: lit fraction on the grid nodes of the footprint, then looked up per pixel
        top = min(box[1, 1], SHADOW_TOP_Y)
        reach = (top - SAND_Y + 25) / L[1]
        xa = np.array([box[0, 0], box[1, 0], box[0, 0] - reach * L[0], box[1, 0] - reach * L[0]])
        za = np.array([box[0, 2], box[1, 2], box[0, 2] - reach * L[2], box[1, 2] - reach * L[2]])
        gx0, gx1 = max(int(xa.min() / GRID_MM) - 4, 0), min(int(xa.max() / GRID_MM) + 5, surf.H.shape[1])
        gz0, gz1 = max(int(za.min() / GRID_MM) - 4, 0), min(int(za.max() / GRID_MM) + 5, surf.H.shape[0])
        zz, xx = np.mgrid[gz0:gz1, gx0:gx1].astype(np.float64) * GRID_MM
        Pn = np.stack([xx, surf.H[gz0:gz1, gx0:gx1], zz], -1).reshape(-1, 3)
        lit = np.zeros(len(Pn))
        shadow_box = box.copy()
        shadow_box[1, 1] = top
        t, _ = ray_box(Pn, np.broadcast_to(L, Pn.shape), shadow_box)
        lit += np.isinf(t)
        # the lamp is not a point: soft shadow edges (penumbra of a few mm)
        lit = cv2.GaussianBlur(lit.reshape(zz.shape).astype(np.float32), (0, 0), 2.5)
        bb = self.image_bbox(np.array([xa.min(), SAND_Y - 25, za.min()]), np.array([xa.max(), SAND_Y + 21, za.max()]))
        if bb is not None:
            y0, y1, x0, x1 = bb
            ys, xs = slice(y0, y1), slice(x0, x1)
            P = self.P[ys, xs]
            mx = (P[..., 0] / GRID_MM - gx0).astype(np.float32)
            mz = (P[..., 2] / GRID_MM - gz0).astype(np.float32)
            m = cv2.remap(lit, mx, mz, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1.0)
            is_sand = np.isfinite(self.depth[ys, xs]) & (P[..., 1] < SAND_Y + 40)
            factor = np.where(is_sand, 0.5 + 0.5 * m, np.float32(1.0)).astype(np.float32)
            if (factor < 0.999).any():
                region = img[ys, xs].astype(np.float32) * factor[..., None]
                img[ys, xs] = region.astype(np.uint8)
        # the shank itself: coarse ray casting on every 4th pixel, then exact where it may be
        view_box = box.copy()
        view_box[1, 1] = min(view_box[1, 1], self.C[1] - 5.0)  # higher parts are out of view
        bb = self.image_bbox(view_box[0], view_box[1], pad=6, ny=40)
        if bb is None:
            return img
        y0, y1, x0, x1 = bb
        ys, xs = slice(y0, y1), slice(x0, x1)
        h, w = y1 - y0, x1 - x0
        dc = self.d[ys, xs][::4, ::4]
        tc, _ = ray_box(self.C, dc.reshape(-1, 3).astype(np.float64), box)
        cand = np.isfinite(tc).reshape(dc.shape[:2]).astype(np.uint8)
        cand = cv2.dilate(cand, np.ones((3, 3), np.uint8))
        cand = cv2.resize(cand, (cand.shape[1] * 4, cand.shape[0] * 4), interpolation=cv2.INTER_NEAREST)[:h, :w]
        iy, ix = np.nonzero(cand)
        tmap = np.full((h, w), np.inf)
        if len(iy):
            d = self.d[ys, xs][iy, ix].astype(np.float64)
            t, axis = ray_box(self.C, d, box)
            vis = t < self.depth[ys, xs][iy, ix]
            if vis.any():
                iy, ix, d, t, axis = iy[vis], ix[vis], d[vis], t[vis], axis[vis]
                nrm = np.zeros_like(d)
                nrm[np.arange(len(d)), axis] = -np.sign(d[np.arange(len(d)), axis])
                lamb = np.clip(nrm @ L, 0, 1)
                Q = self.C + t[:, None] * d
                streak = 1.0 + 0.025 * np.sin(Q[:, 0] * 2.1 + Q[:, 2] * 1.7 + 0.004 * Q[:, 1])  # brushed steel
                dusty = np.exp(-np.maximum(Q[:, 1] - SAND_Y, 0) / 30.0)[:, None]
                base = STEEL_BGR * (1 - dusty) + np.array([0.42, 0.55, 0.64]) * dusty
                col = base * ((0.45 + 0.7 * lamb) * streak)[:, None] * self.vignette[ys, xs][iy, ix][:, None] * 255.0
                img[y0 + iy, x0 + ix] = np.clip(col, 0, 255).astype(np.uint8)
                tmap[iy, ix] = t
        self.shank_t = (bb, tmap)
        return img

    def _shank_depth_at(self, px_x, px_y):
        if self.shank_t is None:
            return np.full(px_x.shape, np.inf)
        (y0, y1, x0, x1), tmap = self.shank_t
        inside = (px_x >= x0) & (px_x < x1) & (px_y >= y0) & (px_y < y1)
        out = np.full(px_x.shape, np.inf)
        out[inside] = tmap[px_y[inside] - y0, px_x[inside] - x0]
        return out

    def draw_markers(self, img: np.ndarray, markers: dict[int, np.ndarray], surf: SurfaceGrid, zt: float, ss: int = 4,
                     radius: float = MARKER_RADIUS, style: MarkerStyle = BLUE_PAINT):
        C = self.C
        albedo = MARKER_BGR if style == BLUE_PAINT else np.array(style.albedo, np.float32)
        L = LIGHT_DIR
        far_first = sorted(markers.values(), key=lambda p: -float(np.linalg.norm(p - C)))
        for P in far_first:
            dist = np.linalg.norm(P - C)
            if (P - C) @ self.cam.R[2] < 20:
                continue
            c = self.cam.project(P[None])[0]
            rpx = self.cam.matrix[0, 0] * radius / dist
            half = int(np.ceil(rpx * 1.8 + 2))
            x0, y0 = int(np.floor(c[0])) - half, int(np.floor(c[1])) - half
            x1, y1 = x0 + 2 * half + 1, y0 + 2 * half + 1
            x0c, y0c, x1c, y1c = max(x0, 0), max(y0, 0), min(x1, self.cam.width), min(y1, self.cam.height)
            if x1c <= x0c or y1c <= y0c:
                continue
            ys, xs = slice(y0c, y1c), slice(x0c, x1c)
            region = img[ys, xs].astype(np.float32)
            gy, gx = np.mgrid[y0c:y1c, x0c:x1c]
            shank_depth = self._shank_depth_at(gx, gy)
            # contact shadow on the sand around the marker (not on the shank in front of it)
            Ps = self.P[ys, xs].astype(np.float64)
            h_here = float(surf.height(P[0], P[2]))
            if P[1] - h_here > -radius:
                S = P - L * ((P[1] - h_here) / L[1])
                ds = np.hypot(Ps[..., 0] - S[0], Ps[..., 2] - S[2])
                dc = np.hypot(Ps[..., 0] - P[0], Ps[..., 2] - P[2])
                near = (np.abs(Ps[..., 1] - h_here) < 6) & np.isinf(shank_depth)
                dark = 1 - near * (0.45 * np.exp(-((ds / 2.6) ** 4)) + 0.25 * np.exp(-((dc / 3.2) ** 2)))
                region *= dark[..., None]
            # supersampled sphere
            off = (np.arange(ss) + 0.5) / ss - 0.5
            sx = (gx[..., None, None] + off[None, None, None, :]).repeat(ss, axis=2)
            sy = (gy[..., None, None] + off[None, None, :, None]).repeat(ss, axis=3)
            dd = cv2.remap(self.d, sx.ravel().astype(np.float32)[None], sy.ravel().astype(np.float32)[None],
                           cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0].astype(np.float64)
            dd /= np.linalg.norm(dd, axis=1, keepdims=True)
            oc = C - P
            b = dd @ oc
            cc = oc @ oc - radius**2
            disc = b * b - cc
            t = np.where(disc > 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
            pix_depth = np.repeat(self.depth[ys, xs].ravel(), ss * ss).astype(np.float64)
            t_sh = np.repeat(shank_depth.ravel(), ss * ss)
            hit = (t < pix_depth) & (t < t_sh) & np.isfinite(t)
            if not hit.any():
                img[ys, xs] = np.clip(region, 0, 255).astype(np.uint8)
                continue
            Q = C + np.where(hit, t, 0)[:, None] * dd
            nrm = (Q - P) / radius
            lamb = np.clip(nrm @ L, 0, 1)
            hvec = _norm(L - dd)
            spec = np.clip(np.sum(nrm * hvec, axis=1), 0, 1) ** style.shininess * style.spec
            col = albedo * (0.55 + 0.5 * lamb)[:, None] + spec[:, None]
            col = col * 255.0
            frac = hit.reshape(y1c - y0c, x1c - x0c, ss * ss)
            colr = (col * hit[:, None]).reshape(y1c - y0c, x1c - x0c, ss * ss, 3).sum(2)
            cover = frac.mean(-1)
            colr = colr / np.maximum(frac.sum(-1), 1)[..., None] * self.vignette[ys, xs, None]
            if style.transmit:  # glass: the (darkened) scene behind the bead shows through it
                colr = colr + style.transmit * region
            region = region * (1 - cover[..., None]) + colr * cover[..., None]
            img[ys, xs] = np.clip(region, 0, 255).astype(np.uint8)
        return img

    def add_noise(self, img: np.ndarray, k: int) -> np.ndarray:
        pos, neg = self.noise[k % len(self.noise)]
        return cv2.subtract(cv2.add(img, pos), neg)


def update_g3(surf: SurfaceGrid, g3: np.ndarray, rows: slice, cols: slice):
    """Update the (dH/dX, dH/dZ, disturbance) grid inside a changed window (plus a 1-node rim)."""
    r0, r1 = max(rows.start - 1, 1), min(rows.stop + 1, surf.H.shape[0] - 1)
    c0, c1 = max(cols.start - 1, 1), min(cols.stop + 1, surf.H.shape[1] - 1)
    H = surf.H
    g3[r0:r1, c0:c1, 0] = (H[r0:r1, c0 + 1 : c1 + 1] - H[r0:r1, c0 - 1 : c1 - 1]) / (2 * GRID_MM)
    g3[r0:r1, c0:c1, 1] = (H[r0 + 1 : r1 + 1, c0:c1] - H[r0 - 1 : r1 - 1, c0:c1]) / (2 * GRID_MM)
    g3[r0:r1, c0:c1, 2] = surf.D[r0:r1, c0:c1]


class SandShader:
    """Static shading terms of the sand on a coarse world grid: albedo variation, wall occlusion, wall shadow."""

    CELL_MM = 4.0

    def __init__(self, textures: Textures):
        nz, nx = int(BOX_MM[2] / self.CELL_MM) + 2, int(BOX_MM[0] / self.CELL_MM) + 2
        zz, xx = np.mgrid[0:nz, 0:nx].astype(np.float64) * self.CELL_MM
        P = np.stack([xx, np.full_like(xx, SAND_Y), zz], -1)
        coarse = cv2.resize(textures.coarse, (nx, nz), interpolation=cv2.INTER_LINEAR)
        self.grid = np.dstack([coarse, wall_occlusion(P), wall_shadow(P)]).astype(np.float32)

    def lookup(self, X, Z):
        return cv2.remap(self.grid, (X / self.CELL_MM).astype(np.float32), (Z / self.CELL_MM).astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


__all__ = ["CameraView", "SandShader", "update_g3", "bilinear"]
