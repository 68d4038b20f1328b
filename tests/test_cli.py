import json
import subprocess
import sys

import pytest

from conftest import write_clip
from sandtrack_tui.cli import COMMANDS, main
from sandtrack_tui.cli.common import not_available


def run_cli(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "sandtrack_tui", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("command", COMMANDS)
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    assert command in capsys.readouterr().out


def test_not_available_exits_2_with_one_line(capsys, monkeypatch):
    import argparse

    from sandtrack_tui import cli

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command")
    sub.add_parser("future").set_defaults(func=not_available("the future"))
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    monkeypatch.setattr(cli, "COMMANDS", ["future"])
    assert main(["future"]) == 2
    err = capsys.readouterr().err
    assert "not available yet" in err and err.count("\n") == 1


def test_new_creates_project_and_reports_json(tmp_path):
    side = write_clip(tmp_path / "side.mp4", n_frames=8)
    front = write_clip(tmp_path / "front.mp4", n_frames=8, fps=25, width=160, height=120)
    out = run_cli("new", tmp_path / "exp.sandtrack", "--side", side, "--front", front, "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["videos"]["side"]["frames"] == 8
    assert len(result["warnings"]) == 2 and "differ" in out.stderr
    again = run_cli("new", tmp_path / "exp.sandtrack", "--side", side)
    assert again.returncode == 1 and "already exists" in again.stderr


@pytest.mark.parametrize("case", ["missing", "text"])
def test_new_with_bad_video_is_one_line_error(tmp_path, case):
    bad = tmp_path / "bad.mp4"
    if case == "text":
        bad.write_text("not a video")
    out = run_cli("new", tmp_path / "e.sandtrack", "--side", bad)
    assert out.returncode == 1
    assert out.stderr.strip().count("\n") == 0 and "Traceback" not in out.stderr
    assert not (tmp_path / "e.sandtrack").exists()


def test_corrupt_board_file_is_one_line_error(tmp_path):
    side = write_clip(tmp_path / "side.mp4", n_frames=3)
    board = tmp_path / "board.toml"
    board.write_text("columns = 'eight'\nrows = 5\n")
    out = run_cli("new", tmp_path / "e.sandtrack", "--side", side, "--board", board)
    assert out.returncode == 1 and "Traceback" not in out.stderr


def test_relink_moved_video(tmp_path):
    side = write_clip(tmp_path / "side.mp4", n_frames=4)
    assert run_cli("new", tmp_path / "p.sandtrack", "--side", side).returncode == 0
    moved = side.rename(tmp_path / "elsewhere.mp4")
    check = run_cli("relink", tmp_path / "p.sandtrack")
    assert check.returncode == 1 and "not found" in check.stdout and "relink" in check.stdout
    fixed = run_cli("relink", tmp_path / "p.sandtrack", "--side", moved, "--json")
    assert fixed.returncode == 0, fixed.stderr
    assert json.loads(fixed.stdout)["problems"] == []
    assert run_cli("relink", tmp_path / "p.sandtrack").returncode == 0
