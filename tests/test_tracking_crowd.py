"""Touching identical beads (a dense layer): who is who from motion and assignment, where each is from its
outline or its highlight. Small synthetic crowds with exact truth."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from crowd_synth import CLICKED, crowd_project, layer_mm, turned
from sandtrack_tui.tracking import crowd, synthetic
from sandtrack_tui.tracking.engine import Engine
from sandtrack_tui.tracking.matcher import Match, Proposal
from sandtrack_tui.tracking.stereo import StereoCheck
from sandtrack_tui.tracking.tracker import MarkerTrack, Observation

BLACK = (22.0, 22.0, 25.0)
R = 7.0
SHINE = (-0.25, -0.3)  # a bead's highlight from its centre, in radii (the light and the view stay put)
SIZE = (220, 260)


def _packing(gap: float, at=(60.0, 60.0), cols: int = 4, rows: int = 4) -> np.ndarray:
    """Centres of beads in hexagonal rows, `gap` radii apart (2: touching)."""
    return np.array([(at[0] + gap * R * (c + 0.5 * (j % 2)), at[1] + 0.866 * gap * R * j)
                     for j in range(rows) for c in range(cols)])


def _beads(centres: np.ndarray, seed: int = 4, dull=(), shine=SHINE) -> np.ndarray:
    """Black beads on sand, each with a highlight at `shine` radii from its centre (but those of `dull`)."""
    paths = [synthetic.MarkerPath(i + 1, np.array([c]), radius=R) for i, c in enumerate(centres)]
    img = synthetic.render(paths, 1, SIZE, seed=seed, marker_bgr=BLACK).frames[0].astype(np.float32)
    yy, xx = np.mgrid[0:SIZE[0], 0:SIZE[1]].astype(np.float32)
    for i, (cx, cy) in enumerate(centres):
        if i not in dull:
            disc = np.clip(R + 0.5 - np.hypot(xx - cx, yy - cy), 0, 1)
            spot = np.exp(-((xx - cx - shine[0] * R) ** 2 + (yy - cy - shine[1] * R) ** 2) / 2.0)
            img += (60.0 * disc * spot)[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def _layer_model():
    """The model of a bead learned among touching ones (a crowd model, shared by the layer's beads)."""
    packed = _packing(2.02)
    t = MarkerTrack(1, "cam", _beads(packed), 0, packed[0, 0] + 0.3, packed[0, 1] - 0.2, 22, 22)
    assert t.model.crowd
    return t.model


def _tracked_bead(n_frames: int, steps: int | None = None, **render) -> tuple:
    """Bead 5 of a loose packing moving (0.6, 0.3) px a frame over `n_frames` frames, its crowd track stepped
    by an Engine through the first `steps` of them (all by default); (packing, frames, track, engine)."""
    model, k = _layer_model(), 5
    loose = _packing(2.4)
    frames = [_beads(loose + (0.6 * f, 0.3 * f), **render) for f in range(n_frames)]
    t = MarkerTrack(2, "cam", frames[0], 0, loose[k, 0] + 0.3, loose[k, 1] - 0.2, 22, 22, kind=model.kind,
                    like=model)
    eng = Engine()
    eng.add(t, 0)
    for f, img in enumerate(frames[:steps]):
        eng.step({"cam": (f, img, 0.0)})
    return loose, frames, t, eng


def test_a_crowd_bead_is_centred_by_its_highlight_where_its_outline_does_not_measure_it():
    k = 5
    loose, frames, t, eng = _tracked_bead(5)
    assert np.hypot(*(np.array(t.highlight.offset) - np.array(SHINE) * R)) < 0.14  # learned from its outline (0.09)
    x, y = loose[k] + (2.4, 1.2)
    img = frames[-1]

    def centred(dx: float, dy: float, outline: bool, frame=img) -> Match:
        m = Match(x + dx, y + dy, 0.9, 3.0, 1.2, outline=outline, used_centroid=outline)
        t._centre_by_highlight(frame, m)
        return m

    # Its outline not found (the gaps closed round it): its template's peak 1 px off, its highlight places it.
    m = centred(0.8, -0.6, outline=False)
    assert m.outline and m.lit and math.hypot(m.x - x, m.y - y) < 0.063  # measured 0.042 px
    # An outline pulled 1.5 px off (a neighbour's rim, a shadow) disagrees with the highlight: the highlight's.
    m = centred(1.2, 0.9, outline=True)
    assert m.lit and math.hypot(m.x - x, m.y - y) < 0.063
    # One within CARRIED_AGREE_PX of it is the outline's measurement, kept as it is.
    m = centred(0.4, -0.3, outline=True)
    assert not m.lit and (m.x, m.y) == (x + 0.4, y - 0.3)
    # No highlight of its own there: held, not measured.
    m = centred(0.8, -0.6, outline=False, frame=_beads(loose + (2.4, 1.2), dull=(k,)))
    assert not m.outline and not m.lit


def test_a_bead_given_back_by_assignment_is_measured_by_its_outline_and_its_template_cut_again():
    model, k = _layer_model(), 5
    packed = _packing(2.02)
    t = MarkerTrack(2, "cam", _beads(packed), 0, packed[k, 0] + 0.3, packed[k, 1] - 0.2, 22, 22, kind=model.kind,
                    like=model)
    # The layer spread while the bead was hidden: its neighbours moved off, its template (cut among them)
    # no longer fits it, though its whole outline shows.
    spread = packed + (packed - packed[k]) * 0.35 + (3.0, 2.0)
    img = _beads(spread)
    x, y = spread[k]
    assert t.verify_at(img, x + 0.5, y - 0.4) is None
    m = t.verify_assigned(img, x + 0.5, y - 0.4)
    assert m is not None and m.assigned and math.hypot(m.x - x, m.y - y) < 0.3
    t.misses = 12
    t.apply(1, img, m, reattach=True)
    found = t.matcher.match(img, x + 1.0, y + 1.0, 4.0, 4.0)
    assert found.score > 0.95 and math.hypot(found.x - x, found.y - y) < 0.031  # its template cut again there
    # Two beads merged into one blob, or no outline there: not measured.
    assert t.verify_assigned(img, *(0.5 * (spread[k] + spread[k + 1]))) is None


def _carry(points: np.ndarray, turn_deg: float = -8.0, stretch: float = 1.3, shift=(17.0, 22.0)) -> np.ndarray:
    """The layer's carrying of a patch: stretched, turned and moved about its middle (an affine map)."""
    th = math.radians(turn_deg)
    lin = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]]) @ np.diag([1.0, stretch])
    centre = np.array([150.0, 120.0])
    return (np.asarray(points, float) - centre) @ lin.T + centre + shift


