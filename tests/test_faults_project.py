"""Faults around a project: SIGKILL while tracking, a read-only project file, a full disk, and a
video cut short. Each runs the real `sandtrack` command in a child process on a short synthetic
stereo clip with exact ground truth (tracking.synthetic), then checks what is on disk.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import write_clip
from sandtrack_tui.cli import main
from sandtrack_tui.store import Project
from sandtrack_tui.tracking import synthetic

N_SRC = 30  # rendered frames; the clip plays them forward and back (cheap to render, smooth motion)
N = 120


def pingpong(n_src: int, n: int) -> np.ndarray:
    period = 2 * (n_src - 1)
    k = np.arange(n) % period
    return np.where(k < n_src, k, period - k)


@pytest.fixture(scope="module")
def media():
    """Side and front mp4s of five markers with their true pixel tracks, in a folder any user can
    read (the read-only test runs a child as an unprivileged user)."""
    root = Path(tempfile.mkdtemp(prefix="sandtrack-faults-"))
    root.chmod(0o755)
    cal, clips = synthetic.render_stereo(N_SRC)
    order = pingpong(N_SRC, N)
    truth = {}
    for cam, clip in clips.items():
        write_clip(root / f"{cam}.mp4", n_frames=N, width=480, height=360, bframes=0, gop=25, faststart=True,
                   frame_fn=lambda i, w, h, clip=clip: clip.frames[order[i]])
        t = clip.truth.set_index("frame")
        truth[cam] = pd.concat([t.loc[[k]].assign(frame=i) for i, k in enumerate(order)], ignore_index=True)
    yield root, cal, truth
    shutil.rmtree(root, ignore_errors=True)


def make_project(root: Path, cal, name: str) -> Path:
    path = root / name
    for suffix in ("", "-wal", "-shm"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)
    with Project.create(path, {"side": root / "side.mp4", "front": root / "front.mp4"}) as proj:
        proj.set_calibration(cal)
    path.chmod(0o666)
    return path


def sandtrack(*args, user: str | None = None, **kw) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "sandtrack_tui", *map(str, args)]
    if user == "nobody":
        cmd = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", *cmd]
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, **kw)


def tracked_rows(path: Path) -> int:
    """Rows the tracker committed so far, read without taking part in the writer's transactions."""
    conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5)
    try:
        return conn.execute("SELECT COUNT(*) FROM points WHERE status != 'manual'").fetchone()[0]
    except sqlite3.OperationalError:  # the child has not created the tables' first rows yet
        return 0
    finally:
        conn.close()


def one_line_error(proc: subprocess.CompletedProcess | subprocess.Popen, stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if "error:" in ln]
    assert proc.returncode == 1, stderr
    assert "Traceback" not in stderr and len(lines) == 1, stderr
    return lines[0]


def true_ids(points: pd.DataFrame, truth: dict) -> dict[int, int]:
    """Project marker id -> true marker id, by nearest true marker at frame 0 in the side view."""
    t0 = truth["side"].query("frame == 0")
    out = {}
    for r in points.query("frame == 0 and camera == 'side'").itertuples():
        out[int(r.marker)] = int(t0.marker.iloc[int(np.argmin(np.hypot(t0.x_px - r.x_px, t0.y_px - r.y_px)))])
    return out


def errors_px(points: pd.DataFrame, truth: dict) -> pd.DataFrame:
    ids = true_ids(points, truth)
    out = []
    for cam, t in truth.items():
        p = points[points.camera == cam].assign(marker=lambda d: d.marker.map(ids))
        p = p.merge(t[["frame", "marker", "x_px", "y_px"]], on=["frame", "marker"], suffixes=("", "_true"))
        out.append(p.assign(err=np.hypot(p.x_px - p.x_px_true, p.y_px - p.y_px_true)))
    return pd.concat(out, ignore_index=True)


def core(points: pd.DataFrame) -> pd.DataFrame:
    return points[["frame", "camera", "marker", "x_px", "y_px", "status"]].reset_index(drop=True)


def edit_log_agrees(proj: Project, edit_id: int) -> int:
    """Every point row logged by the edit holds the logged value, and vice versa; returns the count."""
    logged = proj.conn.execute("SELECT key, after FROM edit_rows WHERE edit_id=? AND table_name='points'",
                               (edit_id,)).fetchall()
    pts = proj.points()
    have = {(int(r.frame), r.camera, int(r.marker)): r for r in pts.itertuples()}
    for key, after in logged:
        f, c, m = json.loads(key)
        row = have[(f, c, m)]
        x, y, status = json.loads(after)[:3]
        assert (row.x_px, row.y_px, row.status) == (x, y, status)
    keys = {tuple(json.loads(k)) for k, _ in logged}
    tracked = {k for k, r in have.items() if r.status != "manual"}
    assert tracked == keys
    return len(keys)


# -- SIGKILL while tracking -------------------------------------------------------------------
def test_sigkill_while_tracking_loses_nothing_and_resumes(media):
    root, cal, truth = media
    path = make_project(root, cal, "killed.sandtrack")
    child = sandtrack("track", path, "--auto-seed")
    seen = 0
    deadline = time.time() + 120
    while seen == 0 and child.poll() is None and time.time() < deadline:
        time.sleep(0.01)
        seen = tracked_rows(path)
    os.kill(child.pid, signal.SIGKILL)
    child.communicate()
    assert child.returncode == -signal.SIGKILL, "tracking finished before it could be killed"
    assert seen > 0

    with Project.open(path) as proj:
        assert proj.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        seeds = proj.points().query("status == 'manual'")
        markers = seeds.marker.nunique()
        assert markers == 5 and len(seeds) == 10
        hist = proj.history()
        track_edit = hist.iloc[0]
        assert track_edit.description.startswith("track forward") and not track_edit.undone
        n_logged = edit_log_agrees(proj, int(track_edit.id))
        assert n_logged >= seen  # every row seen committed before the kill is still there
        pts = proj.points().query("status != 'manual'")
        assert n_logged < 2 * markers * (N - 1), "the run was not interrupted"
        # rows are written a whole step at a time: every marker and camera reached the same frame
        last = pts.groupby(["marker", "camera"]).frame.max()
        assert last.nunique() == 1 and len(last) == 2 * markers
        stopped_at = int(last.iloc[0])
        assert ((pts.groupby(["marker", "camera"]).frame.count()) == stopped_at).all()  # frames 1..stopped_at
        before = proj.points()
        # undo takes the interrupted run back to the seeds; redo restores it
        assert proj.undo() == track_edit.description
        pd.testing.assert_frame_equal(core(proj.points()), core(seeds))
        assert proj.redo() == track_edit.description
        pd.testing.assert_frame_equal(core(proj.points()), core(before))

    # resume from the last committed frame to the end
    rc = main(["track", str(path), "--from", str(stopped_at)])
    assert rc == 0
    with Project.open(path) as proj:
        pts = proj.points()
        assert len(proj.history()) == len(hist) + 1
        full = pts.groupby(["marker", "camera"]).frame.agg(["min", "max", "count"])
        assert (full["min"] == 0).all() and (full["max"] == N - 1).all() and (full["count"] == N).all()
        e = errors_px(pts, truth)
        assert len(e) == 2 * markers * N
        ok = e[e.status.isin(["tracked", "manual"])]
        assert len(ok) / len(e) > 0.97
        assert ok.err.mean() < 0.5 and ok.err.max() < 3.0, ok.err.describe()
