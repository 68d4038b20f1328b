"""Every-particle tracks joined at the end of a run: pieces of one track across short gaps (gaps.py), and the
tracks of two calibrated views paired across them (particle_pairs.py), on the sample's true tracks (its two
cameras, 0.4373 s apart: a fractional frame) and on synthetic pieces with the traps a crowd sets."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from conftest import SAMPLE_DATA, claimed
from sandtrack_tui.camera import Calibration
from sandtrack_tui.store import Project
from sandtrack_tui.tracking.gaps import chains, find_joins, gap_rows, pieces_of
from sandtrack_tui.tracking.particle_joins import join_tracks
from sandtrack_tui.tracking.particle_pairs import pair_tracks
from sandtrack_tui.xyz import Timeline, compute_xyz

OFFSET_S = 0.4373  # sample_data/ground_truth/sync.json
FRONT = 100  # the front view's tracks get ids FRONT + true marker: each view tracked on its own


def _truth(cam: str) -> pd.DataFrame:
    return pd.read_csv(SAMPLE_DATA / "ground_truth" / f"markers_{cam}.csv")


def _rows(t: pd.DataFrame, cam: str, marker, rng, sd: float = 0.2) -> pd.DataFrame:
    """A view's tracked points (visible frames of the truth, centring noise `sd` px)."""
    t = t[t.visible.astype(bool)]
    return pd.DataFrame({"frame": t.frame.to_numpy(), "camera": cam, "marker": marker(t.marker.to_numpy()),
                         "x_px": t.x_px.to_numpy() + rng.normal(0, sd, len(t)),
                         "y_px": t.y_px.to_numpy() + rng.normal(0, sd, len(t)), "status": "tracked"})


@pytest.fixture(scope="module")
def sample_views():
    rng = np.random.default_rng(3)
    side = _rows(_truth("side"), "side", lambda m: m, rng)
    front = _rows(_truth("front"), "front", lambda m: m + FRONT, rng)
    cal = Calibration.load(SAMPLE_DATA / "ground_truth" / "cameras.toml")
    return side, front, cal


def _timeline(offset_s: float) -> Timeline:
    return Timeline(["side", "front"], {"side": 50.0, "front": 50.0}, {"front": offset_s}, {"side": 440, "front": 440})


def test_every_marker_of_the_sample_paired_right_across_its_views(sample_views):
    side, front, cal = sample_views
    res = pair_tracks(pd.concat([side, front]), cal, ("side", "front"), _timeline(OFFSET_S))
    pairs = sorted((g["side"], g["front"]) for g in res.groups)
    assert pairs == [([m], [m + FRONT]) for m in range(1, 9)]
    assert not res.ambiguous.get("side") and not res.lonely.get("side")


def test_a_second_track_on_the_same_lines_leaves_the_pair_unpaired(sample_views):
    side, front, cal = sample_views
    twin = front[front.marker == FRONT + 3].assign(marker=999, x_px=lambda d: d.x_px + 0.3)  # a look-alike on the line
    res = pair_tracks(pd.concat([side, front, twin]), cal, ("side", "front"), _timeline(OFFSET_S))
    paired = {m for g in res.groups for m in g["side"]}
    assert paired == {1, 2, 4, 5, 6, 7, 8}  # marker 3 left apart, said so
    assert 3 in res.ambiguous["side"] and {FRONT + 3, 999} <= set(res.ambiguous["front"])


def test_without_the_sync_offset_no_wrong_pair(sample_views):
    side, front, cal = sample_views
    res = pair_tracks(pd.concat([side, front]), cal, ("side", "front"), _timeline(0.0))
    assert all(g["front"] == [m + FRONT for m in g["side"]] for g in res.groups)