def test_a_lost_bead_is_carried_by_the_map_of_its_measured_neighbours_moves():
    layer = _packing(2.0, at=(100.0, 80.0), cols=5, rows=5)
    lost, around = 12, [6, 7, 11, 13, 17, 18]  # a bead in the middle, its six neighbours measured
    now = _carry(layer) + np.random.default_rng(1).normal(0.0, 0.2, layer.shape)
    xy, misfit = crowd.moved_with(layer[lost], layer[around], now[around])
    assert np.hypot(*(xy - _carry(layer[lost:lost + 1])[0])) < 0.11 and misfit < 0.36  # measured 0.072, 0.20-0.24
    # Neighbours on one line do not fix the map across it; two are too few.
    row = [10, 11, 13, 14]
    assert crowd.moved_with(layer[lost], layer[row], now[row]) is None
    assert crowd.moved_with(layer[lost], layer[[6, 7]], now[[6, 7]]) is None
    # ... but they carry a bead on their own line, along it (a column of beads its next bead): not one a
    # row off it.
    xy, misfit = crowd.moved_with(layer[lost], layer[row], now[row], on_line_px=0.5 * R)
    assert np.hypot(*(xy - _carry(layer[lost:lost + 1])[0])) < 0.11 and misfit < 0.36  # measured 0.072, 0.20-0.24
    assert crowd.moved_with(layer[7], layer[row], now[row], on_line_px=0.5 * R) is None


