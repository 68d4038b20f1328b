"""Lens models: which distortion terms each named model fits, and the projection of camera-frame
points to distorted pixels for every model.

The pinhole models are OpenCV's, with its coefficient vector (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2,
s3, s4, tau_x, tau_y): radial (k1..k3 over 1 + k4..k6 for the rational model), tangential (p1, p2),
thin prism (s1..s4) and a tilted sensor (tau_x, tau_y, radians). A model fits a subset of the terms;
the others stay 0, and the vector is stored with the shortest length OpenCV accepts for it (5, 8, 12
or 14). The fisheye model is OpenCV's equidistant one (k1..k4). `project` matches
`cv2.projectPoints` / `cv2.fisheye.projectPoints` to float precision (tested).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TERMS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")
FISHEYE_TERMS = ("k1", "k2", "k3", "k4")
_STANDARD = ("k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class Lens:
    name: str
    terms: tuple[str, ...]  # the fitted terms
    description: str
    family: str = "pinhole"  # "pinhole" | "fisheye"

    @property
    def length(self) -> int:
        """Length of the stored distortion vector."""
        if self.family == "fisheye":
            return 4
        last = max((TERMS.index(t) for t in self.terms), default=0)
        return next(n for n in (5, 8, 12, 14) if last < n)

    @property
    def free(self) -> np.ndarray:
        """(length,) bool: which entries of the distortion vector are fitted."""
        names = FISHEYE_TERMS if self.family == "fisheye" else TERMS[: self.length]
        return np.array([t in self.terms for t in names], dtype=bool)

    @property
    def parameters(self) -> int:
        return len(self.terms)


# In order of preference: fewest terms first, so that a model selection keeps the first of equals.
LENSES: dict[str, Lens] = {lens.name: lens for lens in (
    Lens("none", (), "no distortion"),
    Lens("radial1", ("k1",), "radial k1"),
    Lens("radial2", ("k1", "k2"), "radial k1 k2"),
    Lens("tangential", ("k1", "k2", "p1", "p2"), "radial k1 k2, tangential p1 p2"),
    Lens("standard", _STANDARD, "OpenCV's default: k1 k2 p1 p2 k3"),
    Lens("tilted", (*_STANDARD, "tau_x", "tau_y"), "standard + tilted sensor tau_x tau_y"),
    Lens("rational", (*_STANDARD, "k4", "k5", "k6"), "standard + rational k4 k5 k6"),
    Lens("prism", (*_STANDARD, "s1", "s2", "s3", "s4"), "standard + thin prism s1..s4"),
    Lens("rational-prism", (*_STANDARD, "k4", "k5", "k6", "s1", "s2", "s3", "s4"), "rational + thin prism"),
    Lens("full", TERMS, "rational + thin prism + tilted sensor (all 14 terms)"),
    Lens("fisheye", FISHEYE_TERMS, "equidistant fisheye k1..k4", family="fisheye"),
)}
LENS_NAMES = tuple(LENSES)
# The candidates of `--lens auto`, in order of preference. The fisheye model is a different projection,
# chosen by the user for lenses wider than about 120 degrees (the rational terms cover wide-angle lenses).
AUTO_LENSES = tuple(n for n, lens in LENSES.items() if lens.family == "pinhole")


def get_lens(name: str) -> Lens:
    from .errors import SandtrackError

    lens = LENSES.get(name)
    if lens is None:
        raise SandtrackError(f"unknown lens model {name!r} (one of {', '.join(LENS_NAMES)}, or auto)")
    return lens


def lens_of(distortion: np.ndarray, family: str = "pinhole") -> Lens:
    """The first (simplest) named model that holds every non-zero term of a distortion vector."""
    if family == "fisheye":
        return LENSES["fisheye"]
    d = np.asarray(distortion, dtype=float).ravel()
    used = {TERMS[i] for i in np.nonzero(d)[0]}
    return next(lens for lens in LENSES.values() if lens.family == "pinhole" and used <= set(lens.terms))


def padded(distortion: np.ndarray, lens: Lens) -> np.ndarray:
    """The distortion vector at the lens's stored length (terms beyond it must be 0)."""
    d = np.asarray(distortion, dtype=float).ravel()
    out = np.zeros(lens.length)
    n = min(len(d), lens.length)
    out[:n] = d[:n]
    return np.where(lens.free, out, 0.0)


