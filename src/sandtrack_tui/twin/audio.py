"""Sound of the lab: shared room noise, mains hum, the tool's drive while it moves, and a hand clap.

The scene's sound is one signal in scene time; each camera records it from its own start time
(fractional-sample shifts done exactly in the frequency domain) through its own microphone
(own colouring and own self-noise). No acoustic path delay is modelled: the audio offset equals the
video clock offset.
"""

from __future__ import annotations

import numpy as np

from .writer import AUDIO_RATE


def _coloured_noise(rng, n: int, exponent: float) -> np.ndarray:
    """Noise with power spectrum ~ 1/f**exponent (pink for 1)."""
    spec = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1 / AUDIO_RATE)
    f[0] = f[1]
    spec *= f ** (-exponent / 2)
    out = np.fft.irfft(spec, n)
    return out / out.std()


def scene_sound(seed: int, duration_s: float, clap_s: float, tool_start_s: float | None = None,
                tool_end_s: float | None = None) -> np.ndarray:
    """The scene's sound at AUDIO_RATE from scene time 0 to duration_s (float64)."""
    rng = np.random.default_rng(seed + 51)
    n = int(np.ceil(duration_s * AUDIO_RATE))
    t = np.arange(n) / AUDIO_RATE
    room = 0.012 * _coloured_noise(rng, n, 1.0) + 0.004 * _coloured_noise(rng, n, 0.0)
    hum = 0.004 * np.sin(2 * np.pi * 50.0 * t + 0.3) + 0.002 * np.sin(2 * np.pi * 150.0 * t + 1.1)
    sig = room + hum
    if tool_start_s is not None:
        on = np.clip((t - tool_start_s) / 0.15, 0, 1) * np.clip((tool_end_s - t) / 0.15, 0, 1)
        drive = _coloured_noise(rng, n, 1.6) * (1 + 0.3 * np.sin(2 * np.pi * 7.0 * t))
        whine = np.sin(2 * np.pi * (380.0 * t + 3.0 * np.sin(2 * np.pi * 0.5 * t)))
        sig += on * (0.02 * drive + 0.006 * whine)
    # the clap: a sharp broadband burst with a short room tail
    k0 = int(round(clap_s * AUDIO_RATE))
    m = int(0.25 * AUDIO_RATE)
    tc = np.arange(m) / AUDIO_RATE
    burst = rng.standard_normal(m) * (np.exp(-tc / 0.004) + 0.08 * np.exp(-tc / 0.06))
    burst[: int(0.0004 * AUDIO_RATE)] *= np.linspace(0, 1, int(0.0004 * AUDIO_RATE))
    sig[k0 : k0 + m] += 0.6 * burst[: max(0, min(m, n - k0))]
    return sig


def record(scene: np.ndarray, start_s: float, n_samples: int, seed: int, mic: int) -> np.ndarray:
    """What a camera records: samples at scene times start_s + k / AUDIO_RATE (k = 0..n_samples-1),
    through its microphone (`mic` selects colouring and self-noise). float32 in [-1, 1]."""
    pos = start_s * AUDIO_RATE
    i0 = int(np.floor(pos))
    frac = pos - i0
    seg_len = n_samples + 64
    seg = np.zeros(seg_len)
    a, b = max(i0, 0), min(i0 + seg_len, len(scene))
    if b > a:
        seg[a - i0 : b - i0] = scene[a:b]
    spec = np.fft.rfft(seg)
    f = np.fft.rfftfreq(seg_len)
    spec *= np.exp(2j * np.pi * f * frac)  # x(n + frac)
    # microphone colouring: gentle high-pass and a tilt, different per camera
    fhz = f * AUDIO_RATE
    hp = 1.0 / np.sqrt(1.0 + (80.0 / np.maximum(fhz, 1.0)) ** 4)
    tilt = (1.0 + fhz / 8000.0) ** (-0.3 if mic == 0 else -0.5)
    out = np.fft.irfft(spec * hp * tilt, seg_len)[:n_samples]
    rng = np.random.default_rng(seed + 61 + mic)
    out += 0.003 * rng.standard_normal(n_samples)
    return np.clip(out, -1, 1).astype(np.float32)
