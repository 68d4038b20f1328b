"""Time offset between the side and front camera recordings.

Convention (as everywhere in sandtrack): ``offset_s`` is how much later the front camera started
recording than the side camera, so an event at side time ``t`` appears at front time
``t - offset_s``. Times are the files' presentation timelines (`FrameSource.times_s`).

Audio (preferred)
    Both audio tracks are decoded with PyAV and placed on their presentation timeline
    (``frame.pts * time_base``), never by sample index from the file start: a container start
    offset or AAC priming would otherwise shift the result by hundreds of milliseconds.

    1. Candidates: the loudest short transients (a clap) in each track, found on a band-passed
       (300-3500 Hz, removing hum and rumble) energy envelope relative to its running median. The
       first and last 0.15 s are ignored, so the common file-start edge is never taken.
    2. Coarse search (8 kHz): a tapered (Tukey) window around each candidate (from 30 ms before
       its onset until its energy decays into the background, 60-400 ms) is correlated by
       normalised cross-correlation (NCC) against the whole other track. The peak's prominence,
       ``1 - second_peak / peak`` (second peak outside +-25 ms, floored at 4 noise sigmas),
       times ``min(1, peak / 0.4)`` (a weak peak is not trusted even when unique), is the
       confidence.
    3. Refinement at the native rate: the same window, band 300 Hz-8 kHz, NCC over +-3 ms and a
       parabolic fit through the peak (sub-sample).
    4. Cross-check: GCC-PHAT (phase transform, same band) over the shared span (at most 20 s around
       the clap), searched +-50 ms around the clap lag. A confident GCC-PHAT peak that disagrees by
       more than 10 ms lowers the confidence (the difference is reported in the details; a few ms
       may be a real acoustic path difference, about 2.9 ms per metre).
    Low confidence raises `SandtrackError` rather than returning a wrong offset.

Video fallback (no usable audio)
    Per frame, a small grey image: mean brightness (a flash) and mean absolute frame difference
    (the tool's motion). The event's time in each view is where the curve first rises above its
    baseline: a flash at 25 % of its step, the motion once 6 noise sigmas above
    the baseline for 10 frames (0.2 s) running, after a 3-frame running median (keyframes' one-frame
    spikes of coding noise are not motion); linear interpolation between frames gives sub-frame
    times. A flash is cross-checked by correlating the changes of the two curves. The motion onset
    is good to about a frame (the views see the motion differently), so its confidence is capped.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from scipy import signal

from .errors import SandtrackError

COARSE_RATE = 8000
COARSE_BAND = (300.0, 3500.0)
FINE_BAND = (300.0, 8000.0)
EDGE_S = 0.15  # ignore transients this close to a track's ends (file-start edge, filter edges)
WINDOW_BEFORE_S = 0.03
WINDOW_AFTER_S = 0.4
EXCLUDE_S = 0.025
MIN_CONFIDENCE = 0.35
PEAK_TRUSTED = 0.4  # NCC peak at or above which the prominence alone decides the confidence
FLASH_MIN_LEVELS = 8.0  # a flash changes the mean grey level (0-255) by at least this much


class NoUsableAudio(SandtrackError):
    """The file has no audio stream, or its audio is silent or too short."""


class LowConfidence(SandtrackError):
    """The offset could not be determined reliably."""


@dataclass
class AudioTrack:
    """Mono samples on the file's presentation timeline: sample k is at ``start_s + k / sample_rate``."""

    samples: np.ndarray
    sample_rate: int
    start_s: float
    path: str = ""

    @property
    def duration_s(self) -> float:
        return len(self.samples) / self.sample_rate


@dataclass
class SyncResult:
    offset_s: float
    offset_frames: float
    confidence: float
    method: str  # "audio" | "flash" | "motion"
    fps: float
    details: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)

    def summary(self) -> str:
        return (f"offset {self.offset_s * 1000:+.2f} ms = {self.offset_frames:+.3f} frames at {self.fps:g} fps "
                f"(front started later if positive), confidence {self.confidence:.2f}, method {self.method}")


