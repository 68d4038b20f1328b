"""Terminal UI speed: rendering one 100x30-cell view of a 1080p frame (downscale + marker boost +
overlays + Rich segments), truecolor and 256 colours, and a frame step in the running app (key
press -> both views decoded, downscaled and composed; the app runs headless, so the terminal write
is not included).

Uses sample_data/experiment/*.mp4 when present, else a generated 1080p clip.
Targets: render <= 30 ms per view, step <= 100 ms. Wall-clock figures depend on how busy the
machine is; the CPU-time figure does not.
"""

from __future__ import annotations

import asyncio
import statistics
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

from sandtrack_tui.store import Project  # noqa: E402
from sandtrack_tui.tui.frame_view import (  # noqa: E402
    MarkerMark,
    Overlays,
    StripBuilder,
    ViewTransform,
    draw_overlays,
    quantize,
    render_pixels,
)
from sandtrack_tui.video import FrameSource  # noqa: E402

SAMPLE = ROOT / "sample_data" / "experiment"


def _synthetic_frame(i: int, w: int = 1920, h: int = 1080) -> np.ndarray:
    rng = np.random.default_rng(i)
    img = np.clip(np.array([120, 170, 200]) + rng.normal(0, 20, (h // 4, w // 4, 3)), 0, 255).astype(np.uint8)
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_LINEAR)
    for k in range(8):
        cv2.circle(img, (300 + 180 * k + 2 * i, 500 + 15 * k), 5, (190, 70, 20), -1, cv2.LINE_AA)
    return img


def _write_clip(path: Path, n: int = 60) -> Path:
    with av.open(str(path), "w") as out:
        st = out.add_stream("libx264", rate=Fraction(50))
        st.width, st.height, st.pix_fmt = 1920, 1080, "yuv420p"
        st.options = {"preset": "ultrafast", "g": "25", "crf": "20"}
        for i in range(n):
            for pkt in st.encode(av.VideoFrame.from_ndarray(_synthetic_frame(i), format="bgr24")):
                out.mux(pkt)
        for pkt in st.encode():
            out.mux(pkt)
    return path


def _videos(tmp: Path) -> tuple[Path, Path, str]:
    side, front = SAMPLE / "side.mp4", SAMPLE / "front.mp4"
    if side.is_file() and front.is_file():
        return side, front, "sample_data"
    clip = _write_clip(tmp / "clip.mp4")
    return clip, clip, "generated 1080p clip"


def render_times(frame: np.ndarray, cols: int = 100, rows: int = 30, colors: str = "truecolor",
                 repeats: int = 30) -> tuple[list[float], list[float]]:
    """Wall-clock and CPU milliseconds per render (CPU time: what it costs on an idle machine)."""
    h, w = frame.shape[:2]
    tf = ViewTransform.make(w, h, cols, rows)
    builder = StripBuilder()
    marks = [MarkerMark(k, str(k), 300 + 180 * k, 500 + 15 * k, "tracked", k == 1) for k in range(8)]
    out, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        px = render_pixels(frame, tf)
        rgb = quantize(px, colors)
        labels = draw_overlays(rgb, tf, Overlays(marks=marks, cursor=(900.0, 500.0)))
        builder.build(rgb, labels)
        out.append((time.perf_counter() - t0) * 1000)
        cpu.append((time.process_time() - c0) * 1000)
    return out[3:], cpu[3:]


async def _step_latency(project_path: Path, size=(200, 50), steps: int = 25) -> list[float]:
    from sandtrack_tui.tui.app import SandtrackApp

    app = SandtrackApp(project_path)
    async with app.run_test(size=size) as pilot:
        for _ in range(200):
            await pilot.pause(0.02)
            if app.views_ready():
                break
        app.step_latencies_ms.clear()
        for _ in range(steps):
            await pilot.press("right")
            t0 = time.perf_counter()
            while not app.views_ready() and time.perf_counter() - t0 < 5:
                await pilot.pause(0.002)
            await pilot.pause(0.05)  # the user's pace: leaves the prefetcher a moment, as between key presses
        return list(app.step_latencies_ms)


def run() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        side, front, source = _videos(tmp)
        with FrameSource(side, cache_mb=64) as src:
            frame = src.frame(min(10, len(src) - 1))
        tc, tc_cpu = render_times(frame)
        c256, _ = render_times(frame, colors="256")
        big, _ = render_times(frame, 160, 45)
        proj = Project.create(tmp / "bench.sandtrack", {"side": side, "front": front})
        proj.close()
        steps = asyncio.run(_step_latency(tmp / "bench.sandtrack"))
    return {
        "source": source,
        "render_100x30_truecolor_ms_median": round(statistics.median(tc), 1),
        "render_100x30_truecolor_ms_p95": round(float(np.percentile(tc, 95)), 1),
        "render_100x30_truecolor_cpu_ms_median": round(statistics.median(tc_cpu), 1),
        "render_100x30_256_ms_median": round(statistics.median(c256), 1),
        "render_160x45_truecolor_ms_median": round(statistics.median(big), 1),
        "step_two_views_200x50_ms_median": round(statistics.median(steps), 1) if steps else None,
        "step_two_views_200x50_ms_p95": round(float(np.percentile(steps, 95)), 1) if steps else None,
        "render_target_ms": 30,
        "step_target_ms": 100,
    }


if __name__ == "__main__":
    for k, v in run().items():
        print(f"{k}: {v}")
