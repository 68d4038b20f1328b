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
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conftest import POLL_LIMIT_S, write_clip
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


def make_project(root: Path, cal, name: str, side: str = "side.mp4") -> Path:
    """A project on the media in `root` (name may hold a sub-folder)."""
    path = root / name
    for suffix in ("", "-wal", "-shm"):
        Path(f"{path}{suffix}").unlink(missing_ok=True)
    with Project.create(path, {"side": root / side, "front": root / "front.mp4"}) as proj:
        proj.set_calibration(cal)
        proj.set("sync_offset_s", 0.0)  # the rendered cameras are frame-locked
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
    """The points logged by the edit are exactly the tracked points; returns the count."""
    logged = set()
    for table, key in proj.conn.execute("SELECT table_name, key FROM edit_rows WHERE edit_id=?", (edit_id,)):
        if table == "points_batch":
            logged.update(tuple(k) for k in json.loads(key))
        elif table == "points":
            logged.add(tuple(json.loads(key)))
    tracked = {(int(r.frame), r.camera, int(r.marker)) for r in proj.points().itertuples() if r.status != "manual"}
    assert tracked == logged
    return len(logged)


# -- SIGKILL while tracking -------------------------------------------------------------------
def test_sigkill_while_tracking_loses_nothing_and_resumes(media):
    root, cal, truth = media
    path = make_project(root, cal, "killed.sandtrack")
    child = sandtrack("track", path, "--auto-seed")
    seen = 0
    deadline = time.time() + POLL_LIMIT_S
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
        assert len(ok) / len(e) > 0.995  # measured 1200 of 1200
        assert ok.err.mean() < 0.13 and ok.err.max() < 3.0, ok.err.describe()  # measured 0.085 px mean


# -- read-only project, full disk -------------------------------------------------------------
def unprivileged(media_root: Path) -> str | None:
    """Root ignores file permissions: run the child as `nobody` then (None: we are not root).

    Skips when this machine cannot run the child that way: no setpriv, or a checkout, interpreter or media
    folder that `nobody` cannot read (a clone inside a private folder): that is the machine, not the product."""
    if os.geteuid() != 0:
        return None
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: cannot make a file read-only for the child")
    probe = sandtrack("--version", user="nobody", cwd=media_root)
    out, err = probe.communicate(timeout=120)
    if probe.returncode != 0:
        reason = (err.strip().splitlines() or ["no output"])[-1]
        pytest.skip(f"the unprivileged user 'nobody' cannot run this checkout's sandtrack ({reason}); "
                    "clone into a folder other users can read to run this test as root")
    return "nobody"


def project_state(path: Path) -> tuple:
    with Project.open(path) as proj:
        return len(proj.markers()), len(proj.points()), len(proj.history()), proj.get("tracking_boxes")


@pytest.mark.parametrize("folder_writable", [True, False], ids=["file-read-only", "folder-read-only-too"])
def test_read_only_project_is_one_clear_line_and_unchanged(media, folder_writable):
    root, cal, _ = media
    folder = root / f"ro-{folder_writable}"
    folder.mkdir(exist_ok=True)
    path = make_project(root, cal, f"{folder.name}/p.sandtrack")
    before = project_state(path)
    path.chmod(0o444)
    folder.chmod(0o777 if folder_writable else 0o555)
    try:
        child = sandtrack("track", path, "--auto-seed", user=unprivileged(root), cwd=root)
        _, err = child.communicate(timeout=180)
        line = one_line_error(child, err)
        assert "read-only" in line, line
    finally:
        folder.chmod(0o755)
        path.chmod(0o644)
    assert project_state(path) == before


def _can_mount_tmpfs() -> bool:
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c",
                            "mount -t tmpfs -o size=64k tmpfs /mnt && umount /mnt"], capture_output=True)
    return probe.returncode == 0


FREE_KB = 600  # room for the seeds and a few chunks of tracking (450-750 all fill up mid-run)


def test_full_disk_while_tracking_keeps_committed_rows(media, tmp_path):
    """The project lives on a tiny tmpfs (in a private mount namespace) that fills up mid-run."""
    if not _can_mount_tmpfs():
        pytest.skip("needs root to mount a small tmpfs (the store's own test covers the core path)")
    root, cal, _ = media
    path = make_project(root, cal, "full.sandtrack")
    mnt, out = tmp_path / "mnt", tmp_path / "out"
    mnt.mkdir()
    out.mkdir()
    size_kb = path.stat().st_size // 1024 + FREE_KB
    script = textwrap.dedent(f"""
        set -e
        mount -t tmpfs -o size={size_kb}k tmpfs {mnt}
        cp {path} {mnt}/p.sandtrack
        set +e
        {sys.executable} -m sandtrack_tui track {mnt}/p.sandtrack --auto-seed 2> {out}/stderr
        echo $? > {out}/rc
        cp {mnt}/p.sandtrack* {out}/
    """)
    subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c", script], check=True, timeout=300)
    err = (out / "stderr").read_text()
    assert int((out / "rc").read_text()) == 1, err
    line = [ln for ln in err.splitlines() if "error:" in ln]
    assert len(line) == 1 and "disk is full" in line[0] and "Traceback" not in err, err
    with Project.open(out / "p.sandtrack") as proj:
        assert proj.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        hist = proj.history()
        assert hist.description.iloc[0].startswith("track forward")
        kept = edit_log_agrees(proj, int(hist.id.iloc[0]))
        assert 0 < kept < 2 * 5 * (N - 1)  # some chunks were saved before the disk filled, not all
        assert proj.undo() == hist.description.iloc[0]
        assert set(proj.points().status) == {"manual"}


# -- a video cut short ------------------------------------------------------------------------
def test_truncated_video_tracks_up_to_where_it_ends(media, capsys):
    root, cal, truth = media
    data = (root / "side.mp4").read_bytes()
    (root / "side_cut.mp4").write_bytes(data[: len(data) // 2])  # a copy interrupted half-way
    path = make_project(root, cal, "cut.sandtrack", side="side_cut.mp4")
    with Project.open(path) as proj:
        decodable = proj.videos()["side"].frames
    assert 20 < decodable < N
    rc = main(["track", str(path), "--auto-seed", "--json"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "Traceback" not in captured.err
    notes = [ln for ln in captured.err.splitlines() if "cut short" in ln]
    assert len(notes) == 1 and f"0..{decodable - 1}" in notes[0], captured.err
    summary = json.loads(captured.out)
    assert summary["last_frame"] == decodable - 1
    with Project.open(path) as proj:
        pts = proj.points()
    per = pts.groupby(["marker", "camera"]).frame.agg(["min", "max", "count"])
    assert (per["min"] == 0).all() and (per["max"] == decodable - 1).all() and (per["count"] == decodable).all()
    e = errors_px(pts, truth)
    ok = e[e.status.isin(["tracked", "manual"])]
    assert len(ok) == len(e) and ok.err.mean() < 0.14, ok.err.describe()  # measured 0.090 px
