"""What happens in the sand box: the tool's motion, the sand surface it leaves, the 8 markers.

Everything is a pure function of the scene time (s) and the seed, so ground truth and rendering
agree exactly. The sand surface is a height field ``Y = H(X, Z)`` sampled on a 1 mm grid
(``SurfaceGrid``); between nodes it is bilinear (the renderer and the ground truth use the same
interpolation).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.interpolate import PchipInterpolator

from .rig import BOX_MM, SAND_Y, TOOL_X

# Tool: chisel with wings (1:2), working depth 75 mm, pulled along +Z at 0.1 m/s over 700 mm.
TOOL_SPEED = 100.0  # mm/s
TOOL_Z0 = 150.0  # shank front at the start (mm)
TOOL_TRAVEL = 700.0
TOOL_DEPTH = 75.0
SHANK_HALF_X = 6.0  # shank plate 12 mm thick (X)
SHANK_CHORD = 40.0  # along Z, behind the shank front
SHANK_TOP_Y = 1500.0  # hangs from the carriage above the box: its top is never in view
WING_HALF_SPAN = 55.0

MARKER_RADIUS = 2.5
MARKER_IDS = list(range(1, 9))
ROW_Z = [500.0, 550.0, 600.0, 650.0]
ROW_X = [TOOL_X, TOOL_X + 50.0]  # ids 1-4 on the tool path, 5-8 50 mm aside

GRID_MM = 1.0
NX = int(BOX_MM[0] / GRID_MM) + 1
NZ = int(BOX_MM[2] / GRID_MM) + 1
# Extent of the disturbed zone relative to the shank front u = zt - Z (mm, + behind the tool)
U_AHEAD = -90.0
U_SETTLE = 60.0
X_HALF = 118.0  # deformation is zero beyond |X - TOOL_X| > X_HALF


@dataclass(frozen=True)
class Timeline:
    tool_start_s: float = 1.2
    clap_s: float = 0.7
    speed_mm_s: float = TOOL_SPEED

    def tool_z(self, t: np.ndarray | float) -> np.ndarray | float:
        """Shank front Z (mm) at scene time t."""
        return TOOL_Z0 + np.clip((np.asarray(t) - self.tool_start_s) * self.speed_mm_s, 0.0, TOOL_TRAVEL)

    @property
    def tool_end_s(self) -> float:
        return self.tool_start_s + TOOL_TRAVEL / self.speed_mm_s


def _smoothstep(a: float, b: float, x):
    s = np.clip((x - a) / (b - a), 0.0, 1.0)
    return s * s * (3 - 2 * s)


def _g(s):
    return np.exp(-s * s)


def deformation(x, z, zt, rough):
    """Surface height above SAND_Y and disturbance (0..1) at x = X - TOOL_X, Z, shank front zt."""
    u = zt - z
    final = -20.0 * _g(x / 30.0) + 9.0 * (_g((np.abs(x) - 62.0) / 22.0))
    mound = 15.0 * _g(x / 46.0)
    ahead = mound * np.exp(np.minimum(u, 0.0) / 24.0) * _smoothstep(U_AHEAD, U_AHEAD + 40.0, u)
    w = _smoothstep(0.0, U_SETTLE, u)
    dyn = np.where(u < 0, ahead, (1 - w) * mound + w * final)
    started = _smoothstep(TOOL_Z0 - 70.0, TOOL_Z0 - 15.0, z)
    dist = _g(x / 80.0) * _smoothstep(U_AHEAD + 30.0, -10.0, u) * started
    h = dyn * started + 1.3 * rough * dist
    edge = _smoothstep(X_HALF, X_HALF - 20.0, np.abs(x))
    return h * edge, dist * edge


class SurfaceGrid:
    """The sand height field on a 1 mm grid over the whole box, updated as the tool moves."""

    def __init__(self, seed: int):
        rng = np.random.default_rng(seed + 101)
        r = rng.standard_normal((NZ, NX)).astype(np.float32)
        r = 0.75 * cv2.GaussianBlur(r, (0, 0), 5.0) / 0.0564 + 0.25 * cv2.GaussianBlur(r, (0, 0), 2.0) / 0.141
        self.rough = (r / r.std()).astype(np.float32)  # rows = Z, cols = X
        self.H = np.full((NZ, NX), SAND_Y, np.float32)
        self.D = np.zeros((NZ, NX), np.float32)
        self.zt = None
        self._xs = (np.arange(NX) * GRID_MM - TOOL_X).astype(np.float64)

    def _rows(self, zt: float) -> slice:
        lo = int(np.floor((zt - U_SETTLE - 2) / GRID_MM))
        hi = int(np.ceil((zt - U_AHEAD + 2) / GRID_MM)) + 1
        return slice(max(lo, 0), min(hi, NZ))

    def _cols(self) -> slice:
        return slice(int((TOOL_X - X_HALF) / GRID_MM) - 1, int((TOOL_X + X_HALF) / GRID_MM) + 2)

    def set_tool(self, zt: float) -> tuple[slice, slice]:
        """Move the tool to zt; returns the (rows, cols) window of the grid that changed."""
        zt = float(zt)
        if self.zt is None or zt < self.zt:
            rows = slice(0, NZ)  # (re)build from scratch
            self.H[:] = SAND_Y
            self.D[:] = 0
            z_lo, z_hi = 0, NZ
        else:
            a, b = self._rows(self.zt), self._rows(zt)
            z_lo, z_hi = min(a.start, b.start), max(a.stop, b.stop)
            rows = slice(z_lo, z_hi)
        cols = self._cols()
        zs = (np.arange(z_lo, z_hi) * GRID_MM)[:, None]
        h, d = deformation(self._xs[cols][None, :], zs, zt, self.rough[rows, cols])
        self.H[rows, cols] = (SAND_Y + h).astype(np.float32)
        self.D[rows, cols] = d.astype(np.float32)
        self.zt = zt
        return rows, cols

    def height(self, X, Z):
        """Bilinear height (mm) at world X, Z (arrays) for the current tool position."""
        return bilinear(self.H, np.asarray(X) / GRID_MM, np.asarray(Z) / GRID_MM)

    def height_at(self, X: float, Z: float, zt: float) -> float:
        """Height at one point for tool position zt, from the four grid nodes around it (same values
        as the grid would hold), without touching the grid."""
        return float(self.heights_at(np.array([X], float), np.array([Z], float), np.array([zt], float))[0])

    def heights_at(self, X: np.ndarray, Z: np.ndarray, zt: np.ndarray) -> np.ndarray:
        """`height_at` of many points at once (arrays of one length), each with its own tool position;
        outside the deformable band the grid holds flat sand."""
        gx = np.clip(np.asarray(X, float) / GRID_MM, 0, NX - 1.000001)
        gz = np.clip(np.asarray(Z, float) / GRID_MM, 0, NZ - 1.000001)
        i, j = np.floor(gx).astype(np.intp), np.floor(gz).astype(np.intp)
        two = np.arange(2)
        xs = (i[:, None] + two) * GRID_MM - TOOL_X  # (n, 2) along X
        zs = ((j[:, None] + two) * GRID_MM).astype(float)  # (n, 2) along Z
        rough = self.rough[j[:, None, None] + two[None, :, None], i[:, None, None] + two[None, None, :]]
        h, _ = deformation(xs[:, None, :], zs[:, :, None], np.asarray(zt, float)[:, None, None], rough)
        cols_ok = np.abs(xs) <= X_HALF + 2
        node = (SAND_Y + np.where(cols_ok[:, None, :], h, 0.0)).astype(np.float32).astype(np.float64)
        fx, fz = gx - i, gz - j
        top = node[:, 0, 0] * (1 - fx) + node[:, 0, 1] * fx
        bottom = node[:, 1, 0] * (1 - fx) + node[:, 1, 1] * fx
        return top * (1 - fz) + bottom * fz


def bilinear(grid: np.ndarray, gx, gz):
    gx = np.clip(np.asarray(gx, np.float64), 0, grid.shape[1] - 1.000001)
    gz = np.clip(np.asarray(gz, np.float64), 0, grid.shape[0] - 1.000001)
    i = np.floor(gx).astype(np.intp)
    j = np.floor(gz).astype(np.intp)
    fx, fz = gx - i, gz - j
    g = grid
    return ((g[j, i] * (1 - fx) + g[j, i + 1] * fx) * (1 - fz) + (g[j + 1, i] * (1 - fx) + g[j + 1, i + 1] * fx) * fz)


def shank_box(zt: float) -> np.ndarray:
    """Axis-aligned box of the tool's shank (the part that can be seen): [[xmin,ymin,zmin],[xmax,ymax,zmax]]."""
    return np.array([[TOOL_X - SHANK_HALF_X, SAND_Y - TOOL_DEPTH, zt - SHANK_CHORD],
                     [TOOL_X + SHANK_HALF_X, SHANK_TOP_Y, zt]])


