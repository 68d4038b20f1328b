"""Sync: accuracy and speed of the audio offset; refusal without a shared event; sample_data if present.

- files: synthetic mp4 pairs (AAC audio starting 0.25 s / 0.05 s into the files, independent
  noise, mains hum in phase at each file start, one shared clap), several non-whole-frame offsets.
- long: 10 minutes of 48 kHz audio per camera (arrays), clap somewhere in the middle; the time (wall
  and CPU) of `audio_offset` and, separately, of decoding a 10-minute AAC track with PyAV.
- refusal: two tracks with a clap each but nothing shared: how often sync refuses (it should).
- sample_data: `sandtrack sync` on sample_data/experiment/{side,front}.mp4 vs ground_truth/sync.json.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "tests"))

from sandtrack_tui import sync  # noqa: E402
from sync_media import clap, make_pair, scene_audio, write_av  # noqa: E402

RATE = 48000


def _files(tmp: Path) -> dict:
    errs, times = [], []
    for k, off in enumerate([0.7473, -0.4119, 1.2301, 0.0137, 2.5555]):
        d = tmp / f"pair{k}"
        d.mkdir()
        side, front = make_pair(d, offset_s=off, clap_world_s=3.1 + max(off, 0), duration_s=6.0 + abs(off), seed=k)
        t0 = time.perf_counter()
        res = sync.estimate_offset(side, front)
        times.append(time.perf_counter() - t0)
        errs.append(abs(res.offset_s - off) * 1000)
    return {"files_pairs": len(errs), "files_max_error_ms": round(max(errs), 4),
            "files_mean_error_ms": round(float(np.mean(errs)), 4), "files_seconds_per_pair": round(np.mean(times), 2)}


def _long(tmp: Path, minutes: float = 10.0) -> dict:
    rng = np.random.default_rng(11)
    w = clap(RATE, rng)
    dur = minutes * 60
    off = 3.2171
    a = scene_audio(RATE, 0.0, 0.25, dur, 371.3, w, rng, noise=0.05, hum=0.5)
    b = scene_audio(RATE, off, 0.10, dur, 371.3, w, rng, noise=0.05, hum=0.5)
    A, B = sync.AudioTrack(a, RATE, 0.25), sync.AudioTrack(b, RATE, 0.10)
    t0, c0 = time.perf_counter(), time.process_time()
    res = sync.audio_offset(A, B)
    t_off, c_off = time.perf_counter() - t0, time.process_time() - c0
    p = tmp / "long.mp4"
    write_av(p, n_frames=2, audio=a, rate=RATE, audio_start_s=0.25)
    t0, c0 = time.perf_counter(), time.process_time()
    trk = sync.read_audio(p)
    t_dec, c_dec = time.perf_counter() - t0, time.process_time() - c0
    return {"long_minutes": minutes, "long_error_ms": round(abs(res.offset_s - off) * 1000, 4),
            "long_offset_seconds": round(t_off, 2), "long_offset_cpu_seconds": round(c_off, 2),
            "long_decode_seconds": round(t_dec, 2), "long_decode_cpu_seconds": round(c_dec, 2),
            "long_total_seconds": round(t_off + t_dec, 2), "long_decoded_s": round(trk.duration_s, 1)}


def _refusal(trials: int = 10) -> dict:
    refused = 0
    for k in range(trials):
        rng = np.random.default_rng(100 + k)
        a = scene_audio(RATE, 0.0, 0.2, 6.0, 2.5, clap(RATE, rng), rng, noise=0.05)
        b = scene_audio(RATE, 0.5, 0.1, 6.0, 4.1, clap(RATE, rng), rng, noise=0.05)
        try:
            sync.audio_offset(sync.AudioTrack(a, RATE, 0.2), sync.AudioTrack(b, RATE, 0.1))
        except sync.LowConfidence:
            refused += 1
    return {"refusal_trials": trials, "refused_without_shared_event": refused}


def _sample_data() -> dict:
    exp = ROOT / "sample_data" / "experiment"
    truth = ROOT / "sample_data" / "ground_truth" / "sync.json"
    if not (exp / "side.mp4").is_file() or not truth.is_file():
        return {"sample_data": "absent"}
    true = float(json.loads(truth.read_text())["offset_s"])
    t0 = time.perf_counter()
    res = sync.estimate_offset(exp / "side.mp4", exp / "front.mp4")
    return {"sample_true_offset_s": true, "sample_offset_s": round(res.offset_s, 6),
            "sample_error_ms": round(abs(res.offset_s - true) * 1000, 4), "sample_confidence": round(res.confidence, 2),
            "sample_method": res.method, "sample_seconds": round(time.perf_counter() - t0, 2),
            "sample_gcc_phat_difference_ms": res.details.get("gcc_phat_difference_ms")}


def run() -> dict:
    out: dict = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        out.update(_files(tmp))
        out.update(_long(tmp))
    out.update(_refusal())
    out.update(_sample_data())
    return out


if __name__ == "__main__":
    for k, v in run().items():
        print(f"{k}: {v}")