# -- reading ------------------------------------------------------------------------------------
def read_audio(path: str | Path, max_seconds: float | None = None) -> AudioTrack:
    """Decode the first audio stream to mono float32, placed by presentation time (pts)."""
    p = Path(path)
    if not p.is_file():
        raise SandtrackError(f"file not found: {p}")
    try:
        container = av.open(str(p))
    except (av.error.FFmpegError, OSError, ValueError) as exc:
        raise SandtrackError(f"{p}: not a readable media file ({_short(exc)})") from None
    chunks: list[tuple[float, np.ndarray]] = []
    rate = None
    try:
        if not container.streams.audio:
            raise NoUsableAudio(f"{p}: no audio stream")
        stream = container.streams.audio[0]
        next_t = None
        try:
            for frame in container.decode(stream):
                if frame.samples == 0:
                    continue
                rate = rate or frame.sample_rate
                if frame.sample_rate != rate:
                    raise SandtrackError(f"{p}: audio sample rate changes within the file")
                if frame.pts is not None:
                    tb = frame.time_base or stream.time_base or Fraction(1, rate)
                    t0 = float(frame.pts * tb)
                else:
                    t0 = next_t if next_t is not None else 0.0
                mono = _to_mono(frame)
                chunks.append((t0, mono))
                next_t = t0 + len(mono) / rate
                if max_seconds is not None and next_t - chunks[0][0] > max_seconds:
                    break
        except (av.error.InvalidDataError, av.error.FFmpegError):
            pass  # damaged tail: keep what decoded
    finally:
        container.close()
    if not chunks:
        raise NoUsableAudio(f"{p}: the audio stream holds no samples")
    start = chunks[0][0]
    end = max(t + len(x) / rate for t, x in chunks)
    out = np.zeros(int(round((end - start) * rate)) + 1, dtype=np.float32)
    for t, x in chunks:
        k = int(round((t - start) * rate))
        if k < 0:
            continue
        n = min(len(x), len(out) - k)
        out[k:k + n] = x[:n]
    if not np.any(out):
        raise NoUsableAudio(f"{p}: the audio is silent")
    return AudioTrack(out, int(rate), start, str(p))


def _to_mono(frame) -> np.ndarray:
    raw = frame.to_ndarray()
    channels = len(frame.layout.channels) or 1
    arr = raw if frame.format.is_planar else raw.reshape(-1, channels).T
    arr = arr.astype(np.float32)
    if np.issubdtype(raw.dtype, np.integer):
        arr /= float(np.iinfo(raw.dtype).max)
    return arr.mean(axis=0)