def ray_box(o: np.ndarray, d: np.ndarray, box: np.ndarray):
    """Entry distance of rays (o + t d; o (3,) or (N,3), d (N,3)) into an axis-aligned box; inf if missed.
    Also returns the index (0,1,2) of the axis whose face was entered."""
    o = np.broadcast_to(np.asarray(o, np.float64), d.shape)
    tmins, tmaxs = [], []
    for a in range(3):
        da = d[:, a]
        da = np.where(np.abs(da) < 1e-12, 1e-12, da)
        t1 = (box[0, a] - o[:, a]) / da
        t2 = (box[1, a] - o[:, a]) / da
        tmins.append(np.minimum(t1, t2))
        tmaxs.append(np.maximum(t1, t2))
    t_near = np.maximum(np.maximum(tmins[0], tmins[1]), tmins[2])
    t_far = np.minimum(np.minimum(tmaxs[0], tmaxs[1]), tmaxs[2])
    hit = (t_far >= t_near) & (t_far > 0)
    axis = np.where(tmins[0] >= np.maximum(tmins[1], tmins[2]), 0, np.where(tmins[1] >= tmins[2], 1, 2))
    return np.where(hit, np.maximum(t_near, 0.0), np.inf), axis


# -- markers ---------------------------------------------------------------------------------------

