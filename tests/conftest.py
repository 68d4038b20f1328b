"""Shared test helpers: small generated videos with known content."""

from __future__ import annotations

import json
import os
from fractions import Fraction
from functools import cache
from pathlib import Path

# One BLAS / OpenMP / torch thread per process, set before numpy or torch loads (here, and in every xdist
# worker, which inherits it): `make test`'s two workers fill the two cores, and more threads only spin
# against each other (the suite took 267 s with the libraries' own threads, 206 s with one each).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import av  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

# `make test` draws the same examples on every run (a seed derived from each test's source, no example database):
# it cannot fail by chance. `make fuzz` (SANDTRACK_FUZZ=deep) draws new random examples, FUZZ_FACTOR times as many.
DEEP = os.environ.get("SANDTRACK_FUZZ", "") == "deep"
FUZZ_FACTOR = int(os.environ.get("SANDTRACK_FUZZ_FACTOR", "30")) if DEEP else 1
settings.register_profile("deterministic", derandomize=True, deadline=None, database=None, print_blob=True)
settings.register_profile("deep", derandomize=False, deadline=None, database=None, print_blob=True)
settings.load_profile("deep" if DEEP else "deterministic")


# The safety net of every wait in the tests that polls until something holds (a worker done, a screen shown):
# only a broken build ever waits this long, so it is generous enough for a machine under any load.
POLL_LIMIT_S = 300.0


def examples(n: int) -> int:
    """A property test's number of examples: n in `make test`, FUZZ_FACTOR x n in the deep run."""
    return n * FUZZ_FACTOR

SAMPLE_DATA = Path(__file__).resolve().parents[1] / "sample_data"
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results.json"


@cache
def _claims() -> dict:
    return {row["id"]: row["figures"] for row in json.loads(RESULTS.read_text(encoding="utf-8"))["rows"]}


def claimed(row: str, figure: str) -> float:
    """A figure README's performance table states (benchmarks/results.json: the row's id, the figure's name),
    in the table's units. A test that runs the same measurement holds it to about 1.5 x that."""
    fig = _claims()[row][figure]
    return float(fig["value"]) * fig.get("scale", 1)


def within(measured: float, claim: float, factor: float = 1.5) -> bool:
    """An error (or a share missed) no worse than `factor` x what is claimed for it."""
    return measured <= factor * claim


def pct_within(measured_pct: float, claim_pct: float, factor: float = 1.5) -> bool:
    """A percentage claimed near 100 (hidden frames flagged, ...): what it misses no more than `factor` x
    the claimed miss."""
    return 100.0 - measured_pct <= factor * (100.0 - claim_pct) + 1e-9


def ellipsoid_coverage(err: np.ndarray, sd_cov: np.ndarray) -> float:
    """Share of 3-D errors (N, 3) inside their 95 % ellipsoid, from (N, 6) sd X, Y, Z and covariances XY,
    XZ, YZ (`triangulation_sd(..., covariance=True)`): eᵀ C⁻¹ e <= χ²₃(0.95)."""
    sx, sy, sz, cxy, cxz, cyz = np.asarray(sd_cov, float).T
    C = np.stack([np.stack([sx * sx, cxy, cxz], -1), np.stack([cxy, sy * sy, cyz], -1),
                  np.stack([cxz, cyz, sz * sz], -1)], -2)
    e = np.asarray(err, float)
    return float(np.mean(np.einsum("ni,ni->n", e, np.linalg.solve(C, e[..., None])[..., 0]) <= 7.814727903251178))


def numbered_frame(i: int, width: int = 320, height: int = 240) -> np.ndarray:
    """A BGR frame whose index can be read back after lossy compression (see frame_number)."""
    img = np.full((height, width, 3), 40, np.uint8)
    bits = [(i >> b) & 1 for b in range(12)]
    cell = width // 12
    for b, on in enumerate(bits):
        img[: height // 2, b * cell:(b + 1) * cell] = 230 if on else 20
    # moving texture in the lower half so the encoder uses motion prediction and B-frames
    yy, xx = np.mgrid[0:height // 2, 0:width]
    img[height // 2:, :, 1] = (128 + 100 * np.sin((xx + 3 * i) / 7.0) * np.cos(yy / 5.0)).astype(np.uint8)
    return img


def frame_number(img: np.ndarray) -> int:
    height, width = img.shape[:2]
    cell = width // 12
    top = img[: height // 2].mean(axis=2)
    return sum(int(top[height // 4, b * cell + cell // 2] > 128) << b for b in range(12))


def write_clip(path: Path, n_frames: int = 60, fps: int = 50, width: int = 320, height: int = 240,
               bframes: int = 2, gop: int = 12, frame_fn=numbered_frame, faststart: bool = False) -> Path:
    """Write an H.264 mp4 (with B-frames) of numbered frames."""
    with av.open(str(path), "w", options={"movflags": "faststart"} if faststart else {}) as out:
        stream = out.add_stream("libx264", rate=Fraction(fps))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"bf": str(bframes), "g": str(gop), "crf": "18", "preset": "ultrafast"
                          if bframes == 0 else "fast", "threads": "1"}
        for i in range(n_frames):
            frame = av.VideoFrame.from_ndarray(frame_fn(i, width, height), format="bgr24")
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path


@pytest.fixture
def clip(tmp_path) -> Path:
    return write_clip(tmp_path / "clip.mp4")
