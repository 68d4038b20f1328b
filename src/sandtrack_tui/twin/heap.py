"""A heap of sand on a plate, photographed from the side: the angle-of-repose twin.

World frame (mm): origin on the plate at the heap's axis, Y up, X to the right as the camera sees
it, +Z towards the camera. A vertical backdrop stands behind the heap; a lamp at a finite distance
lights the scene (brightness falls off with distance: uneven light) and casts the heap's shadow on
the plate and the backdrop.

The heap's surface is ``Y = h(r, phi)`` around a vertical axis. Along each meridian (azimuth phi
from +X) it is exactly straight between a rounded top and a toe, with slope ``tan(angle(phi))``:

- top, ``r < top_mm``: a paraboloid cap meeting the flank with the same slope;
- flank: a straight line, the angle of repose;
- toe, the last ``toe_mm`` of the radius: a parabola flattening to the plate at ``r = R(phi)``.

The apex height is the same for every azimuth, so an asymmetric heap has a longer base on its
shallower side. The angle is the right flank's for |phi| <= 60 deg and the left flank's for
|phi| >= 120 deg, blended in between: the silhouette seen from the side (any camera height)
lies inside those constant sectors, where the surface is exactly a cone of the flank's angle.
Grain-scale roughness (zero mean, ~``rough_mm``) makes the outline ragged as on real sand.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..camera import Camera
from .rig import INTRINSICS, look_at, pixel_rays


@dataclass(frozen=True)
class Heap:
    height_mm: float = 70.0  # apex above the plate
    angle_left_deg: float = 34.0  # flank facing -X (left in the photo)
    angle_right_deg: float = 34.0
    top_mm: float = 14.0  # radius of the rounded cap
    toe_mm: float = 16.0  # radial width of the toe
    rough_mm: float = 0.35  # RMS height of the grain-scale roughness
    rough_seed: int = 0

    @property
    def angle_deg(self) -> float:
        return 0.5 * (self.angle_left_deg + self.angle_right_deg)

    def slope(self, cos_phi):
        """tan(angle) of the flank at the azimuth whose cosine is cos_phi (phi from +X)."""
        tl, tr = np.tan(np.radians(self.angle_left_deg)), np.tan(np.radians(self.angle_right_deg))
        s = np.clip(np.asarray(cos_phi, float) + 0.5, 0.0, 1.0)
        return tl + (tr - tl) * (s * s * (3 - 2 * s))

    def base_radius(self, cos_phi):
        """Radius where the toe meets the plate."""
        return self.height_mm / self.slope(cos_phi) + 0.5 * (self.top_mm + self.toe_mm)

    def profile(self, r, cos_phi):
        """Smooth surface height (mm) at radius r (no roughness); 0 beyond the toe."""
        t = self.slope(cos_phi)
        rb = self.height_mm / t + 0.5 * (self.top_mm + self.toe_mm)
        r = np.asarray(r, float)
        top = self.height_mm - t * r * r / (2 * self.top_mm)
        flank = self.height_mm - t * (r - 0.5 * self.top_mm)
        toe = t * np.maximum(rb - r, 0.0) ** 2 / (2 * self.toe_mm)
        return np.where(r < self.top_mm, top, np.where(r < rb - self.toe_mm, flank, toe))

    def max_radius(self) -> float:
        return float(max(self.base_radius(1.0), self.base_radius(-1.0)))


@functools.lru_cache(maxsize=4)
def _roughness_tile(seed: int) -> np.ndarray:
    """Unit-RMS grain-scale roughness, a periodic 1024 x 1024 tile (512 mm at 0.5 mm)."""
    from .textures import _noise

    rng = np.random.default_rng(7919 + seed)
    r = 0.8 * _noise(rng, (1024, 1024), 1.5) + 0.6 * _noise(rng, (1024, 1024), 5.0)
    return (r / r.std()).astype(np.float32)


@dataclass
class HeapSurface:
    """The heap's height field with its roughness: h(X, Z) in mm, vectorised."""

    heap: Heap
    texel_mm: float = 0.5
    _rough: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        self._rough = _roughness_tile(self.heap.rough_seed) * np.float32(self.heap.rough_mm)

    def rough(self, X, Z):
        """Bilinear lookup in the periodic roughness tile."""
        g = self._rough
        ny, nx = g.shape
        u = np.asarray(X, float) / self.texel_mm
        v = np.asarray(Z, float) / self.texel_mm
        u0, v0 = np.floor(u), np.floor(v)
        fu, fv = u - u0, v - v0
        i0, j0 = u0.astype(np.int64) % nx, v0.astype(np.int64) % ny
        i1, j1 = (i0 + 1) % nx, (j0 + 1) % ny
        return ((g[j0, i0] * (1 - fu) + g[j0, i1] * fu) * (1 - fv)
                + (g[j1, i0] * (1 - fu) + g[j1, i1] * fu) * fv)

    def height(self, X, Z):
        X, Z = np.asarray(X, float), np.asarray(Z, float)
        r = np.hypot(X, Z)
        c = X / np.maximum(r, 1e-9)
        t = self.heap.slope(c)
        rb = self.heap.height_mm / t + 0.5 * (self.heap.top_mm + self.heap.toe_mm)
        inside = r < rb
        out = np.zeros_like(r)
        if inside.any():
            ri, ci = r[inside], c[inside]
            taper = np.clip((rb[inside] - ri) / self.heap.toe_mm, 0.0, 1.0)  # roughness fades out at the plate
            out[inside] = self.heap.profile(ri, ci) + self.rough(X[inside], Z[inside]) * taper
        return out