# Per-marker motion, keyed by s = (shank front Z) - (marker's initial Z) in mm. Columns: s, dx, dz, dy.
# dx, dz: displacement from the initial position; dy: height above (+, lifted) or below (-, buried)
# the resting position on the current surface. "push" means carried just ahead of the shank.
_SCRIPTS = {
    1: [(-200, 0, 0, 0), (-60, 0, 2, 0), (-14, 0, 3, 0), (0, 0, "push", 0), (30, -4, "push", 1.5),
        (55, -40, 52, 3.0), (75, -64, 60, 0), (140, -70, 63, 0), (250, -71, 63, 0)],
    2: [(-200, 0, 0, 0), (-60, 0, 2, 0), (-14, 0, 3, 0), (0, 1, "push", 0), (20, 4, "push", -3),
        (40, 16, 40, -9.5), (120, 20, 42, -9.5), (165, 27, 40, 0), (260, 28, 40, 0)],
    3: [(-200, 0, 0, 0), (-60, 0, 2, 0), (-14, 0, 3, 0), (0, 1, "push", 0), (22, 5, "push", 6),
        (40, 30, 55, 12), (58, 62, 66, 0), (90, 55, 68, 0), (140, 44, 69, 0), (260, 43, 69, 0)],
    4: [(-200, 0, 0, 0), (-60, 0, 2, 0), (-16, -1, 3, 0), (0, -3, "push", 0), (8, -14, "push", -5),
        (24, -34, 30, -9.5), (90, -40, 32, -9.5), (140, -55, 33, 0), (260, -57, 33, 0)],
    5: [(-200, 0, 0, 0), (-70, 0, 3, 0), (-20, 3, 10, 0), (10, 10, 16, 2), (40, 16, 18, 0), (100, 18, 18, 0),
        (260, 18, 18, 0)],
    6: [(-200, 0, 0, 0), (-70, 0, 3, 0), (-15, 4, 9, -3), (5, 9, 14, -9.5), (70, 14, 18, -9.5),
        (115, 22, 20, 0), (260, 23, 20, 0)],
    7: [(-200, 0, 0, 0), (-70, 0, 4, 0), (-20, -2, 12, 0), (15, -6, 22, 1), (50, -13, 25, 0), (110, -16, 25, 0),
        (260, -16, 25, 0)],
    8: [(-200, 0, 0, 0), (-70, 0, 3, 0), (-20, 4, 8, 1), (15, 15, 13, 5), (45, 38, 15, 0), (110, 46, 15, 0),
        (260, 47, 15, 0)],
}
PUSH_GAP = MARKER_RADIUS + 2.0  # marker centre ahead of the shank front while pushed


