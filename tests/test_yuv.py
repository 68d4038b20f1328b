"""Decoded 4:2:0 frames read window by window (yuv.py): the same pixels as FFmpeg's own BGR conversion."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from conftest import numbered_frame, write_clip
from sandtrack_tui import yuv
from sandtrack_tui.video import FrameSource

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data" / "experiment" / "side.mp4"
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "caliscope_4cam" / "cam_0.mp4"


def _every_yuv_combination() -> tuple:
    """Planes of a 4096 x 4096 frame holding each of the 2^24 (Y, U, V) triples once: block b has
    (U, V) = divmod(b % 65536, 256) and the four Y levels 4 (b // 65536) + 0..3."""
    b = np.arange(2048 * 2048)
    uv, group = b % 65536, b // 65536
    u, v = (uv // 256).astype(np.uint8).reshape(2048, 2048), (uv % 256).astype(np.uint8).reshape(2048, 2048)
    levels = (4 * group[:, None] + np.arange(4)).reshape(2048, 2048, 2, 2)
    y = levels.transpose(0, 2, 1, 3).reshape(4096, 4096).astype(np.uint8)
    return y, u, v


@pytest.mark.parametrize("fmt, colorspace, color_range", [("yuv420p", 2, 0), ("yuv420p", 1, 1), ("yuvj420p", 2, 2)],
                         ids=["bt601-unspecified", "bt709-limited", "full-range"])
def test_window_conversion_equals_ffmpeg_for_every_pixel_value(fmt, colorspace, color_range):
    planes = _every_yuv_combination()
    frame = yuv._frame(planes, fmt, colorspace, color_range)
    tables = yuv.converter(frame)
    assert tables is not None
    want = yuv._swscale_bgr(frame)
    got = yuv.Yuv420Frame(frame, tables)[0:4096, 0:4096]
    assert np.array_equal(got, want)


def test_other_pixel_formats_have_no_window_converter():
    assert yuv.converter(av.VideoFrame(64, 64, "yuv444p")) is None
    assert yuv.converter(av.VideoFrame(64, 64, "gray")) is None


@pytest.mark.parametrize("path", [SAMPLE, REAL], ids=["sample", "real-webcam"])
def test_lazy_frames_read_as_the_decoded_bgr_frames(path):
    if not path.exists():
        pytest.skip(f"{path} is absent")
    rng = np.random.default_rng(3)
    with FrameSource(path, cache_mb=0) as bgr, FrameSource(path, cache_mb=0) as lazy:
        for i in range(1, min(len(bgr), 40)):
            want, got = bgr.frame(i), lazy.lazy_frame(i)
            assert isinstance(got, yuv.Yuv420Frame) and got.shape == want.shape
            for _ in range(20):
                y0, x0 = rng.integers(0, want.shape[0] - 1), rng.integers(0, want.shape[1] - 1)
                y1, x1 = y0 + rng.integers(1, 90), x0 + rng.integers(1, 90)
                assert np.array_equal(got[y0:y1, x0:x1], want[y0:y1, x0:x1])
        assert np.array_equal(np.asarray(got), want)


def test_linear_mask_equals_the_test_on_the_converted_window():
    if not SAMPLE.exists():
        pytest.skip("sample_data is absent")
    from sandtrack_tui.tracking import kernels

    with FrameSource(SAMPLE, cache_mb=0) as src:
        frame = src.lazy_frame(7)
    rng = np.random.default_rng(5)
    founds = 0
    for _ in range(30):
        coeffs = tuple(np.float32(rng.normal(0, 1, 4) * [1, 1, 1, 50]))
        y0, x0 = rng.integers(0, 1000), rng.integers(0, 1800)
        y1, x1 = y0 + rng.integers(1, 80), x0 + rng.integers(1, 120)
        want = kernels.colour_mask(frame[y0:y1, x0:x1], *coeffs)
        got = frame.linear_mask(coeffs, x0, y0, x1, y1)
        assert np.array_equal(got[0], want[0]) and got[1:] == want[1:]
        y, u, v, tables = frame.yuv
        assert yuv._linear_any(y, u, v, x0, y0, x1, y1, *tables, *coeffs, yuv._passing(tables, coeffs)) == want[1]
        # many windows at once, found or not (the epipolar band's tiles): each as linear_mask finds it
        boxes = np.array([(x0 + dx, y0 + dy, x1 + dx, y1 + dy) for dx, dy in rng.integers(-40, 40, (6, 2))], np.int64)
        boxes = np.clip(boxes, 0, [1920, 1080, 1920, 1080])
        many = frame.linear_found(coeffs, boxes)
        assert many.tolist() == [bool(frame.linear_mask(coeffs, *b)[1]) if b[2] > b[0] and b[3] > b[1] else False
                                 for b in boxes]
        founds += int(many.sum())
        # every chroma tested pixel by pixel (as when its passing levels are not one run)
        irregular = np.full(65536, 2, np.uint32)
        y, u, v, tables = frame.yuv
        got = yuv._linear_mask(y, u, v, x0, y0, x1, y1, *tables, *coeffs, irregular)
        assert np.array_equal(got[0], want[0]) and got[1:] == want[1:]
        assert yuv._linear_any(y, u, v, x0, y0, x1, y1, *tables, *coeffs, irregular) == want[1]
    assert 0 < founds < 180  # (both outcomes were tested)


def test_kernels_read_the_planes_as_the_converted_window():
    """The tracker's kernels on a frame in its planes (kernels.*_yuv) give what they give on the window
    converted to BGR, to the last bit; the rest test (kernels.rest_*_luma), which reads the brightness plane,
    the same shift to a few thousandths of a pixel."""
    if not SAMPLE.exists():
        pytest.skip("sample_data is absent")
    from sandtrack_tui.tracking import chroma, kernels, luma

    with FrameSource(SAMPLE, cache_mb=0) as src:
        frame, later = src.lazy_frame(7), src.lazy_frame(8)
    planes, planes_later = frame.yuv, later.yuv
    rng = np.random.default_rng(11)
    coeffs = tuple(np.float32(c) for c in (0.9, -0.4, -0.5, 0.1, 3.0, 1.0))
    radius = 5.5
    args = (luma._steps(radius), luma._COS, luma._SIN, luma.MIN_RISE, luma.STEP, 3, 0.35, 1.0, True)
    moved = agree = 0.0
    for _ in range(25):
        y0, x0 = int(rng.integers(0, 1000)), int(rng.integers(0, 1800))
        y1, x1 = y0 + int(rng.integers(1, 60)), x0 + int(rng.integers(1, 90))
        held = kernels.colour_score_yuv(*planes, x0, y0, x1, y1, *coeffs)
        assert np.array_equal(held, kernels.colour_score(frame[y0:y1, x0:x1], *coeffs))
        # (the chroma interpolated from the planes: as chroma.reinterpolate gives it from the BGR window)
        smooth = kernels.colour_score_yuv_interpolated(*planes, x0, y0, x1, y1, *coeffs)
        want = kernels.colour_score(np.clip(chroma.reinterpolate(frame, x0, y0, x1, y1), 0, 255), *coeffs)
        agree = max(agree, float(np.abs(smooth - want).max()))
        moved = max(moved, float(np.abs(smooth - held).max()))
        # (the rest test reads the coded brightness itself: the shift the converted window's luma gives, to
        # a few thousandths of a pixel, with the same verdict)
        n = int(rng.integers(9, 40))
        want = kernels.rest_reference(frame[y0:y0 + n, x0:x0 + n])
        got = kernels.rest_reference_luma(planes[0], planes[3][0], x0, y0, n)
        assert got[0] == want[0]
        if got[0]:
            a = kernels.rest_shift_luma(planes_later[0], planes_later[3][0], x0, y0, *got[2:], 0.5, 10.0)
            b = kernels.rest_shift(later[y0:y0 + n, x0:x0 + n], *want[2:], 0.5, 10.0)
            assert a[0] == b[0] and abs(a[1] - b[1]) < 0.003 and abs(a[2] - b[2]) < 0.003
        c = 0.5 * n + rng.normal(0, 1, 2)
        assert kernels.edge_centre_yuv(*planes, x0, y0, n, c[0], c[1], radius, *args) == \
            kernels.edge_centre(frame[y0:y0 + n, x0:x0 + n], c[0], c[1], radius, *args)
    assert agree < 0.005 and moved > 0.015  # (as reinterpolate, to rounding; not what the held chroma gives)


def test_window_reads_follow_numpy_slicing(tmp_path):
    clip = write_clip(tmp_path / "c.mp4", n_frames=3, width=322, height=242)
    with FrameSource(clip, cache_mb=0) as src:
        want, got = src.frame(2), src.lazy_frame(2)
    for key in [(slice(-5, None), slice(-7, None)), (slice(3, 2), slice(5, 9)), (slice(230, 400), slice(300, 999)),
                (slice(None), slice(None)), (slice(0, 10, 2), slice(1, 9)), (5, 7), (slice(4, 6),), 17]:
        assert np.array_equal(got[key], want[key]), key
    assert got.ndim == 3 and got.dtype == np.uint8 and got.size == want.size


def test_lazy_frames_stay_valid_after_the_source_closes(tmp_path):
    clip = write_clip(tmp_path / "c.mp4", n_frames=20)
    with FrameSource(clip, cache_mb=0) as src:
        frames = [src.lazy_frame(i) for i in range(1, 20)]
        want = [src.frame(i) for i in range(1, 20)]
    for f, w in zip(frames, want, strict=True):
        assert np.array_equal(f[0:240, 0:320], w)


def test_frame_from_a_cached_lazy_frame_is_bgr(tmp_path):
    clip = write_clip(tmp_path / "c.mp4", n_frames=10)
    with FrameSource(clip) as src:
        lazy = src.lazy_frame(5)
        assert isinstance(lazy, yuv.Yuv420Frame)
        img = src.frame(5)
        assert isinstance(img, np.ndarray) and np.array_equal(img, np.asarray(lazy))
        assert src.lazy_frame(5) is lazy  # the cache keeps the planes
        assert src.frame(5) is img  # and the conversion is kept beside it


def test_a_frame_is_cached_in_one_form_whoever_reads_it_first(tmp_path):
    # A tracking run reads windows of lazy frames while seeds and views read BGR frames of the same
    # source: the form the tracker gets must not depend on which thread decoded a frame first.
    clip = write_clip(tmp_path / "c.mp4", n_frames=10)
    with FrameSource(clip) as src:
        img = src.frame(7)  # decodes frames 0..7 on its way
        assert isinstance(img, np.ndarray)
        for i in range(8):
            assert isinstance(src.lazy_frame(i), yuv.Yuv420Frame)
        assert np.array_equal(np.asarray(src.lazy_frame(7)), img)


def test_video_without_a_window_converter_reads_as_bgr(tmp_path):
    path = tmp_path / "c444.mp4"
    with av.open(str(path), "w") as out:
        s = out.add_stream("libx264", rate=Fraction(25))
        s.width, s.height, s.pix_fmt = 64, 48, "yuv444p"
        for i in range(5):
            for p in s.encode(av.VideoFrame.from_ndarray(numbered_frame(i, 64, 48), format="bgr24")):
                out.mux(p)
        for p in s.encode():
            out.mux(p)
    with FrameSource(path, cache_mb=0) as src:
        got = src.lazy_frame(3)
        assert isinstance(got, np.ndarray) and np.array_equal(got, src.frame(3))
