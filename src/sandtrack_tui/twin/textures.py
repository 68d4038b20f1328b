"""Procedural textures in world coordinates: sand grains, sand bumps, plywood walls (seeded)."""

from __future__ import annotations

import cv2
import numpy as np

SAND_TEXEL_MM = 0.25  # fine grain tile: 1024 x 1024 texels = 256 mm, wrapped
SAND_TILE = 1024
COARSE_TEXEL_MM = 4.0
SAND_BGR = np.array([0.50, 0.655, 0.77], np.float32)  # dry silica sand, linear-ish display values


def _noise(rng, shape, sigma):
    """Gaussian noise blurred by `sigma` texels, periodic (tiles without seams), unit variance."""
    n = rng.standard_normal(shape)
    if sigma > 0:
        fy = np.fft.fftfreq(shape[0])[:, None]
        fx = np.fft.rfftfreq(shape[1])[None, :]
        n = np.fft.irfft2(np.fft.rfft2(n) * np.exp(-2 * np.pi**2 * sigma**2 * (fx**2 + fy**2)), s=shape)
    n = n.astype(np.float32)
    return n / (n.std() + 1e-9)


class Textures:
    def __init__(self, seed: int, sand_bgr: np.ndarray = SAND_BGR):
        rng = np.random.default_rng(seed + 11)
        n = SAND_TILE
        # grains of ~0.3-0.5 mm: per-texel values, slightly blurred, plus rare dark and bright grains
        g1 = _noise(rng, (n, n), 0.6)
        g2 = _noise(rng, (n, n), 1.4)
        lum = 1.0 + 0.10 * g1 + 0.07 * g2
        u = rng.random((n, n)).astype(np.float32)
        dark = cv2.GaussianBlur((u < 0.035).astype(np.float32), (0, 0), 0.7) * 2.2
        bright = cv2.GaussianBlur((u > 0.97).astype(np.float32), (0, 0), 0.7) * 1.6
        lum = lum * (1 - 0.45 * np.clip(dark, 0, 1)) * (1 + 0.25 * np.clip(bright, 0, 1))
        hue = _noise(rng, (n, n), 1.0)
        tex = np.empty((n, n, 3), np.float32)
        tex[..., 0] = sand_bgr[0] * lum * (1 - 0.07 * hue)
        tex[..., 1] = sand_bgr[1] * lum * (1 - 0.02 * hue)
        tex[..., 2] = sand_bgr[2] * lum * (1 + 0.03 * hue)
        self.sand = tex
        # slow brightness/tint variations over the box (pouring, moisture)
        cz, cx = int(1500 / COARSE_TEXEL_MM) + 2, int(500 / COARSE_TEXEL_MM) + 2
        self.coarse = (1.0 + 0.035 * _noise(rng, (cz, cx), 6.0) + 0.02 * _noise(rng, (cz, cx), 1.5)).astype(np.float32)
        # micro relief (mm) of the levelled surface, stored as its shading change under the lamp
        from .rig import LIGHT_DIR

        b = 0.30 * _noise(rng, (n, n), 14.0) + 0.07 * _noise(rng, (n, n), 3.0)
        bx = (np.roll(b, -1, 1) - np.roll(b, 1, 1)) / (2 * SAND_TEXEL_MM)
        bz = (np.roll(b, -1, 0) - np.roll(b, 1, 0)) / (2 * SAND_TEXEL_MM)
        self.sand4 = np.dstack([tex, -(bx * LIGHT_DIR[0] + bz * LIGHT_DIR[2])]).astype(np.float32)
        # plywood: grain streaks along the wall, knots of colour
        w = cv2.GaussianBlur(_noise(rng, (256, 1024), 0.0), (0, 0), sigmaX=90.0, sigmaY=0.7)
        w = w / (w.std() + 1e-9)
        fine = _noise(rng, (256, 1024), 0.6)
        blotch = _noise(rng, (256, 1024), 25.0)
        self.wood = (1.0 + 0.05 * w + 0.02 * fine + 0.035 * blotch).astype(np.float32)

    @staticmethod
    def _lookup(tex, u, v, wrap=True):
        mode = cv2.BORDER_WRAP if wrap else cv2.BORDER_REPLICATE
        return cv2.remap(tex, u.astype(np.float32), v.astype(np.float32), cv2.INTER_LINEAR, borderMode=mode)

    def sand_lookup(self, X, Z):
        """(h, w, 4) sand colour (BGR) and micro-relief shading change at world X, Z (mm)."""
        return self._lookup(self.sand4, X / SAND_TEXEL_MM, Z / SAND_TEXEL_MM)

    def wood_albedo(self, along, Y):
        base = np.array([0.42, 0.58, 0.70], np.float32)
        f = self._lookup(self.wood, along / 1.5, Y / 2.0)
        return f[..., None] * base
