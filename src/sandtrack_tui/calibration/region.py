"""Where in each image a calibration was fitted: the convex hull of its observations' pixels.

A lens model is fitted to the pixels its calibration points fell on; beyond them it extrapolates, and
the parameter covariance cannot say how well (a polynomial's error grows fastest where it has no data).
`image_region` keeps a camera's hull as half-planes (n·p + d <= 0 inside, px); `region_labels` marks each
row "outside" where its pixel in some camera lies beyond that camera's hull by more than TOLERANCE of the
image diagonal, "inside" where every camera with a region has it inside, "" where no camera has one
(a calibration that kept none: imported, or written before regions were kept).
"""

from __future__ import annotations

import numpy as np

from ..jit import jit

TOLERANCE = 0.01  # of the image diagonal: a pixel this close to the hull still counts as inside
LABELS = ("", "inside", "outside")


def _hull(pixels: np.ndarray):
    """scipy's ConvexHull of `pixels` (N, 2), NaN rows ignored; None for fewer than three points or points
    on a line."""
    from scipy.spatial import ConvexHull, QhullError  # 0.7 s to import: only where a calibration is made

    p = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
    p = p[np.isfinite(p).all(axis=1)]
    if len(p) < 3:
        return None
    try:
        return ConvexHull(p)
    except (QhullError, ValueError):
        return None


def image_region(pixels: np.ndarray) -> np.ndarray | None:
    """(F, 3) half-planes (unit normal, offset; px) of the convex hull of `pixels` (N, 2); None without one."""
    hull = _hull(pixels)
    return None if hull is None else hull.equations


def covered_pct(pixels: np.ndarray, size: tuple[int, int]) -> float | None:
    """The hull of `pixels` as a share of the image (%); None without a hull or an image size."""
    hull = _hull(pixels) if min(size) > 0 else None
    return None if hull is None else 100.0 * float(hull.volume) / (size[0] * size[1])  # a 2-D hull's volume: area


@jit(nogil=True)
def _mark(p, halfplanes, tolerance, codes):  # pragma: no cover - compiled
    """codes[i] (LABELS' index) for pixel i of one camera: 2 where it lies beyond an edge by more than
    `tolerance` (the first such edge ends its loop: a million rows take 35 ms, their distances to every edge
    took 0.15 s), else at least 1 where it is finite; a NaN pixel leaves its code."""
    for i in range(p.shape[0]):
        x, y = p[i, 0], p[i, 1]
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        code = 1
        for f in range(halfplanes.shape[0]):
            if halfplanes[f, 0] * x + halfplanes[f, 1] * y + halfplanes[f, 2] > tolerance:
                code = 2
                break
        if code > codes[i]:
            codes[i] = code


def tolerance_px(size: tuple[int, int]) -> float:
    """TOLERANCE of the image diagonal (px); 0 for an unknown size."""
    return TOLERANCE * float(np.hypot(*size)) if min(size) > 0 else 0.0


def region_codes(calibration, pixels: dict[str, np.ndarray], n: int) -> np.ndarray:
    """Per row, an index into LABELS: "outside" where a camera's pixel lies beyond its calibrated region
    (`Calibration.regions`), "inside" where every camera with a region and a pixel has it inside, "" where
    no camera with a region has a pixel."""
    codes = np.zeros(n, np.int8)
    for name, region in (getattr(calibration, "regions", None) or {}).items():
        if name in pixels and name in calibration.cameras:
            cam = calibration.cameras[name]
            _mark(np.ascontiguousarray(pixels[name], dtype=np.float64).reshape(-1, 2),
                  np.ascontiguousarray(region, dtype=np.float64), tolerance_px((cam.width, cam.height)), codes)
    return codes


def region_labels(calibration, pixels: dict[str, np.ndarray], n: int) -> np.ndarray:
    """`region_codes` as text (object array)."""
    return np.array(LABELS, dtype=object)[region_codes(calibration, pixels, n)]


def outside_note(table) -> str | None:
    """One line on the rows with XYZ whose pixels lie outside a calibrated region (None if there are none)."""
    if "calibrated_region" not in table.columns or not len(table):
        return None
    with_xyz = table["X_mm"].notna().to_numpy() if "X_mm" in table.columns else np.ones(len(table), bool)
    outside = int(((table["calibrated_region"] == LABELS[2]).to_numpy() & with_xyz).sum())
    if not outside:
        return None
    return (f"{outside} of {int(with_xyz.sum())} rows with XYZ have a pixel outside the image region the "
            "calibration covered (calibrated_region = outside): the lens model extrapolates there, and their sd "
            "leaves out its error")


def warm_up() -> None:
    """Compile (or load) the kernel once: run after installing, so the first `sandtrack xyz` does not pay it."""
    _mark(np.array([[0.0, 0.0], [np.nan, 1.0]]), np.array([[1.0, 0.0, -1.0], [0.0, 1.0, -1.0]]), 0.5,
          np.zeros(2, np.int8))


if __name__ == "__main__":
    warm_up()
