"""The heap's silhouette in a side photo, and its top outline to a fraction of a pixel.

1. What the heap is not: the colours along the image's border (backdrop above, plate below, both
   sides) are clustered (k-means on chromaticity, log intensity and grain texture). A pixel far from
   every border cluster is heap-like. A shadow or uneven light scales the three colour channels
   alike, which leaves the chromaticity unchanged and only shifts the log intensity (weighted low);
   the border clusters span whatever light the backdrop receives. Otsu's threshold on that
   distance, and the largest connected part, give a first mask on a reduced image.
2. GrabCut (OpenCV), started from that mask (its eroded core certain heap, far pixels certain
   background), refines it at full resolution on a crop around the heap, on the chromaticity and log
   intensity: colour models of heap and background learned from this very image, and a smooth
   boundary.
3. The outline is the top edge of the mask per image column, refined to a fraction of a pixel:
   across the edge each pixel is taken as a mix of the background just above and the heap just
   below (`subpixel_edges`), and the edge lies where the summed background fractions put it. This
   does not depend on how bright either side is, so a flank that darkens along its length, or meets
   a shadow on the backdrop, is not tilted.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import SandtrackError

WORK_PX = 640  # long side of the reduced image for the first mask
BORDER_FRACTION = 0.04
DARK_LEVEL = 4.0  # added to every channel: near-black pixels have no meaningful colour
TEXTURE_WEIGHT = 10.0  # low: the edges of shadows and of the plate have local contrast too
OPEN_FRACTION = 0.01  # masks are opened with a disk of this share of the image's long side
MIN_AREA_FRACTION = 0.002
EDGE_WIN = 5  # +- rows mixed across the edge
EDGE_REF_NEAR, EDGE_REF_FAR = 6, 12  # rows of pure background above / heap below the edge
EDGE_POOL = 10  # +- columns pooled for the two sides' colour statistics
MIN_SEPARATION = 16.0  # squared Mahalanobis distance between the sides (4 standard deviations)


@dataclass
class Outline:
    x: np.ndarray  # image column of each outline point (px)
    y: np.ndarray  # top edge in that column, sub-pixel (px, pixel centres at integers)
    touches: set  # image borders the heap reaches: "left", "right", "top"
    bbox: tuple  # x0, y0, x1, y1 of the heap mask
    area_px: int
    mask_crop: np.ndarray  # the heap mask inside bbox (bool)


def _open(mask: np.ndarray, long_side: int) -> np.ndarray:
    """Morphological opening with a disk: removes thin slivers (a shadow's edge, the plate's far edge)
    and leaves a straight flank where it is; the rounded apex and toe are not fitted anyway."""
    r = max(1, int(round(OPEN_FRACTION * long_side)))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    return cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, disk) > 0


def _largest(mask: np.ndarray) -> np.ndarray:
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros(mask.shape, bool)
    return lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


def _chroma(img: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Chromaticity (r, g: each channel's share of the sum) and log intensity of a lightly smoothed image.
    A shadow or a brighter lamp scales all three channels alike: the chromaticity stays."""
    f = cv2.blur(img.astype(np.float32), (3, 3))
    total = f.sum(2) + 3 * DARK_LEVEL
    r = (f[..., 2] + DARK_LEVEL) / total
    g = (f[..., 1] + DARK_LEVEL) / total
    return r, g, np.log(total / 3.0)


def _features(img: np.ndarray) -> np.ndarray:
    """Per pixel: chromaticity (1 unit = 0.01), log intensity (a shadow halving the light = 1.4 units) and
    the grain texture (local contrast relative to the brightness, floored against dark-pixel noise)."""
    r, g, log_i = _chroma(img)
    i = np.exp(log_i)
    m = cv2.blur(i, (5, 5))
    contrast = np.sqrt(np.maximum(cv2.blur(i * i, (5, 5)) - m * m, 0.0)) / (m + 20.0)
    return np.dstack([(r - 1 / 3) * 100.0, (g - 1 / 3) * 100.0, log_i * 2.0, contrast * TEXTURE_WEIGHT]).astype(
        np.float32)


