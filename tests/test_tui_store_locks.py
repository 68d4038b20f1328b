"""The TUI keeps a project open while workers open and close their own connections: another
process must never be able to delete the WAL under it (edits written afterwards would be lost)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from sandtrack_tui.store import Project


def test_worker_connections_keep_the_ui_connection_locked(tmp_path):
    path = tmp_path / "p.sandtrack"
    Project.create(path).close()
    ui = Project.open(path)
    ui.add_marker("1", 1)
    worker = Project.open(path)  # as a tracking or table worker does
    worker.close()
    reader = f"from sandtrack_tui.store import Project; Project.open({str(path)!r}).close()"
    subprocess.run([sys.executable, "-c", reader], check=True, cwd=Path(__file__).parents[1])
    assert Path(str(path) + "-wal").exists()
    ui.set_points([(0, "side", 1, 1.0, 2.0, "manual")], "after the other process")
    ui.close()
    with Project.open(path) as again:
        assert len(again.points()) == 1
