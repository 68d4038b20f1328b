"""Frame-accurate decoding speed on a 1080p H.264 clip: sequential fps and random-seek latency."""

from __future__ import annotations

import random
import sys
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sandtrack_tui.video import FrameSource  # noqa: E402


def make_clip(path: Path, n: int = 250) -> Path:
    """1080p50 H.264 with B-frames and a GoPro-like GOP, textured moving content."""
    rng = np.random.default_rng(0)
    base = rng.integers(60, 200, (1080 + 64, 1920 + 64, 3), dtype=np.uint8)
    with av.open(str(path), "w") as out:
        s = out.add_stream("libx264", rate=Fraction(50))
        s.width, s.height, s.pix_fmt = 1920, 1080, "yuv420p"
        s.options = {"bf": "2", "g": "25", "crf": "23", "preset": "veryfast"}
        for i in range(n):
            img = np.ascontiguousarray(base[i % 64:i % 64 + 1080, (2 * i) % 64:(2 * i) % 64 + 1920])
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                out.mux(p)
        for p in s.encode():
            out.mux(p)
    return path


def run() -> dict:
    sample = ROOT / "sample_data" / "experiment" / "side.mp4"
    with tempfile.TemporaryDirectory() as tmp:
        path = sample if sample.exists() else make_clip(Path(tmp) / "clip.mp4")
        t0 = time.perf_counter()
        src = FrameSource(path, cache_mb=0.001)
        open_s = time.perf_counter() - t0
        n = min(len(src), 250)
        t0 = time.perf_counter()
        for _ in src.iter_frames(0, n):
            pass
        seq_fps = n / (time.perf_counter() - t0)
        rnd = FrameSource(path, cache_mb=0.001)
        rng = random.Random(0)
        idx = [rng.randrange(len(src)) for _ in range(40)]
        lat = []
        for i in idx:
            t0 = time.perf_counter()
            rnd.frame(i)
            lat.append((time.perf_counter() - t0) * 1000)
        return {
            "clip": "sample_data/experiment/side.mp4" if path == sample else "generated 1080p50 H.264, GOP 25",
            "frames": len(src),
            "open_ms": round(open_s * 1000, 1),
            "sequential_decode_fps": round(seq_fps, 1),
            "random_seek_median_ms": round(float(np.median(lat)), 1),
            "random_seek_p95_ms": round(float(np.percentile(lat, 95)), 1),
        }


if __name__ == "__main__":
    print(run())