def initial_positions(radius: float = MARKER_RADIUS) -> dict[int, np.ndarray]:
    out = {}
    for k, mid in enumerate(MARKER_IDS):
        out[mid] = np.array([ROW_X[k // 4], SAND_Y + radius, ROW_Z[k % 4]])
    return out


class MarkerScript:
    """Smooth scripted marker motion (jittered by the seed), X/Z in mm, dy relative to the surface."""

    def __init__(self, seed: int, timeline: Timeline, radius: float = MARKER_RADIUS):
        rng = np.random.default_rng(seed + 7)
        self.timeline = timeline
        self.radius = radius
        push_gap = PUSH_GAP if radius == MARKER_RADIUS else radius + 2.0
        self.push_gap = push_gap
        self.p0 = initial_positions(radius)
        self.funcs = {}
        for mid, keys in _SCRIPTS.items():
            s = np.array([k[0] for k in keys], float)
            jit = 1.0 + 0.08 * rng.standard_normal()
            dx = np.array([k[1] for k in keys], float) * jit
            dx[np.abs(dx) > 0] += rng.normal(0, 1.0, np.count_nonzero(np.abs(dx) > 0))
            dz = np.array([s[i] + push_gap if k[2] == "push" else k[2] for i, k in enumerate(keys)], float)
            dy = np.array([k[3] for k in keys], float)
            self.funcs[mid] = (PchipInterpolator(s, dx, extrapolate=False), PchipInterpolator(s, dz, extrapolate=False),
                               PchipInterpolator(s, dy, extrapolate=False), s[0], s[-1])

    def offsets(self, mid: int, t):
        """(dx, dz, dy) arrays for scene times t."""
        fx, fz, fy, s0, s1 = self.funcs[mid]
        s = np.clip(np.asarray(self.timeline.tool_z(t), float) - self.p0[mid][2], s0, s1)
        return fx(s), fz(s), fy(s)

    def positions_over(self, t: np.ndarray, surface: SurfaceGrid) -> dict[int, np.ndarray]:
        """Marker centres (mm, world) at scene times t: marker id -> (n, 3); in the shank's lane the shank
        front pushes a marker ahead of it (smoothly)."""
        t = np.asarray(t, float)
        zt = np.asarray(self.timeline.tool_z(t), float)
        out = {}
        for mid in MARKER_IDS:
            dx, dz, dy = (np.asarray(v, float) for v in self.offsets(mid, t))
            x = self.p0[mid][0] + dx
            z = self.p0[mid][2] + dz
            w = _smoothstep(SHANK_HALF_X + 5.0, SHANK_HALF_X + 3.0, np.abs(x - TOOL_X))
            pushed = (w > 0) & (z > zt - SHANK_CHORD)
            z = np.where(pushed, z + w * 0.7 * np.logaddexp(0.0, (zt + self.push_gap - z) / 0.7), z)
            y = surface.heights_at(x, z, zt) + self.radius + dy
            out[mid] = np.stack([x, y, z], axis=1)
        return out

    def positions(self, t: float, surface: SurfaceGrid) -> dict[int, np.ndarray]:
        """Marker centres (mm, world) at scene time t (the surface's grid state is not used)."""
        return {mid: p[0] for mid, p in self.positions_over(np.array([t], float), surface).items()}


# -- visibility ------------------------------------------------------------------------------------

def _disc_samples(n: int = 64) -> np.ndarray:
    """Equal-area points on the unit disc (Fibonacci spiral)."""
    k = np.arange(n) + 0.5
    r = np.sqrt(k / n) * 0.97
    a = k * np.pi * (3 - np.sqrt(5))
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


_DISC = _disc_samples()


def visible_fraction(cam, P: np.ndarray, zt: float, surface: SurfaceGrid, others=(),
                     radius: float = MARKER_RADIUS) -> float:
    """Fraction of the marker sphere's silhouette (centre P, world, `radius` mm) that the camera really
    sees: inside the image, not behind the tool's shank, not under or behind sand, not behind another
    marker (centres `others`, same radius)."""
    C = cam.center_mm
    e3 = C - P
    dist = np.linalg.norm(e3)
    e3 /= dist
    e1 = np.cross(e3, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(e3, e1)
    a, b = _DISC[:, 0:1], _DISC[:, 1:2]
    Q = P + radius * (a * e1 + b * e2 + np.sqrt(1 - a * a - b * b) * e3)
    px = cam.project(Q)
    ok = (px[:, 0] >= 0) & (px[:, 0] <= cam.width - 1) & (px[:, 1] >= 0) & (px[:, 1] <= cam.height - 1)
    ok &= cam.R[2] @ (P - C) > 0
    d = C - Q
    seg = np.linalg.norm(d, axis=1)
    d /= seg[:, None]
    t_box, _ = ray_box(Q, d, shank_box(zt))
    ok &= ~(t_box < seg)
    others = np.array(list(others), np.float64).reshape(-1, 3)
    if len(others):  # only spheres within two radii of the line of sight can hide part of this one
        O_all = others
        along = (O_all - P) @ e3
        off = np.linalg.norm(O_all - P - along[:, None] * e3, axis=1)
        others = O_all[(along > -2 * radius) & (off < 2 * radius + 1e-6)]
    for O in others:
        if np.linalg.norm(O - P) < 1e-9:
            continue
        oc = Q - O
        b = np.sum(d * oc, axis=1)
        disc = b * b - (np.sum(oc * oc, axis=1) - radius**2)
        t_hit = -b - np.sqrt(np.maximum(disc, 0))
        ok &= ~((disc > 0) & (t_hit > 1e-6) & (t_hit < seg))
    # sand between the point and the camera: march from Q towards the camera while below the highest sand
    top = float(surface.H.max()) + 0.5
    rise = np.where(d[:, 1] > 1e-6, (top - Q[:, 1]) / np.maximum(d[:, 1], 1e-6), 400.0)
    steps = np.arange(0.0, float(np.clip(rise.max(), 0.0, 400.0)) + 0.5, 0.5)
    pts = Q[:, None, :] + d[:, None, :] * steps[None, :, None]
    below_top = pts[..., 1] < top
    h = surface.height(pts[..., 0], pts[..., 2])
    under = (pts[..., 1] < h) & below_top
    ok &= ~under.any(axis=1)
    return float(ok.mean())