# -- signal helpers -----------------------------------------------------------------------------
def _resample(x: np.ndarray, rate_in: int, rate_out: int) -> np.ndarray:
    if rate_in == rate_out:
        return x
    g = math.gcd(int(rate_in), int(rate_out))
    return signal.resample_poly(x.astype(np.float64), rate_out // g, rate_in // g)


def _coarse(x: np.ndarray, rate: int) -> np.ndarray:
    """Band-passed COARSE_RATE signal for the search: a short anti-alias FIR when the rate is a
    multiple of COARSE_RATE (fast on long tracks), then the zero-phase band-pass (hum must go:
    in phase at each file start, it would correlate at every multiple of its period)."""
    x = np.asarray(x, np.float32)
    if rate % COARSE_RATE == 0:
        q = rate // COARSE_RATE
        h = signal.firwin(6 * q + 1, 0.45 * COARSE_RATE, fs=rate).astype(np.float32)
        y = signal.upfirdn(h, x, 1, q)[3:]  # drop the FIR's delay: 3q input = 3 output samples
    else:
        y = _resample(x, rate, COARSE_RATE)
    return _bandpass(y, COARSE_RATE, COARSE_BAND).astype(np.float32)


def _bandpass(x: np.ndarray, rate: float, band: tuple[float, float]) -> np.ndarray:
    lo, hi = band
    hi = min(hi, 0.45 * rate)
    sos = signal.butter(4, [lo, hi], btype="bandpass", fs=rate, output="sos")
    return signal.sosfiltfilt(sos, x)


def _transients(x: np.ndarray, rate: float, count: int = 3, min_gap_s: float = 1.0) -> list[float]:
    """Times (s from the track start) of the `count` strongest transients, strongest first."""
    hop = max(int(0.005 * rate), 1)
    win = 2 * hop
    n = (len(x) - win) // hop
    if n < 10:
        return []
    idx = np.arange(n)[:, None] * hop + np.arange(win)[None, :]
    energy = np.mean(x[idx] ** 2, axis=1) + 1e-20
    bg_len = max(int(1.0 / 0.005) | 1, 3)
    from scipy.ndimage import median_filter

    background = median_filter(energy, size=min(bg_len, n if n % 2 else n - 1), mode="nearest") + 1e-20
    score = energy / background
    edge = int(EDGE_S / 0.005) + 1
    score[:edge] = 0
    score[-edge:] = 0
    out: list[float] = []
    gap = int(min_gap_s / 0.005)
    for _ in range(count):
        k = int(np.argmax(score))
        if score[k] <= 1.5:  # not a transient at all
            break
        out.append((k * hop + win / 2) / rate)
        score[max(0, k - gap):k + gap] = 0
    return out


def _ncc(template: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation of `template` at every valid position of `x` (len(x)-len(t)+1)."""
    t = template - template.mean()
    tn = np.sqrt(np.sum(t ** 2))
    m = len(t)
    if len(x) < m or tn == 0:
        return np.zeros(0)
    num = signal.oaconvolve(x, t[::-1], mode="valid")
    c1 = np.concatenate([[0.0], np.cumsum(x, dtype=np.float64)])
    c2 = np.concatenate([[0.0], np.cumsum(np.square(x, dtype=np.float64))])
    s1 = c1[m:] - c1[:-m]
    s2 = c2[m:] - c2[:-m]
    var = np.maximum(s2 - s1 * s1 / m, 1e-12 * tn * tn)
    return num / (tn * np.sqrt(var))


def _parabolic(y: np.ndarray, k: int) -> float:
    """Sub-sample position of the peak at index k (parabola through k-1, k, k+1)."""
    if k <= 0 or k >= len(y) - 1:
        return float(k)
    a, b, c = y[k - 1], y[k], y[k + 1]
    den = a - 2 * b + c
    if den >= 0:
        return float(k)
    return float(k + 0.5 * (a - c) / den)


def _prominence(c: np.ndarray, k: int, exclude: int) -> tuple[float, float]:
    """(confidence, noise sigma): 1 - second peak / peak, second peak floored at 4 robust sigmas."""
    peak = float(c[k])
    if peak <= 0:
        return 0.0, 0.0
    mask = np.ones(len(c), bool)
    mask[max(0, k - exclude):k + exclude + 1] = False
    rest = c[mask]
    if len(rest) == 0:
        return 0.0, 0.0
    sub = rest[:: max(1, len(rest) // 200_000)]  # robust spread from a subsample: long tracks
    sigma = 1.4826 * float(np.median(np.abs(sub - np.median(sub))))
    second = max(float(rest.max()), 4.0 * sigma)
    return float(np.clip(1.0 - second / peak, 0.0, 1.0)), sigma


# -- audio offset -------------------------------------------------------------------------------
def audio_offset(side: AudioTrack, front: AudioTrack, fps: float = 50.0, max_offset_s: float | None = None,
                 min_confidence: float = MIN_CONFIDENCE) -> SyncResult:
    """Offset from two audio tracks (see the module docstring). Raises LowConfidence when unsure."""
    rate = min(side.sample_rate, front.sample_rate)
    a_full = _resample(side.samples, side.sample_rate, rate).astype(np.float32, copy=False)
    b_full = _resample(front.samples, front.sample_rate, rate).astype(np.float32, copy=False)
    for trk, x in ((side, a_full), (front, b_full)):
        if len(x) < rate * 1.0:
            raise NoUsableAudio(f"{trk.path or 'audio'}: audio shorter than 1 s")
    a_c = _coarse(a_full, rate)
    b_c = _coarse(b_full, rate)

    # Strongest transients of each track, tried in rank order (side 1, front 1, side 2, ...); stop
    # early once the two tracks' strongest transients agree on a confident offset.
    ranked = []
    for source, x, y, tx, ty in (("side", a_c, b_c, side.start_s, front.start_s),
                                 ("front", b_c, a_c, front.start_s, side.start_s)):
        for r, t_ev in enumerate(_transients(x, COARSE_RATE)):  # s from the track start
            ranked.append((r, source, x, y, tx, ty, t_ev))
    ranked.sort(key=lambda c: (c[0], c[1] != "side"))
    candidates = []  # (confidence, peak, offset_s, source, window)
    for _r, source, x, y, tx, ty, t_ev in ranked:
        found = _coarse_match(x, y, tx, ty, t_ev, source, max_offset_s)
        if found is not None:
            candidates.append(found)
        good = [c for c in candidates if c[0] >= max(min_confidence, 0.4)]
        if len({c[3] for c in good}) == 2 and any(
                abs(g[2] - h[2]) < 0.002 for g in good for h in good if g[3] != h[3]):
            break
    if not candidates:
        raise LowConfidence("no transient (clap) found in the audio: sync from the video or enter the offset")
    candidates.sort(key=lambda c: (c[0], c[1]), reverse=True)
    conf, peak, coarse, source, (w0, w1) = candidates[0]
    agreeing = sum(1 for c in candidates[1:] if c[0] >= min_confidence and abs(c[2] - coarse) < 0.005)

    # Fine refinement at the native rate, same window in side time, on band-passed excerpts.
    if source == "front":
        w0, w1 = w0 + coarse, w1 + coarse
    t_side_event = w0 + 0.03
    a_f, ta = _excerpt(a_full, side.start_s, rate, w0 - 0.5, w1 + 0.5)
    b_f, tb = _excerpt(b_full, front.start_s, rate, w0 - coarse - 0.5, w1 - coarse + 0.5)
    fine = _fine_match(_bandpass(a_f, rate, FINE_BAND), _bandpass(b_f, rate, FINE_BAND), ta, tb, rate, (w0, w1),
                       coarse)
    offset = fine if fine is not None else coarse

    gcc = _gcc_phat_check(a_full, b_full, side.start_s, front.start_s, rate, offset, t_side_event)
    details = {
        "event_side_s": t_side_event,
        "event_front_s": t_side_event - offset,
        "coarse_offset_s": coarse,
        "clap_peak_ncc": peak,
        "clap_confidence": conf,
        "transient_from": source,
        "agreeing_candidates": agreeing,
        "gcc_phat_offset_s": gcc[0],
        "gcc_phat_confidence": gcc[1],
        "gcc_phat_difference_ms": None if gcc[0] is None else (gcc[0] - offset) * 1000,
        "sample_rate": rate,
        "audio_start_s": {"side": side.start_s, "front": front.start_s},
    }
    # A weak peak is not trusted even when unique: two different bangs heard by one camera each
    # correlate at ~0.2-0.3; the same clap heard by both at >= 0.4 in the tests' noise range.
    confidence = conf * min(1.0, peak / PEAK_TRUSTED)
    if gcc[0] is not None and gcc[1] >= 0.5 and abs(gcc[0] - offset) > 0.010:
        confidence = min(confidence, 0.5 * (1 - gcc[1]))
        details["warning"] = "GCC-PHAT over the shared span disagrees with the clap by more than 10 ms"
    result = SyncResult(offset, offset * fps, confidence, "audio", fps, details)
    if confidence < min_confidence:
        raise LowConfidence(
            f"audio sync is not reliable (confidence {confidence:.2f} < {min_confidence:.2f}; "
            f"best guess {offset * 1000:+.1f} ms): clap louder near both cameras, or sync from the video")
    return result


def _event_extent(x: np.ndarray, rate: float, t_ev: float) -> tuple[float, float]:
    """Window (s from the track start) around a transient: from just before its onset to where its
    energy decays into the background (0.06-0.4 s), so little noise dilutes the correlation."""
    hop = max(int(0.005 * rate), 1)
    k_ev = int(t_ev * rate)
    lo = max(k_ev - int(1.0 * rate), 0)
    seg = x[lo:k_ev + int(0.5 * rate)]
    n = len(seg) // hop
    if n < 4:
        return t_ev - WINDOW_BEFORE_S, t_ev + WINDOW_AFTER_S
    e = np.mean(seg[:n * hop].reshape(n, hop) ** 2, axis=1)
    k0 = (k_ev - lo) // hop
    background = float(np.median(e[:max(k0 - 4, 1)])) if k0 > 4 else float(np.median(e))
    after = e[k0:]
    below = np.nonzero(after < 2.0 * background)[0]
    dur = (below[0] * hop / rate) if len(below) else WINDOW_AFTER_S
    return t_ev - 0.03, t_ev + float(np.clip(dur + 0.02, 0.06, WINDOW_AFTER_S))


def _excerpt(x: np.ndarray, t0: float, rate: int, lo_s: float, hi_s: float) -> tuple[np.ndarray, float]:
    """Samples of x between absolute times lo_s..hi_s (clipped), and the time of its first sample."""
    i0 = max(int(math.floor((lo_s - t0) * rate)), 0)
    i1 = min(int(math.ceil((hi_s - t0) * rate)), len(x))
    i1 = max(i1, i0)
    return np.asarray(x[i0:i1], np.float64), t0 + i0 / rate


def _coarse_match(x, y, tx, ty, t_ev, source, max_offset_s):
    """Correlate a window of x around t_ev against all of y.
    Returns (conf, peak, offset_s, source, (window start, end) in x's absolute time)."""
    w0, w1 = _event_extent(x, COARSE_RATE, t_ev)
    i0 = max(int(round(w0 * COARSE_RATE)), 0)
    i1 = min(int(round(w1 * COARSE_RATE)), len(x))
    if i1 - i0 < 0.05 * COARSE_RATE:
        return None
    win = x[i0:i1] * signal.windows.tukey(i1 - i0, 0.2)
    c = _ncc(win, y)
    if len(c) == 0:
        return None
    # offset_s = t_side - t_front; for a side window matched at front sample j:
    #   t_side = tx + i0/r, t_front = ty + j/r.  For a front window, the roles swap.
    j = np.arange(len(c))
    offs = (tx + i0 / COARSE_RATE) - (ty + j / COARSE_RATE)
    if source == "front":
        offs = -offs
    if max_offset_s is not None:
        c = np.where(np.abs(offs) <= max_offset_s, c, 0.0)
    k = int(np.argmax(c))
    conf, _ = _prominence(c, k, int(EXCLUDE_S * COARSE_RATE))
    kk = _parabolic(c, k)
    off = (tx + i0 / COARSE_RATE) - (ty + kk / COARSE_RATE)
    if source == "front":
        off = -off
    return conf, float(c[k]), float(off), source, (tx + i0 / COARSE_RATE, tx + i1 / COARSE_RATE)


def _fine_match(a, b, ta, tb, rate, window, coarse, search_s=0.003):
    i0 = int(round((window[0] - ta) * rate))
    i1 = int(round((window[1] - ta) * rate))
    i0, i1 = max(i0, 0), min(i1, len(a))
    if i1 - i0 < 0.05 * rate or len(b) == 0:
        return None
    win = a[i0:i1] * signal.windows.tukey(i1 - i0, 0.2)
    # expected front sample of the window start
    j_exp = (ta + i0 / rate - coarse - tb) * rate
    s = int(math.ceil(search_s * rate)) + 2
    j0 = int(math.floor(j_exp)) - s
    if j0 < 0 or j0 + (i1 - i0) + 2 * s > len(b):
        return None
    c = _ncc(win, b[j0:j0 + (i1 - i0) + 2 * s])
    k = int(np.argmax(c))
    kk = _parabolic(c, k)
    return float((ta + i0 / rate) - (tb + (j0 + kk) / rate))


def _gcc_phat_check(a, b, ta, tb, rate, offset, t_side_event, span_s=20.0, search_s=0.050):
    """GCC-PHAT over the shared span (at most span_s around the event). Returns (offset_s|None, confidence)."""
    # shared span in side time
    lo = max(ta, tb + offset)
    hi = min(ta + len(a) / rate, tb + offset + len(b) / rate)
    lo = max(lo, t_side_event - span_s / 2)
    hi = min(hi, lo + span_s)
    if hi - lo < 1.0:
        return None, 0.0
    n = int((hi - lo) * rate)
    ia = max(int(math.ceil((lo - ta) * rate)), 0)
    lo = ta + ia / rate  # on a's sample grid
    ib = int(round((lo - offset - tb) * rate))
    if ib < 0:
        ia, ib = ia - ib, 0
        lo = ta + ia / rate
    n = min(n, len(a) - ia, len(b) - ib)
    if n < rate:
        return None, 0.0
    # b's nominal position is rounded to a sample: keep the fraction
    frac = (lo - offset - tb) * rate - ib
    xa = a[ia:ia + n] * signal.windows.tukey(n, 0.05)
    xb = b[ib:ib + n] * signal.windows.tukey(n, 0.05)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    A = np.fft.rfft(xa, nfft)
    B = np.fft.rfft(xb, nfft)
    R = A * np.conj(B)
    R /= np.maximum(np.abs(R), 1e-12)
    f = np.fft.rfftfreq(nfft, 1 / rate)
    R[(f < FINE_BAND[0]) | (f > min(FINE_BAND[1], 0.45 * rate))] = 0
    r = np.fft.irfft(R, nfft)
    m = int(search_s * rate)
    cc = np.concatenate([r[-m:], r[:m + 1]])  # lags -m..m; lag L: a[t] ~ b[t - L]
    k = int(np.argmax(cc))
    conf, _ = _prominence(cc, k, int(0.002 * rate))
    lag = _parabolic(cc, k) - m
    # a[t] matches b[t - lag]: side time lo + t/r  <-> front time (lo - offset) + (t - lag - frac)/r
    return float(offset + (lag + frac) / rate), conf


# -- video fallback -----------------------------------------------------------------------------
def _activity(src, max_frames: int | None = None, size=(96, 54)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    import cv2

    n = len(src) if max_frames is None else min(len(src), max_frames)
    bright = np.zeros(n)
    motion = np.zeros(n)
    prev = None
    for i, img in src.iter_frames(0, n):
        g = cv2.resize(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), size, interpolation=cv2.INTER_AREA).astype(np.float32)
        bright[i] = g.mean()
        motion[i] = 0.0 if prev is None else float(np.mean(np.abs(g - prev)))
        prev = g
    if n > 1:
        motion[0] = motion[1]
    return np.asarray(src.times_s[:n], dtype=np.float64), bright, motion


def _onset(t: np.ndarray, y: np.ndarray, min_rise: float = 0.0, smooth: int = 1,
           sustain: int = 1, level: float = 0.25) -> tuple[float, float] | None:
    """Time where y first rises above its baseline and stays there for `sustain` frames (sub-frame,
    by linear interpolation), and a sharpness score (rise / baseline noise).

    smooth > 1: a running median first, which removes one-frame spikes (a keyframe's change of
    coding noise looks like motion in every view at the same file time). The threshold is
    baseline + max(6 noise sigmas, `level` x rise), the rise measured to the 95th percentile."""
    if len(y) < 8:
        return None
    if smooth > 1:
        from scipy.ndimage import median_filter

        y = median_filter(np.asarray(y, float), size=smooth, mode="nearest")
    base_n = max(5, len(y) // 10)
    base = float(np.median(y[:base_n]))
    top = float(np.percentile(y, 95)) if smooth > 1 else float(np.max(y))
    rise = top - base
    noise = max(1.4826 * float(np.median(np.abs(y[:base_n] - base))), 0.002 * abs(rise), 1e-9)
    if rise <= 10 * noise or rise < min_rise:
        return None
    thr = base + max(6 * noise, level * rise)
    above = y > thr
    run = np.convolve(above.astype(int), np.ones(sustain, int), mode="full")[sustain - 1:]  # run[k] = sum above[k:k+s]
    ok = np.nonzero(run[: len(y) - sustain + 1] == sustain)[0]
    ok = ok[ok > 0]
    if len(ok) == 0:
        return None
    k = int(ok[0])
    f = (thr - y[k - 1]) / max(y[k] - y[k - 1], 1e-12)
    return float(t[k - 1] + np.clip(f, 0, 1) * (t[k] - t[k - 1])), rise / noise


def video_offset(side_src, front_src, fps: float | None = None, max_frames: int | None = None,
                 min_confidence: float = MIN_CONFIDENCE) -> SyncResult:
    """Offset from a flash or the motion onset seen in both views (FrameSource objects)."""
    fps = fps or float(side_src.fps)
    ts, bs, ms = _activity(side_src, max_frames)
    tf, bf, mf = _activity(front_src, max_frames)
    tries = []
    for method, ys, yf, kw in (("flash", np.abs(bs - np.median(bs[: max(3, len(bs) // 10)])),
                                np.abs(bf - np.median(bf[: max(3, len(bf) // 10)])), {"min_rise": FLASH_MIN_LEVELS}),
                               ("motion", ms, mf, {"smooth": 3, "sustain": 10, "level": 0.0})):
        os_, of_ = _onset(ts, ys, **kw), _onset(tf, yf, **kw)
        if os_ is None or of_ is None:
            continue
        offset = os_[0] - of_[0]
        xc = _curve_lag(ts, ys, tf, yf, fps)
        sharp = min(os_[1], of_[1])
        conf = float(np.clip((sharp - 8) / (40 if method == "flash" else 10), 0, 1))
        if method == "flash" and xc is not None and abs(xc - offset) > 1.5 / fps:
            conf *= 0.3
        if method == "motion":
            conf = min(conf, 0.6)  # the views see the motion differently: good to about a frame
        tries.append(SyncResult(offset, offset * fps, conf, method, fps, {
            "event_side_s": os_[0], "event_front_s": of_[0], "curve_correlation_offset_s": xc,
            "sharpness": sharp}))
        if method == "flash" and conf >= min_confidence:
            break
    if not tries:
        raise LowConfidence("no flash or motion onset visible in both videos: enter the offset by hand")
    best = max(tries, key=lambda r: r.confidence)
    if best.confidence < min_confidence:
        raise LowConfidence(f"video sync is not reliable (confidence {best.confidence:.2f}; best guess "
                            f"{best.offset_s * 1000:+.1f} ms from {best.method}): enter the offset by hand")
    return best


def _curve_lag(ts, ys, tf, yf, fps, up: int = 8) -> float | None:
    """Offset by correlating the changes of the two activity curves on a common fine time grid (the
    changes, not the levels: a step correlates badly with itself, its edge well)."""
    dt = 1.0 / (fps * up)
    if len(ts) < 4 or len(tf) < 4:
        return None
    gs = np.arange(ts[0], ts[-1], dt)
    gf = np.arange(tf[0], tf[-1], dt)
    a = np.abs(np.diff(np.interp(gs, ts, ys), prepend=ys[0]))
    b = np.abs(np.diff(np.interp(gf, tf, yf), prepend=yf[0]))
    a = (a - a.mean()) / (a.std() + 1e-12)
    b = (b - b.mean()) / (b.std() + 1e-12)
    c = signal.correlate(a, b, mode="full", method="fft")
    k = int(np.argmax(c))
    lag = _parabolic(c, k) - (len(b) - 1)  # a[i] ~ b[i - lag]
    return float(gs[0] - gf[0] + lag * dt)


# -- entry point --------------------------------------------------------------------------------
def estimate_offset(side_path: str | Path, front_path: str | Path, method: str = "auto", fps: float | None = None,
                    max_offset_s: float | None = None, min_confidence: float = MIN_CONFIDENCE,
                    max_frames: int | None = None) -> SyncResult:
    """Offset (s, front started later if positive) between two recordings.

    method: "audio", "video" or "auto" (audio; the video when there is no usable audio or the audio
    is not conclusive). Raises SandtrackError (LowConfidence) rather than return an unreliable offset.
    """
    from .video import FrameSource

    if method not in ("auto", "audio", "video"):
        raise SandtrackError(f"unknown sync method {method!r} (auto, audio, video)")
    if fps is None:
        try:
            with FrameSource(side_path, cache_mb=8) as s:
                fps = float(s.fps)
        except SandtrackError:
            if method == "video":
                raise
            fps = 50.0
    audio_problem = None
    if method in ("auto", "audio"):
        try:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(2) as pool:  # decoding releases the GIL: both tracks at once
                tracks = list(pool.map(read_audio, (side_path, front_path)))
            return audio_offset(tracks[0], tracks[1], fps, max_offset_s, min_confidence)
        except (NoUsableAudio, LowConfidence) as exc:
            if method == "audio":
                raise
            audio_problem = str(exc)
    with FrameSource(side_path, cache_mb=64) as s, FrameSource(front_path, cache_mb=64) as f:
        try:
            res = video_offset(s, f, fps, max_frames, min_confidence)
        except LowConfidence as exc:
            if audio_problem:
                raise LowConfidence(f"{audio_problem}; {exc}") from None
            raise
    if audio_problem:
        res.details["audio_problem"] = audio_problem
    return res


SPEED_OF_SOUND_M_S = 343.0  # dry air at 20 °C


def sound_path_bound_s(calibration, a: str = "side", b: str = "front") -> float | None:
    """How far (s) the sound's path can shift an audio offset between cameras `a` and `b`: a clap reaches
    them up to their distance apart / the speed of sound apart (zero for a clap as far from both); None
    without both cameras in the calibration."""
    if calibration is None or a not in calibration.cameras or b not in calibration.cameras:
        return None
    d_mm = float(np.linalg.norm(calibration.cameras[a].center_mm - calibration.cameras[b].center_mm))
    return d_mm / 1000.0 / SPEED_OF_SOUND_M_S


def sound_path_line(bound_s: float) -> str:
    """What `sound_path_bound_s` means for the user, in one line."""
    return (f"the clap's sound path may shift it by up to ±{1000 * bound_s:.2f} ms (the cameras are "
            f"{bound_s * SPEED_OF_SOUND_M_S:.2f} m apart): clap about as far from both")


def _short(exc: BaseException) -> str:
    return str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
