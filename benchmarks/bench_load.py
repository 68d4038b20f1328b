"""Load: a long 1080p50 pair tracked headless; peak memory (RSS) and speed over time.

The pair is SANDTRACK_LOAD_MINUTES long (default 30). To keep generation cheap, one minute of
1080p50 H.264 (8 blue markers circling on a sand texture, period 60 s) is rendered once and
remuxed end to end with shifted timestamps, so the long file is a real continuous stream.
`sandtrack track --auto-seed` then runs in a child process while RSS and the number of rows
committed to the project are sampled.
"""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

FPS = 50


def _render_minute(path: Path, seconds: int = 60) -> None:
    rng = np.random.default_rng(7)
    sand = rng.normal(150, 18, (1080, 1920)).astype(np.float32)
    sand = cv2.GaussianBlur(sand, (0, 0), 1.2)
    base = np.dstack([sand * 0.78, sand * 0.9, sand]).clip(0, 255).astype(np.uint8)
    centres = [(300 + 180 * k, 540 + (60 if k % 2 else -60)) for k in range(8)]
    with av.open(str(path), "w") as out:
        s = out.add_stream("libx264", rate=Fraction(FPS))
        s.width, s.height, s.pix_fmt = 1920, 1080, "yuv420p"
        s.options = {"bf": "2", "g": "50", "crf": "26", "preset": "ultrafast"}
        for i in range(seconds * FPS):
            img = base.copy()
            phase = 2 * np.pi * i / (seconds * FPS)
            for k, (cx, cy) in enumerate(centres):
                x = cx + 60 * np.cos(phase + k)
                y = cy + 60 * np.sin(phase + k)
                cv2.circle(img, (int(round(x * 16)), int(round(y * 16))), 5 * 16, (190, 90, 30), -1,
                           cv2.LINE_AA, shift=4)
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                out.mux(p)
        for p in s.encode():
            out.mux(p)


def _remux_repeated(src: Path, dst: Path, times: int) -> None:
    with av.open(str(src)) as inp, av.open(str(dst), "w") as out:
        istream = inp.streams.video[0]
        ostream = out.add_stream_from_template(istream)
        packets = [p for p in inp.demux(istream) if p.size > 0]
        span = max(p.pts for p in packets) + packets[1].duration if packets[1].duration else None
        if not span:
            span = int(round(60 / istream.time_base))
        for k in range(times):
            for p in packets:
                p.stream = ostream
                p.pts += span if k else 0
                p.dts += span if k else 0
                out.mux(p)


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def run(minutes: float | None = None) -> dict:
    minutes = float(minutes or os.environ.get("SANDTRACK_LOAD_MINUTES", 30))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        minute = tmp / "minute.mp4"
        _render_minute(minute, seconds=min(60, max(1, int(minutes * 60))))
        long = tmp / "long.mp4"
        _remux_repeated(minute, long, max(1, int(np.ceil(minutes))))
        proj = tmp / "load.sandtrack"
        sandtrack = [sys.executable, "-m", "sandtrack_tui"]
        subprocess.run([*sandtrack, "new", proj, "--side", long, "--front", long], check=True,
                       capture_output=True)
        t0 = time.perf_counter()
        child = subprocess.Popen([*sandtrack, "track", proj, "--auto-seed", "--allow-unsynced", "--json"],
                                 stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        samples = []
        conn = sqlite3.connect(f"file:{proj}?mode=ro", uri=True)
        while child.poll() is None:
            time.sleep(5)
            try:
                rows = conn.execute("SELECT COUNT(*) FROM points").fetchone()[0]
            except sqlite3.Error:
                rows = samples[-1][2] if samples else 0
            samples.append((time.perf_counter() - t0, _rss_mb(child.pid), rows))
        out = child.stdout.read()
        elapsed = time.perf_counter() - t0
        frames = int(minutes * 60 * FPS)
        rates = []
        for (ta, _, ra), (tb, _, rb) in zip(samples, samples[1:], strict=False):
            if tb > ta and rb > ra:
                rates.append((rb - ra) / (tb - ta) / 16)  # 8 markers x 2 cameras per frame
        third = max(len(rates) // 3, 1)
        return {
            "minutes": minutes,
            "frames_per_camera": frames,
            "exit_code": child.returncode,
            "seconds": round(elapsed, 1),
            "frames_per_s": round(frames / elapsed, 1),
            "peak_rss_mb": round(max((s[1] for s in samples), default=0.0), 1),
            "rate_first_third_fps": round(float(np.mean(rates[:third])), 1) if rates else None,
            "rate_last_third_fps": round(float(np.mean(rates[-third:])), 1) if rates else None,
            "result_tail": out[-200:],
        }


if __name__ == "__main__":
    print(run(float(sys.argv[1]) if len(sys.argv) > 1 else None))
