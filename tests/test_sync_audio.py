"""Audio and video sync against synthetic recordings with a known, non-whole-frame offset."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

sys.path.insert(0, str(Path(__file__).parent))
from conftest import claimed, within  # noqa: E402
from sandtrack_tui import sync  # noqa: E402
from sandtrack_tui.cli import main  # noqa: E402
from sandtrack_tui.errors import SandtrackError  # noqa: E402
from sandtrack_tui.store import Project  # noqa: E402
from sync_media import clap, make_pair, scene_audio  # noqa: E402

TRUE_OFFSET = 0.7473  # s, 37.365 frames at 50 fps
FPS = 50


@pytest.fixture(scope="module")
def av_pair(tmp_path_factory):
    # audio starts 0.25 s into the side file and 0.05 s into the front file (plus AAC priming)
    return make_pair(tmp_path_factory.mktemp("sync"), offset_s=TRUE_OFFSET, audio_start=(0.25, 0.05))


def test_read_audio_uses_presentation_time(av_pair):
    side, front = av_pair
    a = sync.read_audio(side)
    b = sync.read_audio(front)
    assert a.sample_rate == 48000
    # the decoded audio starts 0.25 s / 0.05 s into the files, minus the AAC encoder's priming
    # (1024 samples, decoded and kept: it is part of the presentation timeline)
    assert a.start_s == pytest.approx(0.25 - 1024 / 48000, abs=1e-6)
    assert b.start_s == pytest.approx(0.05 - 1024 / 48000, abs=1e-6)


def test_audio_offset_from_files_within_1ms(av_pair):
    side, front = av_pair
    res = sync.estimate_offset(side, front)
    assert res.method == "audio"
    # the measurement of README's sync row (synthetic AAC pairs: 0.0011 ms at most); measured 0.0008 ms here
    assert within(1000 * abs(res.offset_s - TRUE_OFFSET), claimed("sync", "pairs"))
    assert res.offset_frames == pytest.approx(res.offset_s * FPS)
    assert res.confidence >= sync.MIN_CONFIDENCE
    # the GCC-PHAT cross-check over the shared span agrees
    assert res.details["gcc_phat_difference_ms"] is not None
    assert abs(res.details["gcc_phat_difference_ms"]) < 0.004  # measured 0.0025 ms


def _tracks(noise, seed, hum=0.8, offset=TRUE_OFFSET, starts=(0.25, 0.1), clap_at=3.1, dur=6.0, shared=True):
    rate = 48000
    rng = np.random.default_rng(seed)
    w = clap(rate, rng)
    a = scene_audio(rate, 0.0, starts[0], dur, clap_at, w, rng, noise=noise, hum=hum)
    w2 = w if shared else clap(rate, rng)
    b = scene_audio(rate, offset, starts[1], dur, clap_at if shared else clap_at + 1.37, w2, rng, noise=noise,
                    hum=hum)
    return sync.AudioTrack(a, rate, starts[0]), sync.AudioTrack(b, rate, starts[1])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_clap_only_shared_under_noise_and_hum(seed):
    # hum (0.8) louder than the clap (0.5 peak), independent noise (0.07 rms) in each track
    a, b = _tracks(noise=0.07, seed=seed)
    res = sync.audio_offset(a, b)
    assert abs(res.offset_s - TRUE_OFFSET) < 2.3e-6  # s; measured up to 1.6e-6


def test_never_wrong_when_it_answers_in_heavy_noise():
    answered = 0  # how many it answers is not the point: an answer must be right
    for seed in range(10, 16):
        a, b = _tracks(noise=0.15, seed=seed)
        try:
            res = sync.audio_offset(a, b)
        except sync.LowConfidence:
            continue
        answered += 1
        assert abs(res.offset_s - TRUE_OFFSET) < 5.3e-6  # s; measured up to 3.5e-6


def test_whole_file_correlation_is_fooled_but_clap_window_is_not():
    """The trap this module avoids: hum in phase at each file start and the common file-start edge."""
    a, b = _tracks(noise=0.05, seed=4)
    x = sync._bandpass(a.samples.astype(float), 48000, (20, 8000))
    y = sync._bandpass(b.samples.astype(float), 48000, (20, 8000))
    c = signal.correlate(x, y, mode="full", method="fft")
    naive = a.start_s - b.start_s + (np.argmax(c) - (len(y) - 1)) / 48000
    assert abs(naive - TRUE_OFFSET) > 0.05
    assert abs(sync.audio_offset(a, b).offset_s - TRUE_OFFSET) < 3.3e-7  # s; measured 2.2e-7


def test_negative_offset_and_max_offset():
    a, b = _tracks(noise=0.05, seed=5, offset=-1.2345)
    res = sync.audio_offset(a, b, max_offset_s=3.0)
    assert abs(res.offset_s + 1.2345) < 4.4e-7  # s; measured 2.9e-7


def test_refuses_without_a_shared_event():
    a, b = _tracks(noise=0.05, seed=6, shared=False)
    with pytest.raises(sync.LowConfidence):
        sync.audio_offset(a, b)


def test_refuses_pure_noise():
    rng = np.random.default_rng(7)
    a = sync.AudioTrack(rng.standard_normal(48000 * 4).astype(np.float32) * 0.1, 48000, 0.0)
    b = sync.AudioTrack(rng.standard_normal(48000 * 4).astype(np.float32) * 0.1, 48000, 0.0)
    with pytest.raises(SandtrackError):
        sync.audio_offset(a, b)


def test_different_sample_rates():
    a, b = _tracks(noise=0.05, seed=8)
    b44 = sync.AudioTrack(signal.resample_poly(b.samples, 147, 160).astype(np.float32), 44100, b.start_s)
    res = sync.audio_offset(a, b44)
    assert abs(res.offset_s - TRUE_OFFSET) < 3.8e-7  # s; measured 2.5e-7


def _flash_fn(start_world, t_flash=2.3137):
    def fn(i):
        t0 = start_world + i / FPS  # exposure [t0, t0 + 1/fps]: partial brightness in the flash frame
        frac = np.clip((t0 + 1 / FPS - t_flash) * FPS, 0, 1)
        return np.full((48, 64, 3), 40 + 150 * frac, np.uint8)
    return fn


def _motion_fn(start_world, speed):
    def fn(i):
        t = start_world + i / FPS
        x = min(5 + speed * max(0.0, t - 1.9), 50)
        cols = np.arange(64)
        cover = np.clip(np.minimum(cols + 1 - x, x + 6 - cols), 0, 1)  # anti-aliased block
        # fresh sensor noise every frame, as in real footage; with keyframes every 40 frames (the
        # same file frames in both views) the coding noise jumps there: not motion
        img = np.full((48, 64), 90.0) + np.random.default_rng(i).normal(0, 4, (48, 64))
        img[15:30] += 140 * cover[None]
        return np.repeat(np.clip(img, 0, 255)[:, :, None].astype(np.uint8), 3, axis=2)
    return fn


def test_video_fallback_flash(tmp_path):
    side, front = make_pair(tmp_path, offset_s=TRUE_OFFSET, with_audio=False,
                            frame_fns=(_flash_fn(0.0), _flash_fn(TRUE_OFFSET)))
    res = sync.estimate_offset(side, front)
    assert res.method == "flash"
    assert abs(res.offset_frames - TRUE_OFFSET * FPS) < 0.092  # measured 0.062 frame
    assert "audio_problem" in res.details


def test_video_fallback_motion(tmp_path):
    side, front = make_pair(tmp_path, offset_s=TRUE_OFFSET, with_audio=False, gop=40,
                            frame_fns=(_motion_fn(0.0, 30), _motion_fn(TRUE_OFFSET, 21)))
    res = sync.estimate_offset(side, front, method="video")
    assert res.method == "motion"
    assert abs(res.offset_frames - TRUE_OFFSET * FPS) < 0.68  # measured 0.45 frame (good to about one)


def test_video_fallback_refuses_static_scene(tmp_path):
    side, front = make_pair(tmp_path, with_audio=False)
    with pytest.raises(SandtrackError):
        sync.estimate_offset(side, front)


def test_cli_sync_json_and_project(av_pair, tmp_path, capsys):
    side, front = av_pair
    proj = tmp_path / "exp.sandtrack"
    Project.create(proj, {"side": side, "front": front}).close()
    assert main(["sync", str(proj), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert within(1000 * abs(out["offset_s"] - TRUE_OFFSET), claimed("sync", "pairs"))
    assert out["offset_frames"] == pytest.approx(out["offset_s"] * FPS)
    with Project.open(proj) as p:
        assert p.sync_offset_s == pytest.approx(out["offset_s"])
        assert p.get("sync_result")["method"] == "audio"
        assert "sound_path_bound_ms" not in out  # no calibration: the cameras' distance is not known
        from sandtrack_tui.calibration.synthetic import stereo_rig

        p.set_calibration(stereo_rig())  # the front camera 434 mm from the side one
    assert main(["sync", str(proj)]) == 0
    text = capsys.readouterr().out
    bound = np.linalg.norm([420.0, -60.0, 90.0]) / 343.0  # ms
    assert f"the clap's sound path may shift it by up to ±{bound:.2f} ms (the cameras are 0.43 m apart)" in text


def test_cli_sync_bad_input(tmp_path, capsys):
    assert main(["sync", str(tmp_path / "missing.mp4"), str(tmp_path / "other.mp4")]) == 1
    assert "not found" in capsys.readouterr().err
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"not a video")
    assert main(["sync", str(bad)]) == 1


@pytest.mark.parametrize("fmt,dtype,scale", [("s16", np.int16, 32767), ("fltp", np.float32, 1.0),
                                             ("s16p", np.int16, 32767)])
def test_to_mono_stereo_layouts(fmt, dtype, scale):
    import av

    left = np.linspace(-0.5, 0.5, 64)
    right = np.full(64, 0.25)
    planar = fmt.endswith("p")
    arr = np.stack([left, right]) if planar else np.stack([left, right], axis=1).reshape(1, -1)
    frame = av.AudioFrame.from_ndarray((arr * scale).astype(dtype), format=fmt, layout="stereo")
    mono = sync._to_mono(frame)
    np.testing.assert_allclose(mono, (left + right) / 2, atol=1e-3)
