import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time

import numpy as np
import pandas as pd
import pytest

from conftest import POLL_LIMIT_S, write_clip
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.store import SCHEMA_VERSION, Project


@pytest.fixture
def project(tmp_path):
    side = write_clip(tmp_path / "side.mp4", n_frames=10)
    front = write_clip(tmp_path / "front.mp4", n_frames=10)
    proj = Project.create(tmp_path / "exp.sandtrack", {"side": side, "front": front})
    yield proj
    proj.close()


def _rows(marker, camera, frames, x0=100.0, status="tracked"):
    return pd.DataFrame({
        "frame": frames, "camera": camera, "marker": marker,
        "x_px": [x0 + f for f in frames], "y_px": [50.0 + f for f in frames],
        "status": status, "score": 0.9, "psr": 12.0, "colour_frac": 0.8,
    })


def test_round_trip(project, tmp_path):
    project.set("sync_offset_s", 0.4373)
    project.set("board", {"type": "charuco", "columns": 8, "rows": 5, "square_mm": 25.0})
    m = project.add_marker("marker 1")
    project.set_points(_rows(m, "side", range(5)))
    project.set_points(_rows(m, "front", range(3), status="manual"))
    project.close()

    again = Project.open(tmp_path / "exp.sandtrack")
    assert again.sync_offset_s == pytest.approx(0.4373)
    assert again.board().columns == 8
    assert again.markers().to_dict("records") == [{"id": 1, "label": "marker 1"}]
    assert again.cameras() == ["side", "front"]
    pts = again.points(marker=1, camera="side")
    assert list(pts.frame) == [0, 1, 2, 3, 4]
    assert np.allclose(pts.x_px, [100, 101, 102, 103, 104])
    assert set(again.points(camera="front").status) == {"manual"}
    assert again.videos()["side"].frames == 10
    again.close()


def test_undo_redo(project):
    m = project.add_marker()
    project.set_points(_rows(m, "side", range(4)), "track")
    project.set_points(_rows(m, "side", [2], x0=500.0, status="manual"), "nudge")
    assert project.points(frame=2).x_px.item() == 502.0
    assert project.undo() == "nudge"
    assert project.points(frame=2).x_px.item() == 102.0
    assert project.undo() == "track"
    assert project.points().empty
    assert project.redo() == "track"
    assert len(project.points()) == 4
    assert project.redo() == "nudge"
    assert project.points(frame=2).status.item() == "manual"
    assert project.redo() is None
    # a new edit after an undo drops the redo stack
    project.undo()
    project.delete_points(m, "side", frames=(0, 1))
    assert not project.can_redo()
    assert list(project.points().frame) == [2, 3]
    project.undo()
    assert list(project.points().frame) == [0, 1, 2, 3]


def test_edit_written_in_chunks_is_one_undo_step(project):
    m = project.add_marker()
    project.set_points(_rows(m, "side", [0], status="manual"), "seed")
    with project.edit("track forward") as ed:
        ed.write(_rows(m, "side", [1, 2]))
        ed.write(_rows(m, "side", [3, 4]))
        ed.write(_rows(m, "side", [2], x0=0.0))  # the same row written twice in one edit
    assert len(project.points()) == 5
    project.undo()
    assert list(project.points().frame) == [0]
    project.redo()
    assert project.points(frame=2).x_px.item() == 2.0


def test_edit_without_a_disk_sync_per_write_commits_each_write(project):
    m = project.add_marker()
    other = sqlite3.connect(str(project.path))  # another process's view of the file
    try:
        with project.edit("track forward", sync_each_write=False) as ed:
            assert project.conn.execute("PRAGMA synchronous").fetchone()[0] == 1  # NORMAL
            ed.write(_rows(m, "side", [0, 1]))
            assert other.execute("SELECT COUNT(*) FROM points").fetchone()[0] == 2  # committed at once
        assert project.conn.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL again
        with pytest.raises(RuntimeError), project.edit("fails", sync_each_write=False) as ed:
            ed.write(_rows(m, "side", [2]))
            raise RuntimeError("stopped")
        assert project.conn.execute("PRAGMA synchronous").fetchone()[0] == 2
        assert other.execute("SELECT COUNT(*) FROM points").fetchone()[0] == 3
    finally:
        other.close()
    assert project.undo() == "fails" and project.undo() == "track forward"
    assert project.points().empty


