"""Angle of repose of a simulated heap: DEM particle positions (LIGGGHTS/LAMMPS dump, exchange CSV).

1. Up is the axis along which the particles spread least (a heap is wider than tall below 63 deg),
   pointing away from the side where they spread most (the base); or given.
2. The base level is the lowest particle centres; the surface particles are the highest particle in
   each cell of a horizontal grid two particle diameters wide, so that every cell holds a particle of
   the top layer (diameter = twice the median of the radius column, else the median distance to
   the nearest neighbour). On a slope that particle sits near the cell's uphill side: the same
   offset everywhere, which does not change the angle.
3. The heap's axis is found by fitting a cone ``h = a - tan(angle) * distance from the axis`` to the
   surface particles between `band` = (0.2, 0.8) of the heap's height (soft-L1 loss): the rounded
   top and the toe, with any spilled particles, are left out.
4. Radial slices: around that axis the surface is cut into `slices` equal sectors (default: 16, fewer
   for a small heap, so that each holds about 30 surface particles in the band); in each, the
   surface particles' height against their distance from the axis is fitted by a robust line
   (`fit.robust_line`) on the same band; the slice's angle is that line's angle to the base plane.
   The angle of repose is the mean over the slices, with their standard deviation (the heap's own
   asymmetry and roughness) and the standard error of the mean.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SandtrackError
from .fit import robust_line, slope_angle_deg

BAND = (0.2, 0.8)
SLICES = 16
MIN_PARTICLES = 200
CELL_DIAMETERS = 2.0  # grid cell for the surface particles: every cell holds a particle of the top layer
NORMAL_PASSES = 2
POINTS_PER_SLICE = 30


@dataclass
class Slice:
    azimuth_deg: float  # centre of the sector, from the first horizontal axis towards the second
    angle_deg: float
    sigma_deg: float
    points: int

    def to_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class DumpResult:
    source: str
    angle_deg: float  # mean over the slices
    sd_deg: float  # spread of the slice angles
    sem_deg: float  # standard error of the mean
    cone_angle_deg: float  # one cone fitted to the whole band
    slices: list[Slice]
    up_axis: str  # e.g. "+z"
    base_mm: float
    height_mm: float
    base_radius_mm: float
    axis_mm: tuple[float, float]  # heap axis in the two horizontal coordinates
    particles: int
    surface_particles: int
    diameter_mm: float
    time: float | None = None
    band: tuple[float, float] = BAND
    warnings: list[str] = field(default_factory=list)
    surface: np.ndarray | None = None  # (n, 3): distance from the axis, height above base, azimuth (deg)

    @property
    def sigma_deg(self) -> float:
        return self.sem_deg

    def to_dict(self) -> dict:
        d = {k: v for k, v in self.__dict__.items() if k not in ("surface", "slices")}
        d["kind"] = "dump"
        d["slices"] = [s.to_dict() for s in self.slices]
        return d


AXES = "xyz"


def parse_up(spec: str) -> tuple[int, float]:
    s = spec.strip().lower()
    sign = -1.0 if s.startswith("-") else 1.0
    s = s.lstrip("+-")
    if s not in AXES or len(s) != 1:
        raise SandtrackError(f"--up {spec!r}: give x, y or z with an optional sign (e.g. z, -y)")
    return AXES.index(s), sign


def detect_up(xyz: np.ndarray) -> tuple[int, float]:
    """Axis of least extent; its sign points from the wide base to the narrow top."""
    lo, hi = np.percentile(xyz, 1, axis=0), np.percentile(xyz, 99, axis=0)
    k = int(np.argmin(hi - lo))
    h = xyz[:, k]
    others = [i for i in range(3) if i != k]
    low = xyz[h <= np.percentile(h, 20)][:, others]
    high = xyz[h >= np.percentile(h, 80)][:, others]
    return k, (1.0 if low.std(axis=0).sum() >= high.std(axis=0).sum() else -1.0)


def _diameter(uvh: np.ndarray, radius: np.ndarray | None) -> float:
    if radius is not None and np.isfinite(radius).any() and np.nanmedian(radius) > 0:
        return float(2 * np.nanmedian(radius))
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    pick = uvh[rng.choice(len(uvh), min(len(uvh), 3000), replace=False)]
    d, _ = cKDTree(uvh).query(pick, k=2)
    return float(np.median(d[:, 1]))


def surface_particles(uvh: np.ndarray, cell: float) -> np.ndarray:
    """Indices of the highest particle in each cell of a horizontal grid."""
    iu = np.floor((uvh[:, 0] - uvh[:, 0].min()) / cell).astype(np.int64)
    iv = np.floor((uvh[:, 1] - uvh[:, 1].min()) / cell).astype(np.int64)
    key = iu * (iv.max() + 1) + iv
    order = np.lexsort((uvh[:, 2], key))
    last = np.ones(len(order), bool)
    last[:-1] = key[order][1:] != key[order][:-1]
    return order[last]


def flank_surface(uvh: np.ndarray, axis: tuple[float, float], angle_rad: float, cell: float) -> np.ndarray:
    """Indices of the outermost particle in each cell of a grid laid along the flank: coordinates down
    the slope (s) and across it (arc length), outermost = furthest along the flank's outward normal.
    On the flank's own plane the choice does not depend on how far down the slope a cell is."""
    du, dv = uvh[:, 0] - axis[0], uvh[:, 1] - axis[1]
    r = np.hypot(du, dv)
    phi = np.arctan2(dv, du) + np.pi
    h = uvh[:, 2]
    c, s_ = np.cos(angle_rad), np.sin(angle_rad)
    down = r * c - h * s_
    out = r * s_ + h * c
    i_s = np.floor((down - down.min()) / cell).astype(np.int64)
    r_mid = np.maximum((i_s + 0.5) * cell, cell)  # radius of the band of cells, for their arc width
    n_arc = np.maximum(np.floor(2 * np.pi * r_mid / cell), 1.0)
    i_a = np.floor(phi / (2 * np.pi) * n_arc).astype(np.int64)
    key = i_s * (int(n_arc.max()) + 1) + i_a
    order = np.lexsort((out, key))
    last = np.ones(len(order), bool)
    last[:-1] = key[order][1:] != key[order][:-1]
    return order[last]