def tilt_matrix(tau_x: float, tau_y: float) -> np.ndarray:
    """OpenCV's projection of the tilted sensor (computeTiltProjectionMatrix)."""
    cx, sx, cy, sy = np.cos(tau_x), np.sin(tau_x), np.cos(tau_y), np.sin(tau_y)
    rx = np.array([[1, 0, 0], [0, cx, sx], [0, -sx, cx]])
    ry = np.array([[cy, 0, -sy], [0, 1, 0], [sy, 0, cy]])
    r = ry @ rx
    pz = np.array([[r[2, 2], 0, -r[0, 2]], [0, r[2, 2], -r[1, 2]], [0, 0, 1]])
    return pz @ r


def distort_normalised(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's pinhole distortion of normalised points (x, y) = (X/Z, Y/Z). `dist`: (D,) or (N, D)
    with D in 0, 4, 5, 8, 12, 14."""
    d = np.asarray(dist, dtype=np.float64)
    n_terms = d.shape[-1]
    if n_terms == 0:
        return x, y

    def term(i):
        return d[..., i] if i < n_terms else 0.0

    r2 = x * x + y * y
    radial = 1 + r2 * (term(0) + r2 * (term(1) + r2 * term(4)))
    if n_terms > 5:
        radial = radial / (1 + r2 * (term(5) + r2 * (term(6) + r2 * term(7))))
    p1, p2 = term(2), term(3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    if n_terms > 8:
        xd = xd + r2 * (term(8) + r2 * term(9))
        yd = yd + r2 * (term(10) + r2 * term(11))
    if n_terms > 12:
        if d.ndim == 1:
            m = tilt_matrix(d[12], d[13])
            w = m[2, 0] * xd + m[2, 1] * yd + m[2, 2]
            xd, yd = (m[0, 0] * xd + m[0, 1] * yd + m[0, 2]) / w, (m[1, 0] * xd + m[1, 1] * yd + m[1, 2]) / w
        else:
            for tau in {(float(a), float(b)) for a, b in d[:, 12:14]}:  # per-point vectors: few distinct tilts
                sel = (d[:, 12] == tau[0]) & (d[:, 13] == tau[1])
                xd[sel], yd[sel] = distort_normalised(xd[sel], yd[sel], np.r_[np.zeros(12), tau])
    return xd, yd


def distort_fisheye(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(dist, dtype=np.float64)
    r = np.hypot(x, y)
    th = np.arctan(r)
    th2 = th * th
    thd = th * (1 + th2 * (d[..., 0] + th2 * (d[..., 1] + th2 * (d[..., 2] + th2 * d[..., 3]))))
    scale = np.where(r > 1e-12, thd / np.where(r > 1e-12, r, 1.0), 1.0)
    return x * scale, y * scale


def undistort_normalised(xd: np.ndarray, yd: np.ndarray, dist: np.ndarray, family: str = "pinhole",
                         tol: float = 1e-12, iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """The undistorted normalised points whose distortion gives (xd, yd): Newton's method on the
    model itself (Jacobian by finite differences), from the distorted point. OpenCV's fixed-point
    iteration (cv2.undistortPoints) stopped hundreds of pixels off near the corners of a wide lens
    (k1 = -0.28); Newton converges to 1e-12 there in a few steps. Points that do not converge (beyond a
    fold of an over-fitted model) are NaN."""
    distort = distort_fisheye if family == "fisheye" else distort_normalised
    x, y = np.array(xd, dtype=float), np.array(yd, dtype=float)
    eps = 1e-7
    todo = np.isfinite(x) & np.isfinite(y)
    with np.errstate(all="ignore"):
        for _ in range(iterations):
            if not todo.any():
                break
            xs, ys = x[todo], y[todo]
            fx, fy = distort(xs, ys, dist)
            rx, ry = fx - xd[todo], fy - yd[todo]
            done = np.hypot(rx, ry) < tol
            ax, ay = distort(xs + eps, ys, dist)
            bx, by = distort(xs, ys + eps, dist)
            j00, j10, j01, j11 = (ax - fx) / eps, (ay - fy) / eps, (bx - fx) / eps, (by - fy) / eps
            det = j00 * j11 - j01 * j10
            step_x = np.where(done, 0.0, (j11 * rx - j01 * ry) / det)
            step_y = np.where(done, 0.0, (j00 * ry - j10 * rx) / det)
            x[todo], y[todo] = xs - step_x, ys - step_y
            idx = np.nonzero(todo)[0]
            todo[idx[done]] = False
        fx, fy = distort(x, y, dist)
        bad = ~(np.hypot(fx - xd, fy - yd) < 1e-9)
    x[bad], y[bad] = np.nan, np.nan
    return x, y


def project(xc: np.ndarray, K: np.ndarray, dist: np.ndarray, family: str = "pinhole") -> np.ndarray:
    """Camera-frame points (N, 3) -> distorted pixels (N, 2).

    `K` may be (3, 3) or per point (N, 3, 3); `dist` (D,) or per point (N, D)."""
    xc = np.asarray(xc, dtype=np.float64).reshape(-1, 3)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # points on the camera plane: inf/NaN
        x = xc[:, 0] / xc[:, 2]
        y = xc[:, 1] / xc[:, 2]
        if family == "fisheye":
            xd, yd = distort_fisheye(x, y, dist)
        else:
            xd, yd = distort_normalised(x, y, dist)
    K = np.asarray(K, dtype=np.float64)
    if K.ndim == 2:
        return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=1)
    return np.stack([K[:, 0, 0] * xd + K[:, 0, 1] * yd + K[:, 0, 2], K[:, 1, 1] * yd + K[:, 1, 2]], axis=1)


def radial_factor(r: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Distorted / undistorted radius of the pinhole radial terms at normalised radius r."""
    d = np.zeros(8)
    src = np.asarray(dist, dtype=float).ravel()[:8]
    d[: len(src)] = src
    r2 = r * r
    return (1 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))) / (1 + r2 * (d[5] + r2 * (d[6] + r2 * d[7])))