def test_a_ghost_pair_of_two_particles_on_one_epipolar_plane_is_left_unpaired(sample_views):
    """Two particles on one epipolar plane (P: marker 3; Q: P moved 25 mm along the baseline), each seen
    measured in one view only: side's track of Q and front's of P lie on each other's lines, a ghost. P's
    side track is there, but flagged (its detections merged with a neighbour's): a rival all the same."""
    side, front, cal = sample_views
    rng = np.random.default_rng(5)
    shift = 0.05 * (cal.cameras["front"].center_mm - cal.cameras["side"].center_mm)
    t = _truth("side")
    t = t[(t.marker == 3) & t.visible.astype(bool)]
    q = cal.cameras["side"].project(cal.to_rig(t[["X_mm", "Y_mm", "Z_mm"]].to_numpy()) + shift)
    ghost = pd.DataFrame({"frame": t.frame.to_numpy(), "camera": "side", "marker": 997,
                          "x_px": q[:, 0] + rng.normal(0, 0.2, len(t)), "y_px": q[:, 1] + rng.normal(0, 0.2, len(t)),
                          "status": "tracked"})
    merged = side.marker == 3
    flagged = side.assign(status=np.where(merged, "occluded", side.status), score=np.where(merged, 0.6, 0.9))
    res = pair_tracks(pd.concat([flagged, ghost, front]), cal, ("side", "front"), _timeline(OFFSET_S))
    assert all(g["front"] == [m + FRONT for m in g["side"]] for g in res.groups)  # no ghost pair
    assert {m for g in res.groups for m in g["side"]} == {1, 2, 4, 5, 6, 7, 8}
    assert 997 in res.ambiguous["side"] and FRONT + 3 in res.ambiguous["front"]
    # a coasting prediction (no detection, no score) is no evidence of the particle
    coasting = flagged.assign(score=np.where(merged, np.nan, 0.9))
    res = pair_tracks(pd.concat([coasting, ghost, front]), cal, ("side", "front"), _timeline(OFFSET_S))
    assert {"side": [997], "front": [FRONT + 3]} in res.groups


def _pieces(tracks: dict[int, np.ndarray], cuts: dict[int, list[tuple[int, int]]], first_id: int = 1):
    """Points of true tracks (id -> (frames, 3): frame, x, y) cut into pieces (id -> [(first, last frame)]),
    each piece a new id ending in 3 coasting frames and a `lost` one, as the tracker writes it. Returns the
    points and piece id -> true id."""
    rows, owner, nid = [], {}, first_id
    for tid, tr in tracks.items():
        for a, b in cuts.get(tid, [(int(tr[0, 0]), int(tr[-1, 0]))]):
            owner[nid] = tid
            piece = tr[(tr[:, 0] >= a) & (tr[:, 0] <= b)]
            rows += [(int(f), "side", nid, x, y, "tracked") for f, x, y in piece]
            if b < 39:
                v = piece[-1] - piece[-2] if len(piece) > 1 else np.zeros(3)
                rows += [(b + k, "side", nid, piece[-1, 1] + v[1] * k, piece[-1, 2] + v[2] * k, "occluded")
                         for k in (1, 2, 3)]
                rows.append((b + 4, "side", nid, np.nan, np.nan, "lost"))
            nid += 1
    return pd.DataFrame(rows, columns=["frame", "camera", "marker", "x_px", "y_px", "status"]), owner


def _line(x0, y0, vx, vy, n=40):
    f = np.arange(n)
    return np.stack([f, x0 + vx * f, y0 + vy * f], axis=1).astype(float)


