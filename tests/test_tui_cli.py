"""`sandtrack [tui] [PROJECT]`: the sample project, relinking, bad input (no UI is started)."""

from __future__ import annotations

import pytest

from conftest import SAMPLE_DATA, write_clip
from sandtrack_tui.cli import main
from sandtrack_tui.cli.cmd_tui import relink, sample_project
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.store import Project


@pytest.fixture
def sample_dir(tmp_path):
    exp = tmp_path / "sample_data" / "experiment"
    exp.mkdir(parents=True)
    write_clip(exp / "side.mp4", n_frames=6, bframes=0)
    write_clip(exp / "front.mp4", n_frames=6, bframes=0)
    return tmp_path / "sample_data"


def test_sample_project_is_made_once_and_remade_when_videos_change(sample_dir, tmp_path):
    target = tmp_path / "data" / "sample.sandtrack"
    p = sample_project(sample_dir, target)
    assert p == target and p.is_file()
    with Project.open(p) as proj:
        assert proj.cameras() == ["side", "front"]
        proj.add_marker("1", 1)  # an edit that must survive reopening
    assert sample_project(sample_dir, target) == target
    with Project.open(target) as proj:
        assert list(proj.markers()["id"]) == [1]
    write_clip(sample_dir / "experiment" / "side.mp4", n_frames=8, bframes=0)  # the sample was re-rendered
    sample_project(sample_dir, target)
    with Project.open(target) as proj:
        assert proj.markers().empty and proj.videos()["side"].frames == 8
    assert target.with_suffix(".sandtrack.old").is_file()
    # never moved away while another sandtrack has it open
    with Project.open(target):
        write_clip(sample_dir / "experiment" / "front.mp4", n_frames=9, bframes=0)
        with pytest.raises(SandtrackError, match="open in another"):
            sample_project(sample_dir, target)


def test_missing_sample_is_one_clear_error(tmp_path):
    with pytest.raises(SandtrackError, match="make sample"):
        sample_project(tmp_path / "nothing", tmp_path / "x.sandtrack")


def test_bad_project_path_exits_1(tmp_path, capsys):
    assert main(["tui", str(tmp_path / "missing.sandtrack")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "project file not found" in err[0]
    (tmp_path / "junk.sandtrack").write_text("not sqlite")
    assert main([str(tmp_path / "junk.sandtrack")]) == 1  # bare `sandtrack PROJECT` is the TUI
    assert "not a sandtrack project" in capsys.readouterr().err


def test_relink_moved_video(sample_dir, tmp_path):
    target = sample_project(sample_dir, tmp_path / "s.sandtrack")
    moved = tmp_path / "moved.mp4"
    (sample_dir / "experiment" / "front.mp4").rename(moved)
    with Project.open(target) as proj:
        assert [p.camera for p in proj.video_problems()] == ["front"]
    relink(target, [f"front={moved}"])
    with Project.open(target) as proj:
        assert proj.video_problems() == []
    with pytest.raises(SandtrackError, match="CAMERA=PATH"):
        relink(target, ["front"])


@pytest.mark.skipif(not (SAMPLE_DATA / "model.pt").is_file(), reason="sample_data/model.pt is not in this checkout")
def test_sample_project_gets_the_bundled_network_once(sample_dir, tmp_path):
    import shutil

    target = tmp_path / "data" / "sample.sandtrack"
    p = sample_project(sample_dir, target)
    with Project.open(p) as proj:  # these clips have no audio and no network: left for F2 and F4
        assert not proj.sync_confirmed() and proj.get("model") is None
    shutil.copy(SAMPLE_DATA / "model.pt", sample_dir / "model.pt")  # a version that bundles the network
    with Project.open(p) as proj:
        proj.conn.execute("DELETE FROM meta WHERE key='sample_setup'")  # as made by an older version
    sample_project(sample_dir, target)
    with Project.open(target) as proj:
        assert proj.get("model")["path"] == str((sample_dir / "model.pt").resolve())
        assert proj.undo() == "sample network"  # the user takes it back
    sample_project(sample_dir, target)
    with Project.open(target) as proj:
        assert proj.get("model") is None  # and it stays back