def standard_approximation(K: np.ndarray, dist: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, float]:
    """The five-term (k1 k2 p1 p2 k3) distortion closest to a longer pinhole model at the undistorted
    normalised points `xy` (N, 2), e.g. those of a grid over the image (least squares: the five terms
    enter the distortion linearly), and the largest pixel difference between the two there."""
    d = np.asarray(dist, dtype=float).ravel()
    xy = np.asarray(xy, dtype=float)
    xy = xy[np.isfinite(xy).all(axis=1)]
    x, y = xy[:, 0], xy[:, 1]
    xd, yd = distort_normalised(x, y, d)
    r2 = x * x + y * y
    A = np.zeros((2 * len(x), 5))
    A[0::2] = np.stack([x * r2, x * r2 ** 2, 2 * x * y, r2 + 2 * x * x, x * r2 ** 3], axis=1)
    A[1::2] = np.stack([y * r2, y * r2 ** 2, r2 + 2 * y * y, 2 * x * y, y * r2 ** 3], axis=1)
    b = np.empty(2 * len(x))
    b[0::2], b[1::2] = xd - x, yd - y
    five = np.linalg.lstsq(A, b, rcond=None)[0]
    x5, y5 = distort_normalised(x, y, five)
    diff = np.hypot((x5 - xd) * K[0, 0], (y5 - yd) * K[1, 1])
    return five, float(diff.max()) if len(diff) else 0.0