@dataclass(frozen=True)
class Shot:
    """Camera placement and scene for one photo."""

    distance_mm: float = 650.0  # camera centre to the heap's axis, horizontally
    camera_height_mm: float = 45.0  # above the plate
    target_height_mm: float = 45.0  # the camera looks at this point on the axis (level when equal)
    roll_deg: float = 0.0
    lamp_mm: tuple = (-380.0, 520.0, 420.0)
    lamp_power: float = 1.0
    backdrop_z_mm: float = -260.0
    backdrop_bgr: tuple = (0.74, 0.75, 0.76)
    plate_bgr: tuple = (0.30, 0.31, 0.33)
    sand_tint: tuple = (1.0, 1.0, 1.0)
    width: int = 1920
    height: int = 1080

    def camera(self) -> Camera:
        """The study's side camera (GoPro intrinsics) at this placement; scaled for smaller images."""
        k = INTRINSICS["side"]
        s = self.width / 1920.0
        K = np.array([[k["fx"] * s, 0, k["cx"] * s], [0, k["fy"] * s, k["cy"] * self.height / 1080.0], [0, 0, 1.0]])
        R, t = look_at((0.0, self.camera_height_mm, self.distance_mm), (0.0, self.target_height_mm, 0.0),
                       self.roll_deg)
        return Camera("side", self.width, self.height, K, np.zeros(5), cv2.Rodrigues(R)[0].ravel(), t)


AMBIENT = 0.30