def _fit_cone(u, v, h, start, scale):
    from scipy.optimize import least_squares

    def res(p):
        return p[0] - p[1] * np.hypot(u - p[2], v - p[3]) - h

    sol = least_squares(res, start, loss="soft_l1", f_scale=scale)
    return sol.x


def measure_particles(xyz_mm: np.ndarray, up: str | None = None, slices: int | None = None, band=BAND,
                      radius_mm: np.ndarray | None = None, source: str = "dump",
                      time: float | None = None) -> DumpResult:
    """Angle of repose of one snapshot of a heap (see module docstring)."""
    xyz = np.asarray(xyz_mm, float)
    xyz = xyz[np.isfinite(xyz).all(axis=1)]
    if len(xyz) < MIN_PARTICLES:
        raise SandtrackError(f"{source}: {len(xyz)} particles: too few for a heap (at least {MIN_PARTICLES})")
    if slices is not None and slices < 3:
        raise SandtrackError("at least 3 slices")
    k, sign = parse_up(up) if up else detect_up(xyz)
    others = [i for i in range(3) if i != k]
    uvh = np.column_stack([xyz[:, others[0]], xyz[:, others[1]], sign * xyz[:, k]])
    diameter = _diameter(uvh, radius_mm)
    base = float(np.percentile(uvh[:, 2], 0.5))
    surf = surface_particles(uvh, CELL_DIAMETERS * diameter)
    s = uvh[surf]
    top = float(np.percentile(s[:, 2], 99.5))
    height = top - base
    if height < 3 * diameter:
        raise SandtrackError(f"{source}: the heap is only {height / diameter:.1f} particle diameters high")
    rel = (s[:, 2] - base) / height
    in_band = (rel >= band[0]) & (rel <= band[1])
    crest = s[rel >= 0.9]
    start = [top, 1.0, float(np.median(crest[:, 0])), float(np.median(crest[:, 1]))]
    a, t, cu, cv = _fit_cone(s[in_band, 0], s[in_band, 1], s[in_band, 2], start, diameter / 2)
    for _ in range(NORMAL_PASSES):  # the same, with the cells laid along the flank
        surf = flank_surface(uvh, (cu, cv), float(np.arctan(abs(t))), CELL_DIAMETERS * diameter)
        s = uvh[surf]
        # the band by distance from the axis (where the cone is 0.2-0.8 high), not by each particle's own
        # height: cutting on the fitted variable would drop the high outliers at the top and the low ones at
        # the bottom and flatten every fit
        rel = (a - abs(t) * np.hypot(s[:, 0] - cu, s[:, 1] - cv) - base) / height
        in_band = (rel >= band[0]) & (rel <= band[1])
        a, t, cu, cv = _fit_cone(s[in_band, 0], s[in_band, 1], s[in_band, 2], [a, t, cu, cv], diameter / 2)
    rel = (a - abs(t) * np.hypot(s[:, 0] - cu, s[:, 1] - cv) - base) / height
    in_band = (rel >= band[0]) & (rel <= band[1])
    cone_angle = float(np.degrees(np.arctan(abs(t))))
    r = np.hypot(s[:, 0] - cu, s[:, 1] - cv)
    az = np.degrees(np.arctan2(s[:, 1] - cv, s[:, 0] - cu)) % 360.0
    if slices is None:  # as many as keep about POINTS_PER_SLICE surface particles in each
        slices = int(np.clip(in_band.sum() // POINTS_PER_SLICE, 4, SLICES))
    width = 360.0 / slices
    out: list[Slice] = []
    warnings: list[str] = []
    for j in range(slices):
        m = in_band & (az >= j * width) & (az < (j + 1) * width)
        try:
            fit = robust_line(r[m], s[m, 2])
        except SandtrackError:
            warnings.append(f"slice at {(j + 0.5) * width:.0f} deg has too few surface particles")
            continue
        ang, sig = slope_angle_deg(fit)
        if fit.slope >= 0:
            warnings.append(f"slice at {(j + 0.5) * width:.0f} deg does not descend from the axis")
            continue
        out.append(Slice((j + 0.5) * width, ang, sig, int(m.sum())))
    if len(out) < max(3, slices // 2):
        raise SandtrackError(f"{source}: only {len(out)} of {slices} slices could be fitted: is this a heap?")
    angles = np.array([sl.angle_deg for sl in out])
    sd = float(angles.std(ddof=1))
    toe = float(np.percentile(r[(rel > 0.02) & (rel < 0.1)], 50)) if ((rel > 0.02) & (rel < 0.1)).any() else np.nan
    res = DumpResult(source, float(angles.mean()), sd, sd / np.sqrt(len(out)), cone_angle, out,
                     f"{'+' if sign > 0 else '-'}{AXES[k]}", base, height, toe, (float(cu), float(cv)), len(xyz),
                     len(surf), diameter, time, tuple(band), warnings,
                     np.column_stack([r, s[:, 2] - base, az]))
    return res
