"""A view of a dense scene (a flume's packed bed of 300 black beads, tests/dense_synth.py) stays a picture:
the marker boost, which would paint every bead, paints only the tracked markers, never more than a few % of
the view, and says so once; the ids of 300 markers never overlap and never cover a bead, at 1x and zoomed."""

from __future__ import annotations

import cv2
import numpy as np

from dense_synth import HEIGHT, RADIUS, WIDTH, bead_centres, dense_frame, write_frames
from sandtrack_tui.store import Project
from sandtrack_tui.tracking.run import marker_look
from sandtrack_tui.tui.app import SandtrackApp
from sandtrack_tui.tui.frame_view import BOOST_DENSE_SHARE, BOOST_RGB, ViewTransform, render
from test_tui_app import aio
from test_tui_app import settle as _settle
from test_tui_session import label_runs

TRACKED = 20  # markers tracked among the 300 beads in frame 1


async def settle(pilot, app, cond=None):
    await _settle(pilot, app, cond, timeout=60)


def _boosted(pixels: np.ndarray) -> np.ndarray:
    return np.all(pixels == BOOST_RGB, axis=2)


def _far_from(tf: ViewTransform, boosted: np.ndarray, centres: np.ndarray) -> int:
    """Boosted display pixels off every bead of `centres` (farther than its radius and a display pixel and a
    half from its centre)."""
    v, u = np.nonzero(boosted)
    x, y = tf.x0 + (u + 0.5) * tf.s, tf.y0 + (v + 0.5) * tf.s
    d = np.hypot(x[:, None] - centres[None, :, 0], y[:, None] - centres[None, :, 1]).min(axis=1)
    return int((d > RADIUS + 1.5 * tf.s).sum())


def test_boost_paints_only_the_tracked_beads_of_a_packed_bed():
    centres = bead_centres()
    bgr = cv2.cvtColor(dense_frame(centres), cv2.COLOR_GRAY2BGR)
    bead = int(np.argmin(np.hypot(*(centres - (640, 300)).T)))
    for look in (marker_look(bgr, *centres[bead]), marker_look(bgr, centres[bead][0] + 7, centres[bead][1])):
        assert look is not None
        for zoom in (1, 4):
            tf = ViewTransform.make(WIDTH, HEIGHT, 98, 27, zoom, (640, 280))
            everything = render(bgr, tf, True, look, centres)  # every bead tracked
            tracked = centres[::15]  # 20 of them
            some = render(bgr, tf, True, look, tracked)
            none = render(bgr, tf, True, look, None)
            # the bed looks like markers all over: without the limit the boost would paint a blue field
            assert everything.limited and everything.marker_share > 4 * BOOST_DENSE_SHARE, (zoom, look.kind)
            assert not _boosted(none.pixels).any()
            on = _boosted(some.pixels)
            assert on.any() and _far_from(tf, on, tracked) == 0, (zoom, look.kind)
            seen = sum(tf.contains(x + dx, y + dy) for x, y in tracked for dx, dy in
                       ((-RADIUS, 0), (RADIUS, 0), (0, -RADIUS), (0, RADIUS)))
            assert on.sum() <= seen / 4 * np.pi * (RADIUS / tf.s + 1.5) ** 2  # no more than those beads
            for r in (everything, some):  # never more than a few % of the view
                assert _boosted(r.pixels).mean() <= BOOST_DENSE_SHARE


def test_dense_view_in_the_app_ids_of_300_markers_and_the_boost_notice(tmp_path):
    centres = bead_centres()
    seed = int(np.argmin(np.hypot(*(centres - (640, 300)).T)))  # the bead clicked (the boost's look)
    write_frames(tmp_path / "side")
    with Project.create(tmp_path / "bed.sandtrack", {"side": tmp_path / "side"}) as proj:
        rows = [(0, "side", k + 1, float(x), float(y), "manual" if k == seed else "tracked")
                for k, (x, y) in enumerate(centres)]
        rows += [(1, "side", k + 1, float(x), float(y), "tracked") for k, (x, y) in enumerate(centres[:TRACKED])]
        proj.set_points(rows, "beads")

    @aio
    async def run():
        app = SandtrackApp(tmp_path / "bed.sandtrack")
        async with app.run_test(size=(100, 30)) as pilot:
            await settle(pilot, app, lambda: app.look is not None)
            v = app.view("side")
            app.cursor["side"] = (640.0, 280.0)
            for zoom in (1, 2, 4):
                await settle(pilot, app, lambda z=zoom: app.zoom["side"] == z)
                shown = [app._labels[k + 1] for k, (x, y) in enumerate(centres) if v.tf.contains(x, y)]
                runs = label_runs(v._labels)
                assert len(runs) == len(set(runs)) and set(runs) <= set(shown), f"{zoom}x: ids overlap"
                # where there is room every id is placed; 300 ids in a 98 x 15-cell view at 1x: 234 placed
                assert len(runs) == len(shown) if zoom > 1 else len(runs) >= 234 / 1.5, (zoom, len(runs))
                cells = {v.tf.source_to_cell(x, y)[::-1] for x, y in centres}
                assert not cells & set(v._labels), f"{zoom}x: an id covers a bead"
                await pilot.press("plus")
            await pilot.press("0", "right")  # fit, frame 1: 20 of the 300 beads tracked
            await settle(pilot, app, lambda: app.frame == 1)
            on = _boosted(v.pixels)
            assert on.any() and _far_from(v.tf, on, centres[:TRACKED]) == 0
            notes = [n.message for n in app._notifications]
            assert sum("marker boost" in n and "only the tracked markers" in n for n in notes) == 1, notes

    run()