def test_gaps_closed_only_where_nothing_else_explains_them():
    tracks = {
        1: _line(100, 100, 2.0, 0.5),  # lost twice, each time found again where its motion leads
        2: _line(300, 100, 0.0, 0.0),  # at rest, lost once
        3: _line(500, 100, 1.0, 0.0),  # lost; a look-alike (4) starts beside where it should reappear
        4: _line(521.5, 101.5, 0.0, 0.0)[18:],
        5: _line(700, 80, 0.0, 0.0),  # at rest, lost; a fast particle (6) seen once passes on the spot...
        6: np.array([[23.0, 702.4, 81.25]]),  # ... before the resting one is found again
    }
    cuts = {1: [(0, 9), (13, 24), (31, 39)], 2: [(0, 19), (25, 39)], 3: [(0, 14), (20, 39)], 5: [(0, 19), (26, 39)]}
    pts, owner = _pieces(tracks, cuts)
    joins, apart = find_joins(pts, diameter_px=12.0, first_frame=0, last_frame=39)
    assert all(owner[a] == owner[b] for a, b in joins)  # never a wrong join
    joined = {owner[a] for a, _ in joins}
    assert {1, 2} <= joined and 3 not in joined and 5 not in joined and apart >= 2
    assert [owner[c[0]] for c in chains(joins) if len(c) == 3] == [1]  # three pieces, one particle
    # the frames between two joined pieces are flagged, never filled by a guess
    head = chains(joins)[0]
    writes, deletes = gap_rows(pieces_of(pts), head, "side")
    assert {w[0] for w in writes} == {10, 11, 12, 25, 26, 27, 28, 29, 30}
    assert {w[5] for w in writes} == {"occluded"}
    assert {w[0] for w in writes if w[3] is None} == {28, 29, 30}  # the tracker's coasting kept, nothing more
    assert {d[0] for d in deletes} == {13}  # the earlier piece's rows where the next one has the particle


def test_run_joins_make_one_marker_with_both_views_and_3d(tmp_path, sample_views):
    """The sample's tracks cut into pieces in each view: joined and paired in one edit, the 3D of each
    particle near the truth; one undo takes it all back."""
    side, front, cal = sample_views
    with Project.create(tmp_path / "p.sandtrack", {c: SAMPLE_DATA / "experiment" / f"{c}.mp4"
                                                    for c in ("side", "front")}) as proj:
        proj.set_calibration(cal)
        proj.set("sync_offset_s", OFFSET_S)
        cut = side[~((side.marker == 2) & side.frame.between(200, 203))]  # side marker 2 unseen 4 frames
        late = cut[(cut.marker == 2) & (cut.frame > 203)].index
        cut.loc[late, "marker"] = 50  # ... and found again as a new particle
        lost = pd.DataFrame([(204, "side", 2, np.nan, np.nan, "lost")], columns=cut.columns)
        rows = pd.concat([cut, lost, front]).assign(confidence=None, sd_px=None, score=None)
        with proj.edit("track every particle") as ed:
            ed.add_markers(set(rows.marker))
            ed.write(rows[["frame", "camera", "marker", "x_px", "y_px", "status", "confidence", "sd_px", "score"]]
                     .itertuples(index=False, name=None))
            out = join_tracks(proj, ed, {"side": (0, 439, 9.0), "front": (0, 439, 9.0)}, set(rows.marker))
        assert out["gaps"]["side"]["gaps_closed"] == 1 and out["pairing"]["paired"] == 8
        pts = proj.points()
        assert sorted(pts.marker.unique()) == list(range(1, 9))
        assert set(pts[(pts.camera == "side") & (pts.marker == 2) & pts.frame.between(200, 203)].status) == {"occluded"}
        xyz = compute_xyz(proj, method="triangulation")
        traj = pd.read_csv(SAMPLE_DATA / "ground_truth" / "trajectories.csv")
        m = xyz.dropna(subset=["X_mm"]).merge(traj, on=["frame", "marker"], suffixes=("", "_t"))
        err = np.linalg.norm(m[["X_mm", "Y_mm", "Z_mm"]].to_numpy() - m[["X_mm_t", "Y_mm_t", "Z_mm_t"]].to_numpy(),
                             axis=1)
        assert m.marker.nunique() == 8 and np.mean(err) <= 1.5 * claimed("particles_pairs", "mm")
        edits = proj.history()
        assert list(edits.kind).count("points") == 1  # the run, its joins included
        proj.undo()
        assert sorted(proj.points().marker.unique()) == []
