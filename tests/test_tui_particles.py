"""`A` in the terminal UI, every particle: on the synthetic bed of touching beads, seeded from one bead, the
choice tracks every bead in the view as one edit, and `u` takes it back."""

from __future__ import annotations

import time

import numpy as np

from dense_synth import HEIGHT, RADIUS
from sandtrack_tui.tui.app import SandtrackApp
from sandtrack_tui.tui.screens.prompts import AutoSeedChoice
from test_tracking_particles import _seeded_project, bed  # noqa: F401 - bed is the module's fixture
from test_tui_app import aio, settle


async def _every_particle(pilot, app) -> None:
    """A, then e: every particle like the seeded one."""
    await settle(pilot, app)
    await pilot.press("A")
    await settle(pilot, app, lambda: isinstance(app.screen, AutoSeedChoice))
    await pilot.press("e")


def test_every_particle_from_the_a_key(tmp_path, bed):  # noqa: F811
    _folder, truth, _fly = bed
    proj = _seeded_project(tmp_path, bed)
    inside = [int(((c[:, 0] > RADIUS) & (c[:, 1] < HEIGHT - RADIUS)).sum()) for c in truth]

    @aio
    async def run():
        app = SandtrackApp(proj)
        async with app.run_test(size=(100, 30)) as pilot:
            await _every_particle(pilot, app)
            await settle(pilot, app, lambda: app.bg_task is None and len(proj.points()) > 1, timeout=30)
            pts = proj.points(camera="side")
            tracked = pts[pts.status.isin(["tracked", "manual"]) & pts.x_px.notna()]
            assert tracked.marker.nunique() >= 0.99 * inside[0]  # every bead of the first frame
            per_frame = tracked.groupby("frame").size().reindex(range(len(truth)), fill_value=0).to_numpy()
            assert (per_frame >= 0.97 * np.array(inside)).all(), per_frame
            assert tracked.marker.nunique() == len(app.marker_list)  # the UI shows them
            await pilot.press("u")
            await pilot.pause()
            left = proj.points()
            assert len(left) == 1 and int(left.marker.iloc[0]) == 1  # only the seed
            assert len(app.marker_list) <= 1

    run()
    proj.close()


def test_every_particle_without_a_seed_says_so(tmp_path, bed):  # noqa: F811
    from sandtrack_tui.store import Project

    proj = Project.create(tmp_path / "empty.sandtrack", {"side": bed[0]})

    @aio
    async def run():
        app = SandtrackApp(proj)
        async with app.run_test(size=(100, 30)) as pilot:
            await settle(pilot, app)
            await pilot.press("A", "y")
            await settle(pilot, app, lambda: any("seed one particle first" in n.message for n in app._notifications),
                         timeout=30)
            assert proj.points().empty and app.bg_task is None

    run()
    proj.close()


def test_escape_stops_the_every_particle_run_keeping_one_edit(tmp_path, bed, monkeypatch):  # noqa: F811
    """Escape during the run (as for the seeded run): it stops after the frame in hand; the frames tracked so
    far stay as the run's one edit, which `u` takes back whole."""
    from sandtrack_tui.tracking import particles

    steps = []
    step = particles.ParticleTracker.step

    def slow_step(self, frame, image):
        steps.append(frame)
        time.sleep(0.3)
        return step(self, frame, image)

    monkeypatch.setattr(particles.ParticleTracker, "step", slow_step)
    proj = _seeded_project(tmp_path, bed)

    @aio
    async def run():
        app = SandtrackApp(proj)
        async with app.run_test(size=(100, 30)) as pilot:
            await _every_particle(pilot, app)
            await settle(pilot, app, lambda: len(steps) >= 2, timeout=30)
            await pilot.press("escape")
            await settle(pilot, app, lambda: app.bg_task is None, timeout=30)
            pts = proj.points(camera="side")
            assert 1 <= pts.frame.max() < len(bed[1]) - 1  # stopped before the end ...
            assert set(pts.frame) == set(range(pts.frame.max() + 1))  # ... every frame up to there written
            assert any("cancelled" in n.message for n in app._notifications)
            assert list(proj.history().kind).count("points") == 2  # the seed, then the run as one edit
            await pilot.press("u")
            await pilot.pause()
            left = proj.points()
            assert len(left) == 1 and int(left.marker.iloc[0]) == 1

    run()
    proj.close()