def test_settings_and_markers_are_undoable(project):
    project.set("sync_offset_s", 0.1)
    project.set("sync_offset_s", 0.2)
    project.undo()
    assert project.sync_offset_s == pytest.approx(0.1)
    m = project.add_marker("a")
    project.set_points(_rows(m, "side", range(3)))
    project.delete_marker(m)
    assert project.markers().empty and project.points().empty
    project.undo()
    assert project.markers().label.tolist() == ["a"] and len(project.points()) == 3


def test_bad_status_is_rejected(project):
    with pytest.raises(SandtrackError):
        project.set_points(_rows(1, "side", [0], status="great"))


def test_sigkill_while_writing_keeps_every_committed_edit(project, tmp_path):
    path = project.path
    project.close()
    script = textwrap.dedent(f"""
        import sys
        import pandas as pd
        from sandtrack_tui.store import Project
        p = Project.open({str(path)!r})
        m = p.add_marker()
        for i in range(100000):
            p.set_points(pd.DataFrame({{"frame": [i], "camera": ["side"], "marker": [m], "x_px": [float(i)],
                                       "y_px": [0.0], "status": ["tracked"]}}), f"edit {{i}}")
            print(i, flush=True)
    """)
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    last = -1
    deadline = time.time() + POLL_LIMIT_S
    while last < 30 and time.time() < deadline:
        last = int(child.stdout.readline())
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    reopened = Project.open(path)
    frames = reopened.points().frame.tolist()
    # every edit reported as done before the kill is there, contiguous, nothing half-written
    assert frames == list(range(len(frames))) and len(frames) >= last + 1
    assert reopened.undo() == f"edit {len(frames) - 1}"
    reopened.close()


def test_moved_video_is_reported_and_relinkable(tmp_path):
    side = write_clip(tmp_path / "side.mp4", n_frames=5)
    proj = Project.create(tmp_path / "p.sandtrack", {"side": side})
    moved = tmp_path / "moved.mp4"
    side.rename(moved)
    problems = proj.video_problems()
    assert [p.problem for p in problems] == ["missing"]
    with pytest.raises(SandtrackError, match="not found"):
        proj.open_sources()
    proj.link_video("side", moved)
    assert proj.video_problems() == []
    write_clip(moved, n_frames=7)  # content changed under the project
    assert [p.problem for p in proj.video_problems()] == ["changed"]


def test_bad_project_files(tmp_path):
    with pytest.raises(SandtrackError, match="not found"):
        Project.open(tmp_path / "none.sandtrack")
    garbage = tmp_path / "garbage.sandtrack"
    garbage.write_bytes(b"\x00\x01 definitely not sqlite" * 100)
    with pytest.raises(SandtrackError, match="not a sandtrack project"):
        Project.open(garbage)
    damaged = tmp_path / "damaged.sandtrack"
    Project.create(damaged).close()
    data = bytearray(damaged.read_bytes())
    data[100:4096] = b"\xff" * (4096 - 100)
    damaged.write_bytes(bytes(data))
    with pytest.raises(SandtrackError):
        Project.open(damaged)
    other = tmp_path / "other.sqlite"
    sqlite3.connect(other).execute("CREATE TABLE t (x)").connection.commit()
    with pytest.raises(SandtrackError, match="not a sandtrack project"):
        Project.open(other)


def test_newer_schema_is_refused(tmp_path):
    path = tmp_path / "future.sandtrack"
    Project.create(path).close()
    conn = sqlite3.connect(path)
    conn.execute("UPDATE meta SET value=? WHERE key='schema_version'", (str(SCHEMA_VERSION + 1),))
    conn.commit()
    conn.close()
    with pytest.raises(SandtrackError, match="newer sandtrack"):
        Project.open(path)


