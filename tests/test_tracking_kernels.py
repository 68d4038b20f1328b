"""The compiled tracker kernels against the plain numpy / OpenCV arithmetic they replace."""

import cv2
import numpy as np

from sandtrack_tui.tracking import kernels
from sandtrack_tui.tracking.chroma import LUMA_BGR
from sandtrack_tui.tracking.colour import EPS
from sandtrack_tui.tracking.matcher import Match
from sandtrack_tui.tracking.rest import RestReference

RNG = np.random.default_rng(7)


def _disc(cx, cy, r=4.5, size=41, ss=8):
    """Blue disc on sand, anti-aliased by supersampling."""
    yy, xx = np.mgrid[0:size * ss, 0:size * ss] / ss + 0.5 / ss
    inside = ((xx - cx) ** 2 + (yy - cy) ** 2 <= r * r).reshape(size, ss, size, ss).mean(axis=(1, 3))
    sand, blue = np.array([120.0, 160.0, 190.0]), np.array([170.0, 70.0, 40.0])
    img = sand * (1 - inside[..., None]) + blue * inside[..., None] + RNG.normal(0, 1.0, (size, size, 3))
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def test_colour_score_and_mask_equal_the_formula():
    win = RNG.integers(0, 256, (23, 31, 3), dtype=np.uint8)
    w, b = np.float32([0.9, -0.4, -0.6]), np.float32(0.2)
    f = win.astype(np.float32)
    want = (f @ w) / (f.sum(axis=-1) + np.float32(EPS)) + b
    got = kernels.colour_score(win, w[0], w[1], w[2], b, np.float32(EPS), np.float32(1))
    assert got.dtype == np.float32 and np.allclose(got, want, atol=1e-6)
    got_f = kernels.colour_score(f, w[0], w[1], w[2], b, np.float32(EPS), np.float32(1))  # float windows (chroma.py)
    assert np.allclose(got_f, want, atol=1e-6)
    mask, found, x0, y0, x1, y1 = kernels.colour_mask(win, w[0], w[1], w[2], np.float32(-10.0))
    want = (f @ w - 10.0 >= 0).astype(np.uint8)
    assert np.array_equal(mask, want)
    rows, cols = np.flatnonzero(want.any(axis=1)), np.flatnonzero(want.any(axis=0))
    assert found and (x0, y0, x1, y1) == (cols[0], rows[0], cols[-1] + 1, rows[-1] + 1)
    assert not kernels.colour_mask(win, w[0], w[1], w[2], np.float32(-1e6))[1]


def test_cubic_profile_sampling_equals_opencv_remap():
    luma = RNG.uniform(0, 255, (21, 21)).astype(np.float32)
    px, py = RNG.uniform(1, 19, (2, 60)).astype(np.float32)
    want = cv2.remap(luma, px[None], py[None], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)[0]
    wx, wy = np.empty(4), np.empty(4)
    got = [kernels._cubic_sample(luma, float(x), float(y), wx, wy) for x, y in zip(px, py, strict=True)]
    assert np.abs(np.array(got) - want).max() < 1e-3


