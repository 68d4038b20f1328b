"""The flume twin's beads: a soft-sphere DEM of glass beads in a narrow, tilted, water-filled channel.

A bed is made by letting beads fall into the channel and settle (a random packing of touching beads
on a floor of glued ones, its surface irregular); then water flows over it (a log-law velocity
profile above the local bed surface, turbulent fluctuations per bead), and the beads it moves roll on
the bed, hop over it (saltation: drag, lift, gravity and collisions decide the hop) and push the bed's
surface along. The channel is periodic along the flow: a bead leaving downstream comes back upstream,
out of the camera's view (the domain is longer than the view). Kernels in flume_kernels.py.

Units: mm, s, kg. Axes: x downstream along the bed, y up (normal to the bed), z across the channel
(the camera looks along +z through the wall at z = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SLOTS = 16  # contacts remembered per bead (a bead in a packing touches up to ~12)
RHO_WATER = 1.0e-6  # kg/mm3
NU_WATER = 1.0  # mm2/s
G = 9810.0  # mm/s2


@dataclass(frozen=True)
class FlumePhysics:
    bead_mm: float = 6.0  # mean diameter
    size_sd: float = 0.015  # relative sd of the diameter (clipped at +-3 %)
    rho_bead: float = 2.5e-6  # kg/mm3 (glass)
    channel_mm: float = 10.0  # between the walls (a bead can sit up to 4 mm behind another: overlaps in view)
    slope: float = 0.10  # of the channel (tan)
    bed_mm: float = 18.0  # thickness of the mobile bed before the flow starts (as if packed flat at 0.58)
    ustar_mm_s: float = 85.0  # shear velocity of the flow
    turbulence: float = 1.0  # scale of the turbulent fluctuations (sd 2 u* along the flow, 1 u* across)
    eddy_s: float = 0.025  # their correlation time
    water_mm: float = 50.0  # flow depth above the bed's zero plane (the profile stops growing there)
    roughness: float = 1 / 30  # z0 as a share of the diameter (Nikuradse: ks / 30, ks = d)
    zero_plane: float = 0.25  # the profile's origin below the bed surface, in diameters
    lift: float = 0.1  # lift coefficient
    friction: float = 0.3  # bead-bead and bead-floor (wet glass)
    wall_friction: float = 0.2  # bead-wall (glass on glass, lubricated)
    restitution: float = 0.9  # normal (glass in water at these impact speeds)
    stiffness: float = 5000.0  # normal contact stiffness, N/m (= kg/s2): overlaps ~1e-3 d at rest
    settle_s: float = 0.4
    spinup_s: float = 1.0  # flow on before the first recorded frame

    @property
    def theta(self) -> float:
        return math.atan(self.slope)


@dataclass
class FlumeRun:
    """The recorded frames: positions at each exposure sample, the mid sample being the frame's
    instant; velocities at mid-exposure; contact steps and periodic crossings per frame."""

    radius: np.ndarray  # (N,) mm
    mobile: np.ndarray  # (N,) bool (False: glued to the floor)
    pos: np.ndarray  # (F, S, N, 3) mm
    vel: np.ndarray  # (F, N, 3) mm/s at mid-exposure
    contact_steps: np.ndarray  # (F, N) steps of the frame's interval in contact with a bead or the floor
    wraps: np.ndarray  # (F, N) periodic crossings so far (at the frame's end)
    steps_per_frame: int
    dt: float
    spec: FlumePhysics
    length_mm: float

    @property
    def mid(self) -> int:
        return self.pos.shape[1] // 2


class FlumeSim:
    """The state of the bead simulation, advanced frame by frame."""

    def __init__(self, spec: FlumePhysics, length_mm: float, seed: int, fps: float):
        self.spec, self.fps, self.length_mm = spec, fps, length_mm
        self.rng = np.random.default_rng(seed + 211)
        rng = self.rng
        r0 = spec.bead_mm / 2
        vol = 4 / 3 * np.pi * r0**3
        n_mobile = int(round(0.58 * length_mm * spec.bed_mm * spec.channel_mm / vol))
        floor = self._floor_beads(r0)
        rad = r0 * (1 + np.clip(rng.normal(0, spec.size_sd, len(floor) + n_mobile), -0.03, 0.03))
        self.n_floor = len(floor)
        pos = np.zeros((len(rad), 3))
        pos[: self.n_floor] = floor
        pos[: self.n_floor, 1] = rad[: self.n_floor]  # resting on the floor
        pos[self.n_floor:] = self._loose_column(n_mobile, rad[self.n_floor:], r0)
        self.rad = rad
        self.mobile = np.arange(len(rad)) >= self.n_floor
        vol_i = 4 / 3 * np.pi * rad**3
        mass = vol_i * (spec.rho_bead + 0.5 * RHO_WATER)  # with the water it drags along (added mass)
        self.inv_m = np.where(self.mobile, 1 / mass, 0.0)
        self.inv_i = np.where(self.mobile, 1 / (0.4 * mass * rad**2), 0.0)
        self.pos, self.vel, self.omg = pos, np.zeros_like(pos), np.zeros_like(pos)
        self.wraps = np.zeros(len(rad), np.int64)
        self.partner = np.full((len(rad), SLOTS), -1, np.int64)
        self.spring = np.zeros((len(rad), SLOTS, 3))
        self.touched = np.zeros((len(rad), SLOTS), np.bool_)
        th = spec.theta
        # per unit (added) mass: whole weight along the slope, submerged weight across it (hydrostatic)
        self.gravity = np.array([spec.rho_bead * G * math.sin(th), -(spec.rho_bead - RHO_WATER) * G * math.cos(th),
                                 0.0]) / (spec.rho_bead + 0.5 * RHO_WATER)
        m_red = 0.5 * float(mass[self.mobile].mean())
        kn = spec.stiffness  # N/m = kg/s2, the same in mm units
        t_contact = math.pi * math.sqrt(m_red / kn)
        self.steps_per_frame = int(math.ceil(1 / fps / (t_contact / 15)))
        self.dt = 1 / fps / self.steps_per_frame
        ln_e = math.log(spec.restitution)
        zeta = -ln_e / math.sqrt(math.pi**2 + ln_e**2)
        self.contact = np.array([kn, 2 / 7 * kn, zeta, spec.friction])
        self.box = np.array([length_mm, spec.bed_mm * 6 + 160.0, spec.channel_mm])
        self.bin_mm = 1.0
        self.u_turb = np.zeros((len(rad), 2))
        self.in_bed = np.ones(len(rad), bool)
        self.fluid = np.array([0.0, spec.roughness * spec.bead_mm, spec.zero_plane * spec.bead_mm, spec.water_mm,
                               RHO_WATER, NU_WATER, spec.lift])

    # -- the bed --------------------------------------------------------------------------------
    def _floor_beads(self, r0: float) -> np.ndarray:
        """Beads glued to the floor along the channel, 1.04-1.56 diameters apart, at random across it
        (their radii are set with the others': placed for the largest)."""
        n = int(self.length_mm / (2 * r0 * 1.3))
        pitch = self.length_mm / n
        x = (np.arange(n) + 0.5 + self.rng.uniform(-0.1, 0.1, n)) * pitch
        z = self.rng.uniform(r0 * 1.03, self.spec.channel_mm - r0 * 1.03, n)
        return np.stack([x, np.full(n, r0), z], axis=1)

    def _loose_column(self, n: int, rad: np.ndarray, r0: float) -> np.ndarray:
        """n beads on a loose jittered lattice above the floor (no two touching), to fall and settle."""
        s = self.spec
        pitch = 2 * r0 * 1.1
        per_row = int(self.length_mm / pitch)
        k = np.arange(n)
        row, col = k // per_row, k % per_row
        x = (col + 0.5 + 0.5 * (row % 2)) * (self.length_mm / per_row) + self.rng.uniform(-0.1, 0.1, n) * pitch
        y = 3.5 * r0 + row * pitch + self.rng.uniform(-0.1, 0.1, n) * pitch
        z = self.rng.uniform(rad * 1.01, s.channel_mm - rad * 1.01)
        return np.stack([np.mod(x, self.length_mm), y, z], axis=1)

    def bed_surface(self) -> np.ndarray:
        """The bed's top (mm) per bin_mm along x: the upper envelope of the beads that touched another
        bead or the floor in the last steps (the bed and the beads rolling on it, which shield it: not
        the ones in flight), averaged over 3 diameters (periodic)."""
        s = self.spec
        nb = int(round(self.length_mm / self.bin_mm))
        top = np.full(nb, 0.0)
        p, r = self.pos[self.in_bed], self.rad[self.in_bed]
        if not len(r):  # (nothing has landed yet: the floor)
            return top
        off = np.arange(-int(np.ceil(r.max() / self.bin_mm)), int(np.ceil(r.max() / self.bin_mm)) + 1)
        xb = np.floor(p[:, 0:1] / self.bin_mm).astype(np.int64) + off[None, :]
        dx = (xb + 0.5) * self.bin_mm - p[:, 0:1]
        inside = np.abs(dx) < r[:, None]
        h = p[:, 1:2] + np.sqrt(np.maximum(r[:, None] ** 2 - dx**2, 0.0))
        np.maximum.at(top, np.mod(xb[inside], nb), h[inside])
        w = int(round(3 * s.bead_mm / self.bin_mm)) | 1
        ext = np.concatenate([top[-(w // 2):], top, top[: w // 2]])
        return np.convolve(ext, np.ones(w) / w, mode="valid")

    # -- running --------------------------------------------------------------------------------
    def _turbulence(self, dt: float) -> None:
        s = self.spec
        a = math.exp(-dt / s.eddy_s)
        sd = np.array([2.0, 1.0]) * s.ustar_mm_s * s.turbulence
        self.u_turb = a * self.u_turb + math.sqrt(1 - a * a) * sd * self.rng.standard_normal(self.u_turb.shape)

    def advance(self, n_steps: int, flow: bool, damping: float = 0.0, record_at=None):
        """Run n_steps; returns (positions, velocities) at the steps `record_at` (from 1), and the
        contact steps of each bead over the run."""
        from .flume_kernels import dem_steps  # (numba: loaded when beads are simulated)

        rec = np.asarray(record_at if record_at is not None else [], np.int64)
        rec_pos = np.zeros((len(rec), len(self.rad), 3))
        rec_vel = np.zeros_like(rec_pos)
        contact_steps = np.zeros(len(self.rad), np.int64)
        fluid = self.fluid.copy()
        fluid[0] = self.spec.ustar_mm_s if flow else 0.0
        if flow:
            self._turbulence(n_steps * self.dt)
        dem_steps(self.pos, self.vel, self.omg, self.rad, self.inv_m, self.inv_i, self.wraps, self.partner,
                  self.spring, self.touched, contact_steps, n_steps, self.dt, self.box, self.gravity, self.contact,
                  self.spec.wall_friction, self.bed_surface(), self.bin_mm, fluid,
                  self.u_turb if flow else np.zeros_like(self.u_turb), damping, rec, rec_pos, rec_vel)
        self.in_bed = contact_steps > 0
        return rec_pos, rec_vel, contact_steps

    def settle(self) -> None:
        """Let the poured beads fall and come to rest, without flow: free fall for half of settle_s,
        damped until every bead is still (or twice settle_s more), then free again for a tenth."""
        k = self.steps_per_frame
        n = int(round(self.spec.settle_s * self.fps))
        for _ in range(n // 2):
            self.advance(k, flow=False)
        for _ in range(2 * n):
            self.advance(k, flow=False, damping=30.0)
            if np.abs(self.vel).max() < 1.0:
                break
        for _ in range(max(n // 10, 1)):
            self.advance(k, flow=False)


def simulate(spec: FlumePhysics, length_mm: float, frames: int, fps: float, exposure_s: float, samples: int,
             seed: int, log=lambda msg: None) -> FlumeRun:
    """Settle a bed, run the flow for spec.spinup_s, then record `frames` frames: per frame `samples`
    positions spread evenly over the exposure (odd: the middle one is the frame's instant)."""
    sim = FlumeSim(spec, length_mm, seed, fps)
    k = sim.steps_per_frame
    log(f"flume: {len(sim.rad) - sim.n_floor} beads (+{sim.n_floor} glued), {k} steps per frame")
    sim.settle()
    for _ in range(int(round(spec.spinup_s * fps))):
        sim.advance(k, flow=True)
    mid = k // 2
    span = min(exposure_s / sim.dt, k - 2)
    at = np.unique(np.clip(np.round(mid + (np.linspace(0, 1, samples) - 0.5) * span).astype(np.int64), 1, k))
    if len(at) != samples:  # (an exposure shorter than the steps can resolve: one instant)
        at = np.full(samples, mid, np.int64)
    n = len(sim.rad)
    pos = np.zeros((frames, samples, n, 3))
    vel = np.zeros((frames, n, 3))
    contact = np.zeros((frames, n), np.int64)
    wraps = np.zeros((frames, n), np.int64)
    for f in range(frames):
        p, v, c = sim.advance(k, flow=True, record_at=at)
        pos[f], vel[f], contact[f], wraps[f] = p, v[samples // 2], c, sim.wraps
    return FlumeRun(sim.rad.copy(), sim.mobile.copy(), pos, vel, contact, wraps, k, sim.dt, spec, length_mm)
