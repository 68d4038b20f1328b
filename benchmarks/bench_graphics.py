"""Key -> screen latency and bytes per step over a real pseudo-terminal, for each way of drawing
frames: half-blocks, sixel, kitty graphics.

`sandtrack tui` runs on a pty of 200 x 50 cells (10 x 20 px each) whose other end is a small
terminal (tests/fake_terminal.py): it answers the capability queries as a terminal offering
neither protocol, sixel, or kitty graphics would, so the app chooses its mode itself
(`--graphics auto`); it keeps every chunk the app writes with its arrival time, and rebuilds the
screen from them (text, sixel, kitty images). The project is the sample with its calibration,
synced, and 8 markers auto-seeded and tracked (boxes, ids, the selected marker's epipolar curve and
search window on screen). From frame 150, each of STEPS right-arrow presses waits until the output
has been quiet for 0.3 s (a user's pace).

Per step: `frame_ms` = key written -> the last byte of the frames' pictures arrived (half-blocks:
the last chunk holding a half-block; graphics: the end of the last picture write), `settled_ms` =
key -> the last byte of everything the key caused (status line, timeline, table), and the bytes
written. At the end, the side view decoded from the stream is compared with the frame the app
shows, rendered independently here (overlay pixels aside). The machine may be busy: the lead can
re-run `python benchmarks/run_all.py graphics` on a quiet machine.

Peer: textual-image 0.12 (the newest for Python 3.11) on the same 980 x 551 view: its sixel
encoder 583 KB in 151-285 ms CPU; its kitty path sends one RGB PNG per picture (858 KB at
compression 1, 1.14 MB in base64), ours a palette PNG per changed tile (see benchmarks/README.md).
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "tests"))

from fake_terminal import SIXEL_END, FakeTerminal, PtyTerminal  # noqa: E402

COLS, ROWS, CELL = 200, 50, (10, 20)
STEPS = int(os.environ.get("SANDTRACK_BENCH_STEPS", "30"))
START_FRAME = 250
HALF = "▀".encode()
MODES = {"blocks": {}, "sixel": {"sixel": True}, "kitty": {"kitty": True}}


def make_project(tmp: Path) -> Path:
    from sandtrack_tui.cli import main
    from sandtrack_tui.cli.cmd_tui import sample_project

    path = sample_project(target=tmp / "bench.sandtrack")
    for argv in (["sync", str(path)], ["track", str(path), "--auto-seed", "--to", str(START_FRAME + STEPS + 20)]):
        if main(argv) != 0:
            raise RuntimeError(f"sandtrack {' '.join(argv)} failed")
    return path


def run_mode(project: Path, mode: str) -> dict:
    env = dict(os.environ, TERM="xterm-256color", COLORTERM="truecolor", PYTHONPATH=str(ROOT / "src"))
    term = PtyTerminal([sys.executable, "-m", "sandtrack_tui", "tui", str(project), "--graphics", "auto"],
                       COLS, ROWS, CELL, env=env, **MODES[mode])
    try:
        t_start = time.perf_counter()
        term.wait_quiet(1.5, timeout=60)
        time.sleep(max(0.0, 8.0 - (time.perf_counter() - t_start)))  # the start-up notification is gone
        for key in (b"1",) + (b"\x1b[6~",) * (START_FRAME // 50):  # marker 1 selected, page down to START_FRAME
            term.write(key)
            term.wait_quiet(0.5)
        frame_ms, settled_ms, step_bytes, picture_bytes, cpu_ms, ui_cpu_ms = [], [], [], [], [], []
        for _ in range(STEPS):
            cpu0, ui0 = term.cpu_ms()
            t0 = term.write(b"\x1b[C")
            term.wait_quiet(0.3)
            cpu1, ui1 = term.cpu_ms()
            cpu_ms.append(cpu1 - cpu0)
            ui_cpu_ms.append(ui1 - ui0)
            chunks = term.since(t0)
            if not chunks:
                continue
            settled_ms.append((chunks[-1][0] - t0) * 1000)
            step_bytes.append(sum(len(c) for _, c in chunks))
            picture = [(t, c) for t, c in chunks if (HALF in c if mode == "blocks" else SIXEL_END.encode() in c)]
            if picture:
                frame_ms.append((picture[-1][0] - t0) * 1000)
            picture_bytes.append(_picture_bytes(b"".join(c for _, c in chunks), mode))
        out = term.output()
    finally:
        code = term.close()
    return {
        "detected": _detected(out),
        "frame_ms_median": _r(statistics.median(frame_ms)) if frame_ms else None,
        "frame_ms_p90": _r(float(np.percentile(frame_ms, 90))) if frame_ms else None,
        "settled_ms_median": _r(statistics.median(settled_ms)) if settled_ms else None,
        "cpu_ms_per_step_median": _r(statistics.median(cpu_ms)),
        "ui_thread_cpu_ms_per_step_median": _r(statistics.median(ui_cpu_ms)),
        "bytes_per_step_median": int(statistics.median(step_bytes)) if step_bytes else None,
        "bytes_per_step_max": max(step_bytes) if step_bytes else None,
        "picture_bytes_per_step_median": int(statistics.median(picture_bytes)) if picture_bytes else None,
        "steps_measured": len(frame_ms),
        "exit_code": code,
        **_check_screen(out, mode, project),
    }


def _r(v: float) -> float:
    return round(v, 1)


def _picture_bytes(data: bytes, mode: str) -> int:
    """Bytes of the pictures themselves: graphics writes (between ESC 7 and our end marker), or for
    half-blocks the whole step (Textual sends views, status and timeline in one update)."""
    if mode == "blocks":
        return len(data)
    total, start = 0, 0
    end_marker = SIXEL_END.encode()
    while True:
        a = data.find(b"\x1b7", start)
        if a < 0:
            return total
        b = data.find(end_marker, a)
        if b < 0:
            return total
        total += b - a
        start = b


def _detected(out: bytes) -> str:
    if b"\x1b_Ga=T" in out:
        return "kitty"
    if b"\x1bP0;1;0q" in out:
        return "sixel"
    return "blocks"


def _check_screen(out: bytes, mode: str, project: Path) -> dict:
    """The side view as the terminal shows it at the end, against the frame rendered here."""
    if mode == "blocks":
        return {}
    from sandtrack_tui.store import Project
    from sandtrack_tui.tui.frame_view import ViewTransform
    from sandtrack_tui.tui.graphics import render_view
    from sandtrack_tui.video import FrameSource

    term = FakeTerminal(COLS, ROWS, CELL)
    end = out.rfind(b"\x1b[?1049l")  # leaving the alternate screen: judge the screen just before
    term.feed(out[: end if end > 0 else len(out)])
    ys, xs = np.nonzero(term.graphics_mask()[:, : COLS // 2 * CELL[0]])  # the side view: left half
    if not len(ys):
        return {"side_view": "nothing drawn"}
    col, row = int(xs.min()) // CELL[0], int(ys.min()) // CELL[1]
    cols, rows = (int(xs.max()) + 1) // CELL[0] - col, (int(ys.max()) + 1) // CELL[1] - row
    shown = term.region(col, row, cols, rows).astype(np.int16)
    with Project.open(project) as proj:
        video = proj.videos()["side"].path
    with FrameSource(video) as src:
        frame = src.frame(START_FRAME + STEPS)
    tf = ViewTransform.make(frame.shape[1], frame.shape[0], cols, rows)
    expected = render_view(frame, tf, CELL).astype(np.int16)
    err = np.abs(shown - expected[: shown.shape[0]]).max(axis=2)
    text = int((~term.graphics_mask()[row * CELL[1]:(row + rows) * CELL[1], col * CELL[0]:(col + cols) * CELL[0]]
                ).sum() // (CELL[0] * CELL[1]))
    return {"side_view_cells": f"{cols} x {rows}", "side_view_error_median": float(np.median(err)),
            "side_view_pixels_over_24_pct": round(100 * float((err > 24).mean()), 2),
            "side_view_cells_without_picture": text}


def encoder_figures(video: Path, frames: range, cols: int = 98, rows: int = 27) -> dict:
    """Bytes and CPU per view and step of the tile encoder alone (no terminal, no overlays), for
    each protocol: the first picture, then each following frame."""
    from sandtrack_tui.tui.frame_view import Overlays, ViewTransform
    from sandtrack_tui.tui.graphics import compose, render_view
    from sandtrack_tui.tui.tiles import GraphicsView
    from sandtrack_tui.video import FrameSource

    with FrameSource(video, cache_mb=64) as src:
        pictures = [src.frame(i) for i in frames if i < len(src)]
    tf = ViewTransform.make(pictures[0].shape[1], pictures[0].shape[0], cols, rows)
    rgbs = [compose(render_view(p, tf, CELL), tf, CELL, Overlays()) for p in pictures]
    out = {}
    for mode in ("kitty", "sixel"):
        sizes, cpu = [], []
        gv = GraphicsView(mode, CELL, 256, 0, lambda d: None)
        for rgb in rgbs:
            c0 = time.process_time()
            data = gv.canvas.update(rgb, (1, 2, cols, rows))
            cpu.append((time.process_time() - c0) * 1000)
            sizes.append(len(data))
        tiles = -(-cols // 8) * -(-rows // 2)
        out[mode] = {"first_kb": round(sizes[0] / 1000, 1),
                     "step_kb_median": round(statistics.median(sizes[1:]) / 1000, 1),
                     "step_kb_max": round(max(sizes[1:]) / 1000, 1),
                     "tiles_per_step": round((gv.canvas.tiles_sent - tiles) / (len(rgbs) - 1), 1), "tiles": tiles,
                     "cpu_ms_first": round(cpu[0], 1), "cpu_ms_per_step_median": round(statistics.median(cpu[1:]), 1)}
    return out


def run() -> dict:
    from sandtrack_tui.tui import sixel

    sixel.warm_up()
    encoder = {"sample_side_frames_250_290": encoder_figures(ROOT / "sample_data" / "experiment" / "side.mp4",
                                                             range(250, 291))}
    real = ROOT.parent / "shared" / "data" / "caliscope_4cam"
    if (real / "cam_0.mp4").is_file():  # real webcams, ~6 fps: sensor noise and a board moving by hand
        encoder["real_webcam_cam_0_frames_0_47"] = encoder_figures(real / "cam_0.mp4", range(48))
        encoder["real_webcam_cam_2_frames_0_47"] = encoder_figures(real / "cam_2.mp4", range(48))
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        project = make_project(Path(tmp))
        setup = time.perf_counter() - t0
        results = {mode: run_mode(project, mode) for mode in MODES}
    results["encoder_98x27_cells"] = encoder
    results["setup_s"] = round(setup, 1)
    results["pty"] = f"{COLS} x {ROWS} cells of {CELL[0]} x {CELL[1]} px, {STEPS} steps from frame {START_FRAME}"
    results["frame_target_ms"] = 100
    return results


if __name__ == "__main__":
    for k, v in run().items():
        print(f"{k}: {v}")