def test_read_only_project_gives_clear_message(project):
    project.add_marker()
    if os.geteuid() == 0:
        # root ignores file permissions: open the database read-only instead
        project.conn.close()
        project.conn = sqlite3.connect(f"file:{project.path}?mode=ro", uri=True, isolation_level=None)
        ro = project
    else:
        # a connection opened before the file became read-only keeps writing: reopen it read-only
        project.close()
        os.chmod(project.path, 0o444)
        ro = Project.open(project.path)
    try:
        with pytest.raises(SandtrackError, match="read-only"):
            ro.add_marker()
        assert len(ro.markers()) == 1
    finally:
        ro.close()


def test_full_disk_gives_clear_message_and_keeps_committed_edits(project):
    m = project.add_marker()
    project.set_points(_rows(m, "side", range(5)), "before the disk filled")
    pages = project.conn.execute("PRAGMA page_count").fetchone()[0]
    project.conn.execute(f"PRAGMA max_page_count = {pages + 2}")  # the disk is (nearly) full
    with pytest.raises(SandtrackError, match="disk is full"):
        project.set_points(_rows(m, "front", range(20000)), "too big")
    project.conn.execute("PRAGMA max_page_count = 1000000")
    assert len(project.points()) == 5 and project.points(camera="front").empty
    assert project.undo() == "before the disk filled"


def test_version_1_project_is_migrated(tmp_path):
    from sandtrack_tui import store

    path = tmp_path / "old.sandtrack"
    conn = sqlite3.connect(path)
    conn.executescript(store.MIGRATIONS[0])
    conn.execute("INSERT INTO meta VALUES ('schema_version', '1')")
    conn.execute("INSERT INTO markers VALUES (3, 'old marker')")
    conn.commit()
    conn.close()
    with Project.open(path) as proj:
        assert proj.markers().label.tolist() == ["old marker"]
        version = proj.conn.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0]
        assert int(version) == SCHEMA_VERSION
        indexes = {r[0] for r in proj.conn.execute("SELECT name FROM sqlite_master WHERE type='index'")}
        assert "edit_rows_by_key" in indexes


def test_undo_and_redo_of_random_edit_sequences_restore_every_state(tmp_path):
    """Random edits (writes in several chunks, the same point written twice, deletions), undone and
    redone at random: the points are always those of the state the log says they should be in."""
    rng = np.random.default_rng(11)
    with Project.create(tmp_path / "log.sandtrack") as proj:
        m = proj.add_marker()
        states, redo, current = [], [], {}

        def points_now():
            return {(int(r.frame), r.camera): (r.x_px, r.status) for r in proj.points().itertuples()}

        for step in range(120):
            op = rng.choice(["edit", "edit", "undo", "redo"])
            if op == "edit":
                states.append(dict(current))
                redo.clear()
                with proj.edit(f"edit {step}") as ed:
                    for _ in range(rng.integers(1, 4)):
                        if rng.random() < 0.25 and current:
                            keys = list(current)
                            picked = [keys[i] for i in rng.choice(len(keys), min(3, len(keys)), replace=False)]
                            ed.delete([(f, c, m) for f, c in picked])
                            for k in picked:
                                current.pop(k, None)
                            continue
                        frames = rng.integers(0, 12, rng.integers(1, 6))  # repeats within a write too
                        cam = str(rng.choice(["side", "front"]))
                        status = str(rng.choice(["tracked", "occluded", "manual"]))
                        x = float(rng.integers(0, 1000))
                        ed.write(_rows(m, cam, list(frames), x0=x, status=status))
                        for f in frames:
                            current[(int(f), cam)] = (x + f, status)
                if ed.edit_id is None:  # nothing was written: no edit
                    states.pop()
            elif op == "undo" and states:
                assert proj.undo() is not None
                redo.append(current)
                current = states.pop()
            elif op == "redo" and redo:
                assert proj.redo() is not None
                states.append(current)
                current = redo.pop()
            assert points_now() == current, f"step {step} ({op})"
