"""SIGKILL during `sandtrack train`: the model file is the previous complete one (or absent), the
project is intact, and a rerun succeeds. Synthetic calibration points with exact XYZ."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from conftest import POLL_LIMIT_S
from sandtrack_tui.cli import main
from sandtrack_tui.regression.dataset import load_points
from sandtrack_tui.regression.model import load_model
from sandtrack_tui.regression.synthetic import calibration_points, study_rig
from sandtrack_tui.store import Project


@pytest.fixture
def setup(tmp_path):
    # One core for this process and its children: training then skips its thread-count probe, which
    # takes seconds on a busy machine and is not what these tests are about.
    cpus = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cpus)})
    try:
        yield _setup(tmp_path)
    finally:
        os.sched_setaffinity(0, cpus)


def _setup(tmp_path):
    points = tmp_path / "points.csv"
    calibration_points(n_points=700, seed=3).to_csv(points, index=False)
    proj = tmp_path / "exp.sandtrack"
    with Project.create(proj) as p:
        p.set_calibration(study_rig())
    return tmp_path, points, proj


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def train_quick(points, model, proj) -> None:
    assert main(["train", str(points), "-o", str(model), "--project", str(proj), "--fast", "--epochs", "1",
                 "--no-residual"]) == 0


def project_model(proj):
    with Project.open(proj) as p:
        assert p.conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        return p.get("model"), len(p.history())


def kill_after_first_epoch(args: list[str]) -> None:
    child = subprocess.Popen([sys.executable, "-m", "sandtrack_tui", *args], stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    deadline = time.time() + POLL_LIMIT_S
    line = ""
    while time.time() < deadline:
        line = child.stderr.readline()
        if not line or line.startswith("train ["):  # an epoch is done (or the child ended)
            break
    os.kill(child.pid, signal.SIGKILL)
    child.communicate()
    assert line.startswith("train [") and child.returncode == -signal.SIGKILL, line


def test_sigkill_mid_training_keeps_previous_model_and_project(setup, capsys):
    tmp, points, proj = setup
    model = tmp / "model.pt"
    train_quick(points, model, proj)
    before, before_model = digest(model), project_model(proj)
    assert before_model[0]["path"] == str(model.resolve())

    long_run = ["train", str(points), "-o", str(model), "--project", str(proj), "--epochs", "500", "--no-residual"]
    kill_after_first_epoch(long_run)
    assert digest(model) == before  # the previous complete model, untouched
    load_model(model)
    assert project_model(proj) == before_model

    train_quick(points, model, proj)  # a rerun succeeds
    assert load_model(model).metrics["points"] == len(load_points(points))
    after_model = project_model(proj)
    assert after_model[1] == before_model[1] + 1 and after_model[0]["path"] == str(model.resolve())


def test_sigkill_while_the_model_file_is_written(setup):
    """Killed half-way through writing the file itself: the old model survives whole."""
    tmp, points, proj = setup
    model = tmp / "model.pt"
    train_quick(points, model, proj)
    before = digest(model)
    # The child writes half of the new file's bytes, then is killed (SIGKILL cannot be caught).
    script = textwrap.dedent(f"""
        import io, os, signal, torch
        real_save = torch.save
        def dying_save(obj, f):
            buf = io.BytesIO()
            real_save(obj, buf)
            with open(f, "wb") as fh:
                fh.write(buf.getvalue()[: len(buf.getvalue()) // 2])
                fh.flush()
            os.kill(os.getpid(), signal.SIGKILL)
        torch.save = dying_save
        from sandtrack_tui.cli import main
        main(["train", {str(points)!r}, "-o", {str(model)!r}, "--project", {str(proj)!r}, "--fast",
              "--epochs", "1", "--no-residual"])
    """)
    child = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert child.returncode == -signal.SIGKILL, child.stderr
    assert digest(model) == before
    load_model(model)
    train_quick(points, model, proj)
    assert not (tmp / "model.pt.tmp").exists()  # the rerun replaced the half-written temporary file
    load_model(model)