def _cylinder_span(C, d, radius, y_top):
    """Ray parameter interval inside the cylinder r <= radius, 0 <= Y <= y_top (empty: lo >= hi)."""
    a = d[:, 0] ** 2 + d[:, 2] ** 2
    b = 2 * (C[..., 0] * d[:, 0] + C[..., 2] * d[:, 2])
    c = C[..., 0] ** 2 + C[..., 2] ** 2 - radius ** 2
    disc = b * b - 4 * a * c
    sq = np.sqrt(np.maximum(disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        lo = np.where(disc > 0, (-b - sq) / (2 * a), np.inf)
        hi = np.where(disc > 0, (-b + sq) / (2 * a), -np.inf)
        ty0 = (0.0 - C[..., 1]) / d[:, 1]
        ty1 = (y_top - C[..., 1]) / d[:, 1]
    ylo, yhi = np.minimum(ty0, ty1), np.maximum(ty0, ty1)
    flat = np.abs(d[:, 1]) < 1e-12
    inside = (C[..., 1] >= 0) & (C[..., 1] <= y_top)
    ylo = np.where(flat, np.where(inside, -np.inf, np.inf), ylo)
    yhi = np.where(flat, np.where(inside, np.inf, -np.inf), yhi)
    return np.maximum(np.maximum(lo, ylo), 0.0), np.minimum(hi, yhi)


def march(surface: HeapSurface, C, d, lo, hi, step_mm: float = 2.0, bisect: int = 14):
    """First point where rays C + s d go below the heap surface within [lo, hi]: (s, found)."""
    n = len(d)
    C = np.broadcast_to(np.asarray(C, float), d.shape)
    s_hit = np.full(n, np.inf)
    found = np.zeros(n, bool)
    idx = np.nonzero(hi > lo)[0]
    if len(idx) == 0:
        return s_hit, found
    Ci, di, a, b = C[idx], d[idx], lo[idx], hi[idx]

    def below(k, s):
        P = Ci[k] + s[:, None] * di[k]
        return P[:, 1] < surface.height(P[:, 0], P[:, 2])

    lo_s, hi_s = a.copy(), a.copy()
    got = np.zeros(len(idx), bool)
    s_prev = a.copy()
    for k in range(int(np.ceil((b - a).max() / step_mm)) + 2):
        todo = np.nonzero(~got & (a + (k - 1) * step_mm < b))[0]
        if len(todo) == 0:
            break
        s = np.minimum(a[todo] + k * step_mm, b[todo])
        new = todo[below(todo, s)]
        lo_s[new], hi_s[new] = s_prev[new], np.minimum(a[new] + k * step_mm, b[new])
        got[new] = True
        s_prev[todo] = s
    g = np.nonzero(got)[0]
    for _ in range(bisect):
        mid = 0.5 * (lo_s[g] + hi_s[g])
        m = below(g, mid)
        hi_s[g] = np.where(m, mid, hi_s[g])
        lo_s[g] = np.where(m, lo_s[g], mid)
    s_hit[idx[g]] = hi_s[g]
    found[idx[g]] = True
    return s_hit, found


def render_heap(heap: Heap, shot: Shot, seed: int = 0, textures=None, rays=None) -> np.ndarray:
    """A BGR uint8 photo of the heap. `rays`: the camera's (centre, directions) when rendering many frames."""
    from .textures import Textures

    cam = shot.camera()
    surface = HeapSurface(heap)
    tex = textures or Textures(seed)
    C, d = rays if rays is not None else pixel_rays(cam)
    h, w = cam.height, cam.width
    d = d.reshape(-1, 3)
    n = len(d)
    Rmax, Ytop = heap.max_radius() + 1.0, heap.height_mm + 4 * heap.rough_mm + 1.0
    lo, hi = _cylinder_span(C, d, Rmax, Ytop)
    s_heap, on_heap = march(surface, C, d, lo, hi)
    # plate (Y = 0) and backdrop (Z = backdrop_z)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_plate = np.where(d[:, 1] < 0, -C[1] / d[:, 1], np.inf)
        s_back = np.where(d[:, 2] < 0, (shot.backdrop_z_mm - C[2]) / d[:, 2], np.inf)
    P_plate = C + np.nan_to_num(s_plate, posinf=0)[:, None] * d
    s_plate = np.where(P_plate[:, 2] > shot.backdrop_z_mm, s_plate, np.inf)
    s_min = np.minimum.reduce([s_heap, s_plate, s_back])
    kind = np.select([on_heap & (s_heap <= s_min), s_plate <= s_min, np.isfinite(s_back)], [0, 1, 2], 3)
    s = np.where(kind == 3, 1000.0, s_min)
    P = C + s[:, None] * d
    # normals
    nrm = np.zeros((n, 3))
    nrm[kind == 1] = (0, 1, 0)
    nrm[kind == 2] = (0, 0, 1)
    hp = kind == 0
    if hp.any():
        e = 0.05
        X, Z = P[hp, 0], P[hp, 2]
        gx = (surface.height(X + e, Z) - surface.height(X - e, Z)) / (2 * e)
        gz = (surface.height(X, Z + e) - surface.height(X, Z - e)) / (2 * e)
        v = np.stack([-gx, np.ones_like(gx), -gz], 1)
        nrm[hp] = v / np.linalg.norm(v, axis=1, keepdims=True)
    lamp = np.asarray(shot.lamp_mm, float)
    to_lamp = lamp - P
    dist = np.linalg.norm(to_lamp, axis=1)
    ldir = to_lamp / dist[:, None]
    lamb = np.clip((nrm * ldir).sum(1), 0, 1)
    # cast shadows: rays towards the lamp that pass under the heap surface
    lit = np.ones(n)
    cand = (kind <= 2) & (lamb > 0)
    if cand.any():
        start = P[cand] + ldir[cand] * 0.3 + nrm[cand] * 0.05
        l2, h2 = _cylinder_span(start, ldir[cand], Rmax, Ytop)
        h2 = np.minimum(h2, dist[cand])
        _, blocked = march(surface, start, ldir[cand], l2, h2, step_mm=2.0, bisect=0)
        lit[np.nonzero(cand)[0][blocked]] = 0.0
    lit = cv2.GaussianBlur(lit.reshape(h, w).astype(np.float32), (0, 0), 1.2).ravel()  # the lamp is not a point
    d0 = np.linalg.norm(lamp)
    light = shot.lamp_power * (d0 / dist) ** 2 * lamb * lit
    # the crease between heap and plate gets less ambient light
    r = np.hypot(P[:, 0], P[:, 2])
    rb = heap.base_radius(P[:, 0] / np.maximum(r, 1e-9))
    ao = np.where(kind == 1, 1 - 0.35 * np.exp(-np.maximum(r - rb, 0) / 12.0), 1.0)
    ao = np.where(kind == 0, 1 - 0.25 * np.exp(-np.maximum(P[:, 1], 0) / 8.0), ao)
    shade = (AMBIENT * ao + 0.85 * light)[:, None]
    albedo = np.zeros((n, 3), np.float32)
    if hp.any():  # grain texture in world coordinates (the flanks' own height spreads it on steep parts)
        s4 = tex.sand_lookup(P[:, 0].reshape(h, w) + 200.0, (P[:, 2] + 0.7 * P[:, 1]).reshape(h, w) + 200.0)
        albedo[hp] = s4[..., :3].reshape(-1, 3)[hp] * np.asarray(shot.sand_tint, np.float32)
    rng = np.random.default_rng(seed + 101)
    albedo[kind == 1] = np.asarray(shot.plate_bgr, np.float32)
    albedo[kind == 2] = np.asarray(shot.backdrop_bgr, np.float32)
    albedo[kind == 3] = (0.05, 0.05, 0.05)
    col = (albedo * shade).reshape(h, w, 3)
    plate_tex = 1 + 0.04 * cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 2.0)
    col = np.where((kind == 1).reshape(h, w, 1), col * plate_tex[..., None], col)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    col = col * (1.0 - 0.25 * r2 ** 1.4)[..., None]
    col = cv2.GaussianBlur(col.astype(np.float32), (0, 0), 0.6)
    img = col * 255.0 + rng.normal(0.0, 2.0, col.shape)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)

