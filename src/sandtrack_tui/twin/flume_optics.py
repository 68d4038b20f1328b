"""How the flume twin's camera sees the beads: backlight, glass beads, exposure, sensor.

The channel is lit from behind through a diffuser; the camera looks through the front wall. A glass
bead blocks the light except near its middle, where it acts as a ball lens and lets the backlight
through: a dark disc with a small bright centre. Light passes every bead on its way, so the picture is
the backlight times the product of the beads' transmissions (a bead behind another shows only where
the front one does not cover it). Each bead's transmission is radially symmetric about its projected
centre (a disc edge and a Gaussian spot, both blurred by the defocus), so its true centre is exactly
the centre of what is drawn. A moving bead is averaged over the exposure (samples from the
simulation); the backlight ripples with the mains (100 Hz) and each frame integrates its own part of
the ripple; the sensor adds shot noise, read noise, pixel gain non-uniformity and a black level, and
quantises to its bit depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import erfc


@dataclass(frozen=True)
class Optics:
    exposure_s: float = 1 / 800  # shutter: a bead at 25 px per frame (130 fps) smears 4 px
    samples: int = 9  # instants over the exposure (odd; the middle one is the frame's instant)
    camera_mm: float = 600.0  # camera to the channel's mid-plane
    defocus_px: float = 0.8  # blur (sd, px) at the mid-plane, where the lens is focused
    defocus_per_mm: float = 0.12  # more blur per mm in front of or behind it
    backlight: float = 0.8  # brightest backlight, share of the sensor's full well
    vignetting: float = 0.25  # light lost in the image corners
    gradient: tuple = (0.14, 0.06)  # backlight falling off across x and y (share over the image)
    mottle: float = 0.02  # sd of the diffuser's blotches
    ripple: float = 0.05  # mains ripple of the lamp (amplitude, share), at ripple_hz
    ripple_hz: float = 100.0
    dust: int = 14  # specks on the channel's wall (static)
    full_well_e: float = 10500.0
    read_noise_e: float = 6.0
    prnu: float = 0.008  # pixel gain non-uniformity (sd)
    black_level: float = 0.015  # dark offset, share of the full scale
    bits: int = 12


@dataclass(frozen=True)
class BeadLook:
    """Per bead: transmission of its dark body, of the middle of its bright spot, and the spot's size
    (sd, share of the bead's radius). Glass beads differ: tint, bubbles, roundness."""

    body: np.ndarray
    spot: np.ndarray
    spot_size: np.ndarray

    @classmethod
    def draw(cls, n: int, rng: np.random.Generator) -> BeadLook:
        return cls(body=rng.uniform(0.02, 0.07, n), spot=rng.uniform(0.45, 0.95, n),
                   spot_size=rng.uniform(0.10, 0.20, n))


class SideCamera:
    """A pinhole camera looking along +z at the channel (no lens distortion): `px_per_mm` at the
    mid-plane (z = channel / 2), the view's top-left corner at (x0_mm, y0_mm + height) there. Pixel
    centres are at integer coordinates."""

    def __init__(self, size: tuple, px_per_mm: float, x0_mm: float, y0_mm: float, channel_mm: float,
                 distance_mm: float):
        self.width, self.height = size
        self.f = px_per_mm * distance_mm
        self.cx, self.cy = (self.width - 1) / 2, (self.height - 1) / 2
        self.centre = np.array([x0_mm + self.width / px_per_mm / 2, y0_mm + self.height / px_per_mm / 2,
                                channel_mm / 2 - distance_mm])
        self.mid_z = channel_mm / 2

    def project(self, P: np.ndarray, radius: np.ndarray | float = 0.0):
        """Pixels (u, v) of centres P (..., 3) mm and the radius (px) of spheres of `radius` mm there
        (the silhouette as a disc: off from the exact ellipse by < 0.02 px in these views)."""
        d = P - self.centre
        depth = d[..., 2]
        u = self.cx + self.f * d[..., 0] / depth
        v = self.cy - self.f * d[..., 1] / depth
        return u, v, self.f * np.asarray(radius) / depth

    def velocity(self, P: np.ndarray, V: np.ndarray, fps: float):
        """Image velocity (px per frame) of points P moving at V (mm/s)."""
        d = P - self.centre
        depth = d[..., 2]
        du = self.f * (V[..., 0] * depth - d[..., 0] * V[..., 2]) / depth**2
        dv = -self.f * (V[..., 1] * depth - d[..., 1] * V[..., 2]) / depth**2
        return du / fps, dv / fps


def backlight(size: tuple, optics: Optics, rng: np.random.Generator) -> np.ndarray:
    """The light reaching the sensor without beads (share of full well): diffuser blotches, a
    gradient, vignetting, and dust specks on the wall."""
    w, h = size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    light = (1 - optics.vignetting * r2) * (1 - optics.gradient[0] * xx / w) * (1 - optics.gradient[1] * yy / h)
    blotch = cv2.GaussianBlur(rng.standard_normal((h, w)), (0, 0), 0.05 * max(w, h))
    light *= 1 + optics.mottle * blotch / max(float(blotch.std()), 1e-12)
    for _ in range(optics.dust):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        s, depth = rng.uniform(0.8, 2.5), rng.uniform(0.1, 0.45)
        light *= 1 - depth * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * s * s))
    return optics.backlight * light / light.max()


def lamp(t_s: float, optics: Optics, phase: float) -> float:
    """The lamp's mean brightness over an exposure starting at t_s (1 = its mean)."""
    w = 2 * math.pi * optics.ripple_hz
    e = optics.exposure_s
    if e <= 0:
        return 1 + optics.ripple * math.cos(w * t_s + phase)
    return 1 + optics.ripple * (math.sin(w * (t_s + e) + phase) - math.sin(w * t_s + phase)) / (w * e)


def apply_bead(img: np.ndarray, u: float, v: float, radius_px: float, blur_px: float, body: float, spot: float,
               spot_size: float) -> None:
    """Multiply img (H x W transmission) by one bead's transmission, centred at (u, v)."""
    h, w = img.shape
    half = int(math.ceil(radius_px + 4 * blur_px + 1))
    x0, y0 = int(math.floor(u)) - half, int(math.floor(v)) - half
    x1, y1 = x0 + 2 * half + 2, y0 + 2 * half + 2
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if xa >= xb or ya >= yb:
        return
    dx = np.arange(xa, xb) - u
    dy = np.arange(ya, yb)[:, None] - v
    rho = np.sqrt(dx * dx + dy * dy)
    cover = 0.5 * erfc((rho - radius_px) / (math.sqrt(2) * blur_px))
    s2 = (spot_size * radius_px) ** 2
    var = s2 + blur_px * blur_px
    inner = body + (spot - body) * (s2 / var) * np.exp(-0.5 * rho * rho / var)
    img[ya:yb, xa:xb] *= 1 - cover * (1 - inner)


def sensor(light: np.ndarray, optics: Optics, gain_map: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Digital numbers (0 .. 2^bits - 1) of a frame whose light is `light` (share of full well)."""
    electrons = rng.poisson(np.clip(light * gain_map, 0, None) * optics.full_well_e).astype(np.float64)
    electrons += rng.normal(0.0, optics.read_noise_e, light.shape)
    top = 2**optics.bits - 1
    dn = electrons / optics.full_well_e * top + optics.black_level * top
    return np.clip(np.round(dn), 0, top).astype(np.uint16)