def _map_of(old: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The map (3, 2) taking `old` to `at` (a similarity where `old` lies on a line)."""
    return crowd._fit_map(np.c_[old, np.ones(len(old))], at)


def _hidden_row() -> tuple:
    """A packed layer (8 x 6) and where it was carried; six beads of its third row hidden together
    (`group`), four of them shown again (`shown`), the beads around them (`anchors`: the rows above and
    the ends of their own), and the next row down (`lookalikes`); `beads`: the shown and the lookalikes."""
    cols = 8
    layer = _packing(2.0, at=(100.0, 80.0), cols=cols, rows=6)

    def row(j: int) -> list:
        return list(range(j * cols, (j + 1) * cols))

    group, anchors, lookalikes = row(2)[1:7], row(1) + [row(2)[0], row(2)[7]], row(3)
    shown = group[:2] + group[3:5]
    return layer, _carry(layer), group, anchors, lookalikes, shown, shown + lookalikes


def test_a_registration_shifted_onto_lookalikes_no_track_follows_is_refused_by_the_beads_around_it():
    # Six beads of a row were hidden together and four show again; the beads around them are tracked
    # (anchors), but those of the next row down are followed by no track: lookalikes, unexplained as the
    # lost ones are.
    layer, now, group, anchors, lookalikes, shown, beads = _hidden_row()
    ends = (layer[anchors], now[anchors])
    # On the beads alone the group fits the row of lookalikes better (it pairs more of it), shifted by a row,
    # and as well a bead along it: two perfect fits, so nothing is registered. Every bead measured around the
    # patch lies a row off where such a map puts it.
    assert crowd.register(layer[group], now[beads], R, 6 * R) == (None, {})
    for start in (1, 2):
        row_off = _map_of(layer[group], now[lookalikes[start:start + len(group)]])
        assert crowd.anchor_misfit(row_off, *ends) > 2 * R
    # Fitted with the anchors, the map is the patch's: each shown bead its own, none a lookalike.
    at, agreed = crowd.register(layer[group], now[beads], R, 6 * R, anchors=ends)
    assert at is not None and np.hypot(*(at - now[group]).T).max() < 0.5 * R
    assert {group[i]: beads[b] for i, b in agreed.items()} == {k: k for k in shown}
    # With only the lookalikes in sight, the anchors leave no map that fits: nothing is paired.
    assert crowd.register(layer[group], now[lookalikes], R, 6 * R, anchors=ends) == (None, {})


def _pairing_run(side_points: dict, front_points: dict, frames: int) -> list:
    """CrowdPairing.pair (the engine's) fed with crowd tracks' points ({marker: (frames, 2) px} per view, NaN: not
    measured); returns the engine's pairs after each frame."""
    cal = synthetic.stereo_rig()
    eng = Engine(stereo=StereoCheck(cal, "side", "front"))
    bead = SimpleNamespace(model=SimpleNamespace(crowd=True))
    for cam, pts in (("side", side_points), ("front", front_points)):
        for m in pts:
            eng.tracks[(m, cam)] = bead
    out = []
    for f in range(frames):
        obs = [Observation(f, cam, m, *p[f], "tracked") for cam, pts in (("side", side_points), ("front", front_points))
               for m, p in pts.items() if np.isfinite(p[f]).all()]
        eng.pairing.pair({"side": (f, None, 0.0), "front": (f, None, 0.0)}, obs)
        out.append(dict(eng.partners))
    return out


def test_crowd_tracks_of_the_two_views_are_paired_once_every_other_bead_left_the_line():
    cal = synthetic.stereo_rig()
    n = 30
    a = np.array([10.0, 5.0, 420.0])
    ray = a - np.array([170.0, 0.0, 30.0])  # the front camera's ray through bead a: b lies on it, deeper
    b = np.tile(a + 0.08 * ray, (n, 1))
    b[15:, 1] += np.linspace(0.0, 6.0, n - 15)  # ... until the layer carries it off (from frame 16 on)
    c = np.tile([-30.0, 20.0, 400.0], (n, 1))
    side = {m: cal.cameras["side"].project(x) for m, x in ((1, np.tile(a, (n, 1))), (2, b), (3, c))}
    front = {4: cal.cameras["front"].project(np.tile(a, (n, 1)))}
    pairs = _pairing_run(side, front, n)
    # While beads a and b both lie on the line of the front track's point, whose it is is not known.
    assert all(p == {} for p in pairs[:16])
    broke = [f for f in range(n) if StereoCheck(cal, "side", "front").distance("side", side[2][f:f + 1], "front",
                                                                               front[4][f:f + 1])[0] > 2.0]
    # Paired once b left the line at PAIR_BREAKS frames, both ways, and kept.
    assert pairs[broke[2]] == {(4, "front"): (1, "side"), (1, "side"): (4, "front")}
    assert pairs[broke[1]] == {} and pairs[-1] == pairs[broke[2]]
    # The front track's own bead measured off its line once: a bead beside the line that never left it is
    # not taken for it (the one that left it did so fewer than PAIR_BREAKS times).
    side_once = {1: side[1].copy(), 2: side[2].copy()}
    side_once[1][5] += (0.0, 6.0)
    side_once[2][15:] = side_once[2][14]  # (b stays on the line)
    assert all(p == {} for p in _pairing_run(side_once, front, n))


class _Lost(SimpleNamespace):
    __hash__ = object.__hash__  # (a track is a key of the beads given back)


def test_a_lost_crowd_bead_is_given_back_on_the_other_views_line_only_when_no_other_bead_lies_there():
    from sandtrack_tui.tracking.matcher import Proposal

    cal = synthetic.stereo_rig()
    r = 6.0
    a = np.array([10.0, 5.0, 420.0])
    s = cal.cameras["side"].project(a[None])[0]
    f0 = cal.cameras["front"].project(a[None])[0]
    along = cal.cameras["front"].project((a + 0.05 * a)[None])[0] - f0  # the side ray through a, seen from the front
    along /= np.hypot(*along)
    across = np.array([-along[1], along[0]])

    def given_back(beads: list) -> tuple:
        eng = Engine(stereo=StereoCheck(cal, "side", "front"))
        lost = _Lost(marker=4, camera="front", misses=12, kf=SimpleNamespace(xy=tuple(f0)),
                     model=SimpleNamespace(crowd=True, radius=r))
        eng.tracks.update({(4, "front"): lost,
                           (1, "side"): SimpleNamespace(camera="side", model=SimpleNamespace(radius=r))})
        eng.partners.update({(4, "front"): (1, "side"), (1, "side"): (4, "front")})
        eng.crowd._crowd_seen = {(4, "front"): {0: tuple(f0)}, (1, "side"): {0: tuple(s)}}  # last measured together
        props = {(1, "side"): Proposal(Match(*s, 0.95, 5.0, 1.0))}  # the side view measures it, not moved
        taken = {}
        eng.crowd._unexplained_beads = lambda *args, **kw: np.array(beads, float).reshape(-1, 2)
        eng.crowd._give_back = lambda cam, img, found, props: taken.update(found) or len(found)
        eng.crowd._crowd_on_line("front", None, 5, [lost], props, {}, {"side": (5, None, 0.0), "front": (5, None, 0.0)})
        return {t.marker: tuple(xy) for t, xy in taken.items()}, eng.ambiguous

    own = f0 + 0.6 * along + 0.4 * across
    # The one bead on the side view's line near where it was: given back. One beside the line is not a rival.
    assert given_back([own, f0 + 9.0 * across]) == ({4: tuple(own)}, [])
    # Another bead on the line within a bead's width more: which one it is is not known (flagged).
    taken, ambiguous = given_back([own, f0 - 1.6 * r * along])
    assert taken == {} and ambiguous and ambiguous[0]["marker"] == 4
    # Beside the line only, or farther than it can have gone: nothing.
    assert given_back([f0 + 9.0 * across, f0 + 4.0 * r * along]) == ({}, [])


def test_a_crowd_bead_centred_on_its_outline_updates_its_template_whatever_the_template_scored():
    model, k = _layer_model(), 5
    packed = _packing(2.02)
    t = MarkerTrack(2, "cam", _beads(packed), 0, packed[k, 0] + 0.3, packed[k, 1] - 0.2, 22, 22, kind=model.kind,
                    like=model)
    # The layer around it loosened: its outline shows all round, its template (cut among touching
    # neighbours) scores it lower than a confident match, and would go on doing so.
    spread = packed + (packed - packed[k]) * 0.1
    img = _beads(spread)
    x, y = spread[k]
    first = t.matcher.match(img, x, y, 2.0, 2.0)
    assert first.outline and first.score < t.params.confident_score
    for f in range(1, 13):
        t.predict()
        t.apply(f, img, t.matcher.match(img, x, y, 2.0, 2.0))
    last = t.matcher.match(img, x, y, 2.0, 2.0)
    assert last.score > max(t.params.confident_score, first.score + 0.1) and math.hypot(last.x - x, last.y - y) < 0.3


# -- a two-view crowd through the project: beads seeded in one view each, paired by their tracks -------------
def test_beads_seeded_in_one_view_each_become_one_marker_each_with_true_3d_and_undo_parts_them(tmp_path):
    from sandtrack_tui.tracking.run import BOXES_KEY, KINDS_KEY, track_project
    from sandtrack_tui.xyz import compute_xyz

    centres = turned(layer_mm(), 24, rest=4, deg_per_frame=1.2)
    proj, clips, ids = crowd_project(tmp_path, centres)
    seeded, seeded_boxes = proj.points(), proj.get(BOXES_KEY)
    summary = track_project(proj)
    paired = summary["paired_across_views"]
    # Every bead seeded in one view each: its front marker merged into its side marker, none other.
    assert sorted((p["marker"], p["from"]) for p in paired) == sorted(
        (ids[("side", b)], ids[("front", b)]) for b in range(1, 13) if b != CLICKED)
    assert all(p["camera"] == "front" and p["frames_on_line"] >= 10 for p in paired)
    assert summary["one_camera_markers"] == [] and not summary["problems"]
    assert sorted(proj.markers()["id"]) == list(range(1, 13))
    points = proj.points()
    assert set(points.marker) == set(range(1, 13)) and (points.groupby("marker").camera.nunique() == 2).all()
    assert set(summary["per_marker"]) == {str(m) for m in range(1, 13)}
    boxes, kinds = proj.get(BOXES_KEY), proj.get(KINDS_KEY)
    assert all(f"{m}/front" in boxes and kinds[f"{m}/front"] == "dark" for m in range(1, 13))
    # Each marker's points in both views are its own bead's, and so is its XYZ.
    bead_of = {m: b for (cam, b), m in ids.items() if cam == "side"}
    for cam, clip in clips.items():
        got = points[(points.camera == cam) & (points.status == "tracked")].assign(bead=lambda d: d.marker.map(bead_of))
        m = got.merge(clip.truth, left_on=["frame", "bead"], right_on=["frame", "marker"])
        assert len(m) == len(got) > 0.9 * 11 * 23 and np.hypot(m.x_px_x - m.x_px_y, m.y_px_x - m.y_px_y).max() < 1.0
    xyz = compute_xyz(proj, method="triangulation")
    xyz = xyz[xyz.X_mm.notna()]
    true = centres[xyz.frame.to_numpy(), xyz.marker.map(bead_of).to_numpy() - 1]
    err = np.linalg.norm(xyz[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - true, axis=1)
    # (at 400 mm and 25 degrees between the views a pixel along the epipolar line is ~1.3 mm of depth)
    assert xyz.marker.nunique() == 12 and err.mean() < 0.28 and err.max() < 1.5  # measured 0.18 / 1.1 mm
    # Undo takes back the whole run, the pairing with it: the separate markers of one view each, as seeded.
    assert proj.undo().startswith("track forward")
    assert proj.points().equals(seeded) and sorted(proj.markers()["id"]) == sorted(set(ids.values()))
    assert proj.get(BOXES_KEY) == seeded_boxes
    assert proj.redo().startswith("track forward") and proj.points().equals(points)


def test_lookalikes_that_never_leave_each_others_lines_stay_apart(tmp_path):
    from sandtrack_tui.tracking.run import track_project

    proj, _clips, ids = crowd_project(tmp_path, turned(layer_mm(), 16, rest=16, deg_per_frame=0.0))
    before = sorted(proj.markers()["id"])
    summary = track_project(proj)
    # At rest each bead's line in the other view crosses its whole row: whose is whose is never told.
    assert summary["paired_across_views"] == []
    assert summary["one_camera_markers"] == sorted(set(ids.values()) - {1})
    assert sorted(proj.markers()["id"]) == before
    assert (proj.points().groupby("marker").camera.nunique()[lambda s: s.index != 1] == 1).all()


def test_cli_track_reports_the_beads_made_one_marker_and_tracks_them_as_one_from_a_later_frame(tmp_path, capsys):
    import json

    from sandtrack_tui.cli import main
    from sandtrack_tui.store import Project

    proj, _clips, ids = crowd_project(tmp_path, turned(layer_mm(), 24, rest=4, deg_per_frame=1.2))
    proj.close()
    path = str(tmp_path / "crowd.sandtrack")
    assert main(["track", path, "--to", "15"]) == 0
    line = [x for x in capsys.readouterr().out.splitlines() if "made one marker with both views" in x]
    assert len(line) == 1 and line[0].strip().startswith("11 bead(s) seen in one view each")
    with Project.open(path) as p:
        assert p.undo().startswith("track forward")
    assert main(["track", path, "--to", "15", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    bead_of = {m: b for (cam, b), m in ids.items() if cam == "side"}
    paired = out["paired_across_views"]
    assert len(paired) == 11 and all(set(p) == {"marker", "from", "camera", "frames_on_line", "frame"} for p in paired)
    assert all(p["from"] == ids[("front", bead_of[p["marker"]])] and p["frames_on_line"] >= 10 for p in paired)
    assert out["one_camera_markers"] == []
    # Re-tracked from a later frame (as after a correction): each is one marker seen in both views, started from
    # its points there and checked against the epipolar line from the first step, with nothing left to pair.
    assert main(["track", path, "--from", "15", "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["paired_across_views"] == [] and not again["problems"] and not again["stereo_flags"]
    assert all(again["per_marker"][str(p["marker"])][cam]["tracked"] == 8 for p in paired for cam in ("side", "front"))


def test_a_pair_whose_markers_both_have_points_in_one_view_is_left_apart_and_said_so(tmp_path):
    from sandtrack_tui.store import Project
    from sandtrack_tui.tracking.run import _merge_pairs

    proj = Project.create(tmp_path / "p.sandtrack")
    rows = [(f, "side", 2, 10.0 + f, 20.0, "tracked", 0.9, 5.0, 1.0) for f in range(3)]
    rows += [(f, "front", 13, 12.0 + f, 21.0, "tracked", 0.9, 5.0, 1.0) for f in range(3)]
    rows += [(f, "side", 3, 30.0 + f, 20.0, "tracked", 0.9, 5.0, 1.0) for f in range(3)]
    rows += [(f, "front", 14, 32.0 + f, 21.0, "tracked", 0.9, 5.0, 1.0) for f in range(3)]
    rows += [(40, "side", 14, 50.0, 20.0, "manual", 1.0, None, None)]  # placed in the side view before, elsewhere
    for m in (2, 3, 13, 14):
        proj.add_marker(str(m), m)
    proj.set_points(rows, "tracks")
    engine = SimpleNamespace(pairings=[((2, "side"), (13, "front"), 12, 30), ((3, "side"), (14, "front"), 10, 10)])
    problems: list = []
    with proj.edit("track forward from frame 0") as ed:
        made = _merge_pairs(proj, ed, engine, problems)
    assert made == [{"marker": 2, "from": 13, "camera": "front", "frames_on_line": 12, "frame": 30}]
    assert len(problems) == 1 and "marker 3 and marker 14" in problems[0] and "side" in problems[0]
    pts = proj.points()
    assert sorted(proj.markers()["id"]) == [2, 3, 14] and set(pts[pts.marker == 2].camera) == {"side", "front"}
    assert len(pts[pts.marker == 14]) == 4


def _under_tool(img: np.ndarray, x0: float, seed: int = 9) -> np.ndarray:
    """The tool over the frame from column x0 on: a flat grey surface with the camera's noise."""
    out = img.astype(np.float32)
    noise = np.random.default_rng(seed).normal(0.0, 1.5, out.shape[:2])
    out[:, int(x0):] = (95.0 + noise[:, int(x0):])[..., None]
    return np.clip(out, 0, 255).astype(np.uint8)


def test_a_carried_bead_half_under_the_tool_is_measured_by_its_highlight_and_a_hidden_one_is_not():
    k = 5
    loose, frames, t, eng = _tracked_bead(5)
    assert t.highlight.contrast > 20.0  # learned with its offset, where its outline was seen all round
    x, y = loose[k] + (2.4, 1.2)
    # Carried 1.7 px off (farther than the highlight alone vouches for), its right side under the tool: its
    # outline is not found all round, its highlight (up and left of its centre) stands out of its body.
    half = _under_tool(frames[-1], x + 4.0)
    assert t.matcher.silhouette(half, x, y, strict=True) is None
    m = t.confirm_carried(half, x + 1.2, y + 1.2)
    assert m is not None and math.hypot(m.x - x, m.y - y) < 0.3
    # Wholly under the tool: the brightest point of its flat surface is no highlight.
    assert t.confirm_carried(_under_tool(frames[-1], x - 2.0 * R), x + 1.2, y + 1.2) is None
    assert t.confirm_carried(_under_tool(frames[-1], x - 2.0 * R), x + 0.3, y + 0.2) is None
    # A highlight of this bead's look but that stands out of its body by the noise only is not its own.
    flat = crowd.highlight_contrast(_under_tool(frames[-1], x - 2.0 * R), x + SHINE[0] * R, y + SHINE[1] * R, x, y, R)
    assert abs(flat) < 5.0 and crowd.highlight_contrast(frames[-1], x + SHINE[0] * R, y + SHINE[1] * R, x, y, R) > 20.0


def test_a_carried_bead_whose_highlight_sits_far_off_its_centre_is_measured_by_it():
    # A slanted view sees a bead's highlight 0.45 radii off its centre: a search of half a radius around it
    # would reach the bead's rim and the brighter sand beyond, and find no highlight.
    k, shine = 5, (-0.3, -0.34)
    loose, frames, t, eng = _tracked_bead(5, shine=shine)
    assert np.hypot(*(np.array(t.highlight.offset) - np.array(shine) * R)) < 0.1  # measured 0.069 px
    x, y = loose[k] + (2.4, 1.2)
    assert t.highlight.reach() + math.hypot(*t.highlight.offset) <= R - 1.0  # on the bead's body
    m = t.confirm_carried(frames[-1], x + 0.4, y - 0.3)
    assert m is not None and math.hypot(m.x - x, m.y - y) < 0.3


def test_a_hidden_patch_is_registered_again_from_the_frame_the_most_beads_around_it_were_measured():
    # A row's six beads were hidden together and four show again beside a row of lookalikes no track follows.
    # The beads around them were measured with them at frame 8, not at frame 10 (the tool passed over them),
    # and are measured now.
    layer, now, group, anchors, lookalikes, shown, beads = _hidden_row()
    eng = Engine()
    crowd_bead = SimpleNamespace(crowd=True, radius=R)
    tracks = {k: SimpleNamespace(marker=k, model=crowd_bead) for k in group + anchors}
    eng.tracks.update({(k, "cam"): t for k, t in tracks.items()})
    for k in group:
        eng.crowd._crowd_seen[(k, "cam")] = {8: tuple(layer[k]), 10: tuple(layer[k] + (0.5, 0.3))}
    for k in anchors:
        eng.crowd._crowd_seen[(k, "cam")] = {8: tuple(layer[k])}
    props = {(k, "cam"): Proposal(Match(*now[k], 0.9, 3.0, 1.0)) for k in anchors}
    patch = [tracks[k] for k in group]
    # From frame 10, with no bead around them measured then, the patch fits the lookalikes' row as well.
    at, agreed = crowd.register(layer[group] + (0.5, 0.3), now[beads], R, 6 * R)
    assert all(beads[b] in lookalikes for b in agreed.values())
    # From frame 8, its anchors pin it: each shown bead its own.
    at, agreed = eng.crowd._register_pinned("cam", patch, now[beads], 0, props, {})
    assert {group[i]: beads[b] for i, b in agreed.items()} == {k: k for k in shown}
    # No frame with more anchors than the first try had: not tried again.
    assert eng.crowd._register_pinned("cam", patch, now[beads], len(anchors), props, {}) == (None, {})


def test_a_crowd_match_the_image_motion_refused_is_not_given_back_by_the_blob_search():
    loose, frames, t, eng = _tracked_bead(4, 3)
    t.predict()
    step = {"cam": (3, frames[3], 0.0)}
    # Missed this step, its bead in its gate: the blob search gives it back...
    props: dict = {}
    assert eng.reacquisition.run("cam", frames[3], [t], props, {}, step) == 1 and (2, "cam") in props
    # ... but not when its own match was refused by the flow check this step (that blob is that match).
    props = {}
    eng.crowd.flow_refused = {(2, "cam")}
    assert eng.reacquisition.run("cam", frames[3], [t], props, {}, step) == 0 and not props