def test_rest_shift_measures_a_small_shift_and_refuses_a_large_one():
    ref_img, moved, far = _disc(20.0, 20.0), _disc(20.12, 19.93), _disc(21.0, 20.0)
    ref = RestReference(ref_img, 20.0, 20.0, 4.5, Match(20.0, 20.0, 1.0, 10.0, 1.0))
    lum = cv2.transform(ref_img[ref.y0:ref.y0 + ref.n, ref.x0:ref.x0 + ref.n].astype(np.float32), LUMA_BGR[None])
    assert np.allclose(ref.ref.reshape(ref.n, ref.n), lum, atol=1e-4)
    gx = cv2.Sobel(lum, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    assert np.allclose(ref.gx.reshape(ref.n, ref.n), gx, atol=1e-4)
    dx, dy = ref.shift(moved, 0.3, 3.0)
    assert abs(dx - 0.12) < 0.05 and abs(dy + 0.07) < 0.05  # (one linearised step, sensor noise)
    assert ref.shift(far, 0.3, 3.0) is None


def test_match_peak_psr_and_centroid_equal_the_direct_computation():
    res = RNG.uniform(-0.3, 0.3, (15, 17)).astype(np.float32)
    res[7, 9], res[7, 8], res[7, 10], res[6, 9], res[8, 9] = 0.95, 0.8, 0.7, 0.75, 0.85
    score = np.zeros((31, 33), np.float32)
    yy, xx = np.mgrid[0:31, 0:33]
    score[(xx - 17.3) ** 2 + (yy - 15.2) ** 2 <= 4.5 ** 2] = 1.0
    found, x, y, peak, psr, frac, used, touching = kernels.match_peak(
        res, score, 0, 16, 0, 14, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, 8, 6, 6.0, 0.15, float(score.sum()), 4.5)
    assert found and peak == np.float32(0.95) and not touching
    out = np.ones(res.shape, bool)
    out[1:14, 3:16] = False  # the peak's window, +-6
    side = res[out].astype(np.float64)
    assert abs(psr - (0.95 - side.mean()) / side.std()) < 1e-4
    m = cv2.moments(score)
    assert used and frac > 0.99
    assert abs(x - m["m10"] / m["m00"]) < 1e-6 and abs(y - m["m01"] / m["m00"]) < 1e-6
    # A gate (unit covariance, d2 <= 0.5) that excludes the best peak: the one cell inside is taken.
    found, x, y, peak, *_ = kernels.match_peak(res, score, 0, 16, 0, 14, -6.0, -7.0, 1.0, 0.0, 1.0, 0.5, 8, 6,
                                               6.0, 0.15, 1.0, 4.5)
    assert found and peak == res[7, 6]
    found, *_ = kernels.match_peak(res, score, 0, 16, 0, 14, -6.5, -7.5, 1.0, 0.0, 1.0, 0.4, 8, 6, 6.0, 0.15,
                                   1.0, 4.5)
    assert not found  # no cell inside the gate


def test_a_touching_marker_is_left_out_of_the_centroid_and_the_sidelobes():
    """Two identical discs touching (centres 2 r apart): each centre from its own share of the blob, and
    the neighbour's NCC peak is not a sidelobe."""
    r = 4.5
    score = np.zeros((41, 51), np.float32)
    yy, xx = np.mgrid[0:41, 0:51]
    score[(xx - 20.3) ** 2 + (yy - 20.2) ** 2 <= r * r] = 1.0
    score[(xx - 20.3 - 2 * r) ** 2 + (yy - 20.2) ** 2 <= r * r] = 1.0
    half = 8
    disc = np.zeros((2 * half + 1, 2 * half + 1), np.float32)
    ty, tx = np.mgrid[0:2 * half + 1, 0:2 * half + 1]
    disc[(tx - half) ** 2 + (ty - half) ** 2 <= r * r] = 1.0
    res = cv2.matchTemplate(score, disc, cv2.TM_CCOEFF_NORMED)
    area = float(disc.sum())
    found, x, y, peak, psr, frac, used, touching = kernels.match_peak(  # the left disc's peak
        res, score, 0, 15, 0, res.shape[0] - 1, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0, half, 6, r + 1.5, 0.15, area, r)
    assert found and touching and used
    own = score * ((xx - 20.3) ** 2 + (yy - 20.2) ** 2 <= r * r)
    m = cv2.moments(own)
    assert abs(x - m["m10"] / m["m00"]) < 0.05 and abs(y - m["m01"] / m["m00"]) < 0.05
    plain = kernels.centroid(score, x, y, 2, r + 1.5, 0.15, area)
    assert plain[0] - m["m10"] / m["m00"] > 0.1  # without the split, the neighbour pulls the centre
    assert psr > 8


def test_blob_moments_equal_the_dilated_component_moments():
    win = _disc(20.3, 19.6)
    labels = np.zeros(win.shape[:2], np.int32)
    labels[16:24, 17:25] = 3
    w, b, lo = np.float32([1.2, -0.5, -0.9]), np.float32(0.1), 0.15
    comp = cv2.dilate((labels[15:25, 16:26] == 3).astype(np.uint8), np.ones((3, 3), np.uint8))
    f = win[15:25, 16:26].astype(np.float32)
    wts = np.clip(((f @ w) / (f.sum(axis=-1) + np.float32(EPS)) + b - lo) / (1 - lo), 0, 1) * comp
    m = cv2.moments(wts.astype(np.float32))
    *got, pixels = kernels.blob_moments(win, labels, 3, 16, 15, 26, 25, w[0], w[1], w[2], b, np.float32(EPS),
                                        np.float32(1), lo)
    assert np.allclose(got, (m["m00"], m["m10"], m["m01"]), rtol=1e-5)
    assert pixels == 64


def test_median_equals_numpys_median():
    rng = np.random.default_rng(8)
    for dtype in (np.float32, np.float64):
        for n in [*range(1, 30), 299, 300, 961, 1600, kernels.MEDIAN_COMPILED_MAX, kernels.MEDIAN_COMPILED_MAX + 1]:
            a = (rng.normal(0, 1, n) * rng.choice([1e-3, 1.0, 300.0])).astype(dtype)
            if n % 3 == 0:
                a = np.round(a, 1)  # (ties among the middle values)
            assert kernels.median(a) == float(np.median(a)), (dtype, n)
    window = rng.normal(0.1, 0.2, (41, 39)).astype(np.float32)  # a score window, read whole
    assert kernels.median(window) == float(np.median(window))
    assert kernels.median(window[::3, ::2]) == float(np.median(window[::3, ::2]))
    window[5, 7] = np.nan
    assert np.isnan(kernels.median(window)) and np.isnan(np.median(window))
    assert np.isnan(kernels.median(np.zeros(0, np.float32)))
