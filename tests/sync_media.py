"""Synthetic recordings for the sync tests and benchmark: a two-camera scene with a known offset.

World time 0 = the side camera starts; the front camera starts `offset_s` later. Each file's
audio stream begins `audio_start_s` into the file (as cameras do) and is AAC-encoded (1024-sample
priming), so index-based readings are wrong by hundreds of ms while pts-based ones are right.
"""

from __future__ import annotations

import fractions

import av
import numpy as np


def clap(rate: int, rng: np.random.Generator, length_s: float = 0.06) -> np.ndarray:
    n = int(length_s * rate)
    t = np.arange(n) / rate
    return rng.standard_normal(n) * np.exp(-t / 0.008)


def scene_audio(rate: int, file_start_world_s: float, audio_start_s: float, duration_s: float,
                clap_world_s: float, clap_wave: np.ndarray, rng: np.random.Generator,
                noise: float = 0.05, hum: float = 0.2, clap_gain: float = 0.5) -> np.ndarray:
    """Samples of one camera's audio track: independent noise, mains hum with the same phase at
    every file start (a trap for whole-file correlation), and the shared clap."""
    n = int(duration_s * rate)
    t_file = audio_start_s + np.arange(n) / rate
    x = noise * rng.standard_normal(n)
    x += hum * (np.sin(2 * np.pi * 50 * t_file) + 0.4 * np.sin(2 * np.pi * 150 * t_file + 0.3))
    k = (clap_world_s - file_start_world_s - audio_start_s) * rate
    k0 = int(np.floor(k))
    frac = k - k0
    # fractional-sample placement by linear interpolation of the clap waveform
    wave = clap_gain * ((1 - frac) * np.concatenate([clap_wave, [0.0]]) + frac * np.concatenate([[0.0], clap_wave]))
    lo, hi = max(k0, 0), min(k0 + len(wave), n)
    if hi > lo:
        x[lo:hi] += wave[lo - k0:hi - k0]
    return x.astype(np.float32)


def write_av(path, fps: int = 50, n_frames: int = 100, size=(64, 48), frame_fn=None, audio=None,
             rate: int = 48000, audio_start_s: float = 0.0, gop: int | None = None) -> None:
    """Write an mp4 (H.264 video, optional AAC mono audio starting `audio_start_s` into the file)."""
    # movie_timescale: the mp4 muxer otherwise stores the audio's start gap (edit list) in whole
    # milliseconds, which moves the audio by up to 1 ms (e.g. 32 samples for a 50 ms start)
    c = av.open(str(path), "w", options={"movie_timescale": str(rate)})
    vs = c.add_stream("libx264", rate=fps)
    vs.width, vs.height = size
    vs.pix_fmt = "yuv420p"
    vs.options = {"preset": "ultrafast", "crf": "18", **({"g": str(gop), "keyint_min": str(gop)} if gop else {})}
    ast = None
    if audio is not None:
        ast = c.add_stream("aac", rate=rate)
        ast.layout = "mono"
    for i in range(n_frames):
        img = np.zeros((size[1], size[0], 3), np.uint8) if frame_fn is None else frame_fn(i)
        f = av.VideoFrame.from_ndarray(img, format="bgr24")
        f.pts = i
        for p in vs.encode(f):
            c.mux(p)
    for p in vs.encode():
        c.mux(p)
    if ast is not None:
        start = int(round(audio_start_s * rate))
        a = np.asarray(audio, np.float32)
        for k in range(0, len(a), 1024):
            f = av.AudioFrame.from_ndarray(a[None, k:k + 1024].copy(), format="fltp", layout="mono")
            f.sample_rate = rate
            f.pts = start + k
            f.time_base = fractions.Fraction(1, rate)
            for p in ast.encode(f):
                c.mux(p)
        for p in ast.encode():
            c.mux(p)
    c.close()


def make_pair(folder, offset_s: float = 0.7473, clap_world_s: float = 2.3, duration_s: float = 4.0,
              audio_start=(0.25, 0.05), fps: int = 50, seed: int = 0, rate: int = 48000, with_audio: bool = True,
              frame_fns=(None, None), gop: int | None = None, **audio_kw):
    """side.mp4 and front.mp4 in `folder`; returns their paths."""
    rng = np.random.default_rng(seed)
    wave = clap(rate, rng)
    paths = []
    for name, start_world, a0, fn in (("side", 0.0, audio_start[0], frame_fns[0]),
                                       ("front", offset_s, audio_start[1], frame_fns[1])):
        audio = None
        if with_audio:
            audio = scene_audio(rate, start_world, a0, duration_s - a0, clap_world_s, wave, rng, **audio_kw)
        p = folder / f"{name}.mp4"
        write_av(p, fps=fps, n_frames=int(duration_s * fps), frame_fn=fn, audio=audio, rate=rate,
                 audio_start_s=a0, gop=gop)
        paths.append(p)
    return paths