def _grabcut_image(img: np.ndarray) -> np.ndarray:
    """The 8-bit three-channel image GrabCut models: chromaticity (stretched) and log intensity."""
    r, g, log_i = _chroma(img)
    return np.dstack([128 + (r - 1 / 3) * 700.0, 128 + (g - 1 / 3) * 700.0, log_i * 40.0]).clip(0, 255).astype(
        np.uint8)


def first_mask(img: np.ndarray) -> tuple[np.ndarray, float]:
    """Heap-like pixels on a reduced copy of the image: (mask, reduction factor)."""
    h, w = img.shape[:2]
    s = min(1.0, WORK_PX / max(h, w))
    small = cv2.resize(img, (max(round(w * s), 8), max(round(h * s), 8)), interpolation=cv2.INTER_AREA)
    feat = _features(small)
    hh, ww = feat.shape[:2]
    b = max(2, round(BORDER_FRACTION * min(hh, ww)))
    border = np.zeros((hh, ww), bool)
    border[:b] = border[-b:] = True
    border[:, :b] = border[:, -b:] = True
    samples = feat[border]
    rng = np.random.default_rng(0)
    samples = samples[rng.choice(len(samples), min(4000, len(samples)), replace=False)]
    cv2.setRNGSeed(0)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.1)
    _, _, centres = cv2.kmeans(samples, 8, None, crit, 2, cv2.KMEANS_PP_CENTERS)
    f = feat.reshape(-1, feat.shape[2])
    dist = np.full(len(f), np.inf, np.float32)
    for c in centres:
        dist = np.minimum(dist, ((f - c) ** 2).sum(1))
    dist = np.sqrt(dist).reshape(hh, ww)
    top = float(np.percentile(dist, 99.5))
    if top <= 0:
        return np.zeros((hh, ww), bool), s
    d8 = cv2.GaussianBlur(np.clip(dist / top * 255.0, 0, 255).astype(np.uint8), (5, 5), 0)
    _, fg = cv2.threshold(d8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return _largest(_open(fg > 0, max(hh, ww))), s


def refine_mask(img: np.ndarray, small_mask: np.ndarray, s: float, iterations: int = 4):
    """GrabCut at full resolution on a crop around the first mask: (mask crop, (x0, y0))."""
    h, w = img.shape[:2]
    m = cv2.resize(small_mask.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST)
    ys, xs = np.nonzero(m)
    pad = int(0.12 * max(xs.max() - xs.min(), ys.max() - ys.min())) + 12
    y0, y1 = max(int(ys.min()) - pad, 0), min(int(ys.max()) + pad + 1, h)
    x0, x1 = max(int(xs.min()) - pad, 0), min(int(xs.max()) + pad + 1, w)
    crop = _grabcut_image(img[y0:y1, x0:x1])
    mc = m[y0:y1, x0:x1]
    r = max(2, int(round(3.0 / s)))
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    gc = np.full(mc.shape, cv2.GC_BGD, np.uint8)
    gc[cv2.dilate(mc, ker, iterations=2) > 0] = cv2.GC_PR_BGD
    gc[mc > 0] = cv2.GC_PR_FGD
    gc[cv2.erode(mc, ker, iterations=2) > 0] = cv2.GC_FGD
    if not (gc == cv2.GC_FGD).any():
        gc[mc > 0] = cv2.GC_FGD
    bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(0)
    cv2.grabCut(crop, gc, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    return _largest(_open((gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD), max(h, w))), (x0, y0)


def _pooled(a: np.ndarray, half: int) -> np.ndarray:
    """Sums over the neighbouring columns j - half .. j + half (along axis 0)."""
    c = np.concatenate([np.zeros((1,) + a.shape[1:]), np.cumsum(a, axis=0)])
    j = np.arange(len(a))
    return c[np.minimum(j + half + 1, len(a))] - c[np.maximum(j - half, 0)]


def subpixel_edges(img: np.ndarray, x: np.ndarray, top: np.ndarray) -> np.ndarray:
    """Sub-pixel top edge per column (see module docstring): pixel edge ``top - 0.5`` where the two sides
    cannot be told apart.

    Each pixel across the edge is projected on Fisher's discriminant between the background above (rows
    6-12 above the mask's edge) and the heap below (rows 6-12 under it), both pooled over +-10
    neighbouring columns, in chromaticity and log intensity: the projection, between 0 (background) and 1
    (heap), is the pixel's heap fraction, and the edge lies below the top of the window by the sum of the
    background fractions. The weights follow what separates the two sides here: where a shadow on the
    backdrop is as dark as the sand it is the colour, so the flank's dark rim (grazing light) still counts
    as sand."""
    r, g, log_i = _chroma(img)
    feat = np.dstack([r * 100.0, g * 100.0, log_i]).astype(np.float64)
    h = img.shape[0]
    xi, ti = x.astype(int), top.astype(int)
    out = ti - 0.5
    ok = (ti - EDGE_REF_FAR >= 0) & (ti + EDGE_REF_FAR < h)
    if ok.sum() < 3:
        return out
    xs, ts = xi[ok], ti[ok]
    win = feat[ts[:, None] + np.arange(-EDGE_REF_FAR, EDGE_REF_FAR + 1)[None, :], xs[:, None]]  # (n, rows, 3)
    stats = []
    for side in (win[:, :EDGE_REF_FAR - EDGE_REF_NEAR + 1], win[:, EDGE_REF_FAR + EDGE_REF_NEAR:]):
        count = _pooled(np.full(len(side), side.shape[1], float), EDGE_POOL)
        mean = _pooled(side.sum(axis=1), EDGE_POOL) / count[:, None]
        second = _pooled(np.einsum("nki,nkj->nij", side, side), EDGE_POOL) / count[:, None, None]
        stats.append((mean, second - np.einsum("ni,nj->nij", mean, mean)))
    (mb, cb), (ms, cs) = stats
    dmu = ms - mb
    w = np.linalg.solve(0.5 * (cb + cs) + 1e-4 * np.eye(3)[None], dmu[..., None])[..., 0]
    separation = (dmu * w).sum(axis=1)  # squared Mahalanobis distance between the two sides
    mid = win[:, EDGE_REF_FAR - EDGE_WIN:EDGE_REF_FAR + EDGE_WIN + 1]
    frac = np.clip(((mid - mb[:, None]) * w[:, None]).sum(axis=2) / np.maximum(separation, 1e-12)[:, None], 0.0, 1.0)
    edge = ts - EDGE_WIN - 0.5 + (1.0 - frac).sum(axis=1)
    good = separation > MIN_SEPARATION
    res = out[ok]
    res[good] = edge[good]
    out[ok] = res
    return out


def heap_outline(img: np.ndarray) -> Outline:
    """The heap's top outline in a BGR photo (see module docstring)."""
    if img is None or img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 32:
        raise SandtrackError("not a colour image of usable size")
    h, w = img.shape[:2]
    small, s = first_mask(img)
    if small.sum() < MIN_AREA_FRACTION * small.size:
        raise SandtrackError("no heap found: nothing in the image stands out from the colours along its border")
    mask, (x0, y0) = refine_mask(img, small, s)
    if mask.sum() < MIN_AREA_FRACTION * h * w:
        raise SandtrackError("no heap found after refining the silhouette")
    ys, xs = np.nonzero(mask)
    bx0, bx1, by0, by1 = int(xs.min()), int(xs.max()) + 1, int(ys.min()), int(ys.max()) + 1
    crop = mask[by0:by1, bx0:bx1]
    cols = np.nonzero(crop.any(0))[0]
    top = np.argmax(crop[:, cols], axis=0) + by0 + y0
    x = (cols + bx0 + x0).astype(float)
    touches = set()
    gx0, gx1, gy0 = bx0 + x0, bx1 + x0, by0 + y0
    if gx0 <= 1:
        touches.add("left")
    if gx1 >= w - 1:
        touches.add("right")
    if gy0 <= 1:
        touches.add("top")
    y = subpixel_edges(img, x, top.astype(float))
    return Outline(x, y, touches, (gx0, gy0, gx1, by1 + y0), int(mask.sum()), crop)
