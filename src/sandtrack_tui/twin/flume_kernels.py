"""Compiled inner loop of the flume twin's bead simulation (flume_physics.py): soft-sphere DEM steps.

Units: mm, s, kg (forces in kg mm / s^2). Beads are spheres in a channel between two walls (z = 0 and
z = width) above a floor (y = 0), periodic along x. Contacts: linear spring-dashpot along the normal,
Cundall-Strack tangential spring capped by Coulomb friction (its history kept per contact in
`partner`/`spring` slots), with torques, so beads roll. The fluid acts on each bead through a drag
and a lift computed from a log-law velocity profile above the local bed surface (`bed_top`, one value
per `bin_mm` along x) plus a turbulent fluctuation per bead (`u_turb`); gravity is submerged in the
bed-normal direction (hydrostatic pressure), whole along the slope.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import jit

WALL_LO, WALL_HI, FLOOR = -2, -3, -4  # partner ids of the channel's walls and floor
KAPPA = 0.41
# Chebyshev (second kind) nodes over a bead's height and their chord weights: a bead-averaged flow speed.
_NODES = np.cos(np.arange(1, 6) * np.pi / 6)
_WEIGHTS = np.sin(np.arange(1, 6) * np.pi / 6) ** 2 / np.sum(np.sin(np.arange(1, 6) * np.pi / 6) ** 2)


@jit
def log_law(h, ustar, z0, depth):
    """Streamwise flow speed (mm/s) at height h (mm) above the bed's zero plane; nil below it, constant
    above the water depth."""
    if h <= 0.0:
        return 0.0
    return ustar / KAPPA * math.log(1.0 + min(h, depth) / z0)


@jit
def bed_level(bed_top, bin_mm, x):
    """The bed surface (mm) at x, linear between bins, periodic."""
    n = bed_top.shape[0]
    g = x / bin_mm
    i = int(math.floor(g))
    f = g - i
    i0 = i % n
    i1 = (i + 1) % n
    return bed_top[i0] * (1.0 - f) + bed_top[i1] * f


@jit
def fluid_force(x, y, vx, vy, vz, r, bed_top, bin_mm, fluid, u_tx, u_ty, out):
    """Drag and lift on one bead (into out[0:3]). fluid = (ustar, z0, zero_plane_below_top, depth,
    rho_f, nu, lift_coef)."""
    ustar, z0, zd, depth, rho_f, nu, c_lift = fluid[0], fluid[1], fluid[2], fluid[3], fluid[4], fluid[5], fluid[6]
    y0 = bed_level(bed_top, bin_mm, x) - zd
    h = y - y0
    u = 0.0
    for k in range(5):
        u += _WEIGHTS[k] * log_law(h + r * _NODES[k], ustar, z0, depth)
    expo = min(max((h + r) / (2.0 * r), 0.0), 1.0)
    wx = u + expo * u_tx - vx
    wy = expo * u_ty - vy
    wz = -vz
    w = math.sqrt(wx * wx + wy * wy + wz * wz)
    area = math.pi * r * r
    fx = fy = fz = 0.0
    if w > 1e-9:
        re = w * 2.0 * r / nu
        cd = 24.0 / re * (1.0 + 0.15 * re ** 0.687) if re < 1000.0 else 0.44
        c = 0.5 * rho_f * cd * area * w
        fx, fy, fz = c * wx, c * wy, c * wz
    top = log_law(h + r, ustar, z0, depth) - vx
    bottom = log_law(h - r, ustar, z0, depth) - vx
    fy += 0.5 * rho_f * c_lift * area * (top * top - bottom * bottom)
    out[0], out[1], out[2] = fx, fy, fz


@jit
def _slot(partner, i, j):
    """The contact slot of bead i holding partner j (a new one, its spring zeroed by the caller, if none)."""
    free = -1
    for s in range(partner.shape[1]):
        if partner[i, s] == j:
            return s, False
        if free < 0 and partner[i, s] == -1:
            free = s
    if free >= 0:
        partner[i, free] = j
    return free, True


@jit
def _contact(i, j, nx, ny, nz, delta, ri, rj, vel, omg, inv_m, spring, s, fresh, dt, contact, out):
    """Force on bead i (and its torque, out[3:6]) from a contact of normal n (from i to the partner),
    overlap delta; the partner j < 0 is a wall or the floor (at rest, unmoving). Updates the slot's
    tangential spring. contact = (kn, kt, damping ratio, mu)."""
    kn, kt, zeta, mu = contact[0], contact[1], contact[2], contact[3]
    vjx = vjy = vjz = 0.0
    wjx = wjy = wjz = 0.0
    inv_sum = inv_m[i]
    if j >= 0:
        vjx, vjy, vjz = vel[j, 0], vel[j, 1], vel[j, 2]
        wjx, wjy, wjz = omg[j, 0], omg[j, 1], omg[j, 2]
        inv_sum += inv_m[j]
    m_red = 1.0 / inv_sum
    # relative velocity of i's surface against the partner's at the contact point
    ax = ri * omg[i, 0] + rj * wjx
    ay = ri * omg[i, 1] + rj * wjy
    az = ri * omg[i, 2] + rj * wjz
    rvx = vel[i, 0] - vjx + (ay * nz - az * ny)
    rvy = vel[i, 1] - vjy + (az * nx - ax * nz)
    rvz = vel[i, 2] - vjz + (ax * ny - ay * nx)
    vn = rvx * nx + rvy * ny + rvz * nz  # > 0: approaching
    tx, ty, tz = rvx - vn * nx, rvy - vn * ny, rvz - vn * nz
    gn = 2.0 * zeta * math.sqrt(m_red * kn)
    fn = kn * delta + gn * vn
    if fn < 0.0:
        fn = 0.0
    # tangential spring: carried in the tangent plane, stretched by the sliding velocity
    if fresh:
        spring[i, s, 0] = spring[i, s, 1] = spring[i, s, 2] = 0.0
    sx, sy, sz = spring[i, s, 0], spring[i, s, 1], spring[i, s, 2]
    norm0 = math.sqrt(sx * sx + sy * sy + sz * sz)
    sn = sx * nx + sy * ny + sz * nz
    sx, sy, sz = sx - sn * nx, sy - sn * ny, sz - sn * nz
    norm1 = math.sqrt(sx * sx + sy * sy + sz * sz)
    if norm1 > 1e-15:
        sx, sy, sz = sx * norm0 / norm1, sy * norm0 / norm1, sz * norm0 / norm1
    sx += tx * dt
    sy += ty * dt
    sz += tz * dt
    gt = 2.0 * zeta * math.sqrt(m_red * kt)
    ftx, fty, ftz = -kt * sx - gt * tx, -kt * sy - gt * ty, -kt * sz - gt * tz
    ft = math.sqrt(ftx * ftx + fty * fty + ftz * ftz)
    cap = mu * fn
    if ft > cap:
        if ft > 1e-15:
            ftx, fty, ftz = ftx * cap / ft, fty * cap / ft, ftz * cap / ft
        sx, sy, sz = -ftx / kt, -fty / kt, -ftz / kt  # slipping: the spring holds what friction allows
    spring[i, s, 0], spring[i, s, 1], spring[i, s, 2] = sx, sy, sz
    out[0] = -fn * nx + ftx
    out[1] = -fn * ny + fty
    out[2] = -fn * nz + ftz
    # torque on i: (ri n) x Ft
    out[3] = ri * (ny * ftz - nz * fty)
    out[4] = ri * (nz * ftx - nx * ftz)
    out[5] = ri * (nx * fty - ny * ftx)


@jit
def dem_steps(pos, vel, omg, rad, inv_m, inv_i, wraps, partner, spring, touched, contact_steps,
              n_steps, dt, box, gravity, contact, wall_mu, bed_top, bin_mm, fluid, u_turb, damping,
              rec_at, rec_pos, rec_vel):
    """Advance every bead n_steps of dt (semi-implicit Euler). box = (length, height of the cell grid,
    channel width); gravity (3,): the body force per unit mass (flume_physics: the submerged weight over
    the mass with added mass); inv_m = 0 for beads glued to the floor. `damping` (1/s): a global viscous
    damping (settling only). Positions at the steps in `rec_at` (ascending, counted from 1) go to
    rec_pos / rec_vel. contact_steps[i] counts the steps bead i touched another bead or the floor;
    wraps[i] counts its crossings of the periodic end (+1 downstream)."""
    n = pos.shape[0]
    length, height, width = box[0], box[1], box[2]
    rmax = 0.0
    for i in range(n):
        rmax = max(rmax, rad[i])
    cell = 2.0 * rmax * 1.02
    ncx = max(int(length / cell), 3)
    ncy = max(int(height / cell), 1)
    cwx = length / ncx
    head = np.empty(ncx * ncy, np.int64)
    nxt = np.empty(n, np.int64)
    cx = np.empty(n, np.int64)
    cy = np.empty(n, np.int64)
    force = np.zeros((n, 3))
    torque = np.zeros((n, 3))
    in_contact = np.zeros(n, np.bool_)
    tmp = np.zeros(6)
    fl = np.zeros(3)
    wall = np.array([contact[0], contact[1], contact[2], wall_mu])
    r_next = 0
    for step in range(n_steps):
        head[:] = -1
        for i in range(n):
            a = int(pos[i, 0] / cwx) % ncx
            b = min(max(int(pos[i, 1] / cell), 0), ncy - 1)
            cx[i], cy[i] = a, b
            c = b * ncx + a
            nxt[i] = head[c]
            head[c] = i
        force[:, :] = 0.0
        torque[:, :] = 0.0
        touched[:, :] = False
        in_contact[:] = False
        for i in range(n):
            if inv_m[i] > 0:
                fluid_force(pos[i, 0], pos[i, 1], vel[i, 0], vel[i, 1], vel[i, 2], rad[i], bed_top, bin_mm, fluid,
                            u_turb[i, 0], u_turb[i, 1], fl)
                m = 1.0 / inv_m[i]
                for k in range(3):
                    force[i, k] += fl[k] + m * gravity[k] - damping * m * vel[i, k]
        for i in range(n):
            for dxc in range(-1, 2):
                a = (cx[i] + dxc) % ncx
                for dyc in range(-1, 2):
                    b = cy[i] + dyc
                    if b < 0 or b >= ncy:
                        continue
                    j = head[b * ncx + a]
                    while j >= 0:
                        if j > i and (inv_m[i] > 0 or inv_m[j] > 0):
                            dx = pos[j, 0] - pos[i, 0]
                            if dx > 0.5 * length:
                                dx -= length
                            elif dx < -0.5 * length:
                                dx += length
                            dy = pos[j, 1] - pos[i, 1]
                            dz = pos[j, 2] - pos[i, 2]
                            d2 = dx * dx + dy * dy + dz * dz
                            rs = rad[i] + rad[j]
                            if d2 < rs * rs:
                                d = math.sqrt(d2)
                                s, fresh = _slot(partner, i, j)
                                if s >= 0:
                                    touched[i, s] = True
                                    _contact(i, j, dx / d, dy / d, dz / d, rs - d, rad[i], rad[j], vel, omg,
                                             inv_m, spring, s, fresh, dt, contact, tmp)
                                    for k in range(3):
                                        force[i, k] += tmp[k]
                                        force[j, k] -= tmp[k]
                                        torque[i, k] += tmp[3 + k]
                                        torque[j, k] += tmp[3 + k] * rad[j] / rad[i]
                                in_contact[i] = True
                                in_contact[j] = True
                        j = nxt[j]
            if inv_m[i] <= 0:
                continue
            r = rad[i]
            for side in range(2):
                nz = -1.0 if side == 0 else 1.0
                delta = r - pos[i, 2] if side == 0 else pos[i, 2] + r - width
                if delta > 0.0:
                    pid = WALL_LO if side == 0 else WALL_HI
                    s, fresh = _slot(partner, i, pid)
                    if s >= 0:
                        touched[i, s] = True
                        _contact(i, pid, 0.0, 0.0, nz, delta, r, 0.0, vel, omg, inv_m, spring, s, fresh, dt,
                                 wall, tmp)
                        for k in range(3):
                            force[i, k] += tmp[k]
                            torque[i, k] += tmp[3 + k]
            delta = r - pos[i, 1]
            if delta > 0.0:
                s, fresh = _slot(partner, i, FLOOR)
                if s >= 0:
                    touched[i, s] = True
                    _contact(i, FLOOR, 0.0, -1.0, 0.0, delta, r, 0.0, vel, omg, inv_m, spring, s, fresh, dt,
                             contact, tmp)
                    for k in range(3):
                        force[i, k] += tmp[k]
                        torque[i, k] += tmp[3 + k]
                in_contact[i] = True
        for i in range(n):
            for s in range(partner.shape[1]):
                if not touched[i, s]:
                    partner[i, s] = -1
            if inv_m[i] <= 0:
                vel[i, :] = 0.0
                omg[i, :] = 0.0
                continue
            if in_contact[i]:
                contact_steps[i] += 1
            for k in range(3):
                vel[i, k] += force[i, k] * inv_m[i] * dt
                omg[i, k] += torque[i, k] * inv_i[i] * dt
                pos[i, k] += vel[i, k] * dt
            if pos[i, 0] >= length:
                pos[i, 0] -= length
                wraps[i] += 1
            elif pos[i, 0] < 0.0:
                pos[i, 0] += length
                wraps[i] -= 1
        while r_next < rec_at.shape[0] and rec_at[r_next] == step + 1:
            rec_pos[r_next, :, :] = pos
            rec_vel[r_next, :, :] = vel
            r_next += 1
