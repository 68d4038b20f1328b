"""Tracking H.264 video of synthetic markers (clean, and dusty with a tool passing over them), with and
without the luma carry between intra-coded frames: the carry must not cost accuracy or cause a false lock."""

from __future__ import annotations

from fractions import Fraction

import av
import numpy as np
import pandas as pd
import pytest

from sandtrack_tui.store import Project
from sandtrack_tui.tracking import synthetic
from sandtrack_tui.tracking.luma import LumaPattern, edge_centre, edge_circle, intra_frames
from sandtrack_tui.tracking.run import accept_seeds, track_project
from sandtrack_tui.tracking.tracker import TrackParams
from sandtrack_tui.video import FrameSource

N = 75
KEYINT = 25


def _encode(frames, path, keyint: int = KEYINT) -> None:
    with av.open(str(path), "w") as out:
        s = out.add_stream("libx264", rate=Fraction(50))
        s.width, s.height, s.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
        s.options = {"crf": "26", "preset": "veryfast",
                     "x264-params": f"keyint={keyint}:min-keyint={keyint}:scenecut=0:bframes=2"}
        for img in frames:
            for p in s.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                out.mux(p)
        for p in s.encode():
            out.mux(p)


def _paths():
    t = np.arange(N, dtype=float)
    paths = synthetic.standard_paths(N)
    paths.append(synthetic.MarkerPath(7, np.stack([100 + 0.15 * t, 60 + 0.08 * t], 1), radius=4.5))  # creeping
    paths.append(synthetic.MarkerPath(8, np.stack([380 + 0.3 * t, 40 + 0.0 * t], 1), radius=4.2))
    return paths


def _run(video, clip, tmp_path, **params):
    name = "_".join(f"{k}{v}" for k, v in params.items())
    with Project.create(tmp_path / f"{name}.sandtrack", {"side": video}) as proj:
        accept_seeds(proj, clip.seeds.rename(columns={"x": "x_px", "y": "y_px"}).assign(camera="side"))
        summary = track_project(proj, params=TrackParams(**params))
        p = proj.points().merge(clip.truth, on=["frame", "marker"], suffixes=("", "_t"))
    return p, summary


def _track(video, clip, tmp_path, carry: bool):
    p, _ = _run(video, clip, tmp_path, luma_carry=carry)
    p = p[(p.status == "tracked") & p.visible]
    return np.hypot(p.x_px - p.x_px_t, p.y_px - p.y_px_t).to_numpy()


@pytest.mark.parametrize("dusty, tool", [(0.0, None), (0.35, (240, 300, 40, -60, 6.0))], ids=["clean", "dusty"])
def test_luma_carry_costs_nothing_on_clean_or_dusty_video(tmp_path, dusty, tool):
    clip = synthetic.render(_paths(), N, dusty=dusty, tool=tool, seed=3)
    video = tmp_path / "side.mp4"
    _encode(clip.frames, video)
    with FrameSource(video, cache_mb=8) as src:
        assert np.flatnonzero(intra_frames(src)).tolist() == list(range(0, N, KEYINT))
    off, on = _track(video, clip, tmp_path, False), _track(video, clip, tmp_path, True)
    # the carry never changes what is tracked (measured 98.1 % / 98.7 % of the visible frames)
    assert len(on) == len(off) > 0.97 * clip.truth.visible.sum()
    assert on.max() < 3.0  # no false lock
    assert on.mean() <= off.mean() + 0.03 and np.percentile(on, 95) <= np.percentile(off, 95) + 0.05


def test_edge_centre_finds_a_dark_disc_and_refuses_flat_sand():
    img = np.full((60, 60, 3), (110, 150, 185), np.uint8)
    yy, xx = np.mgrid[0:60, 0:60]
    cx, cy, r = 30.3, 28.6, 4.5
    ss = 8  # anti-aliased disc
    sub = ((xx[..., None, None] + (np.arange(ss)[None, None, :, None] + 0.5) / ss - 0.5 - cx) ** 2
           + (yy[..., None, None] + (np.arange(ss)[None, None, None, :] + 0.5) / ss - 0.5 - cy) ** 2) < r * r
    cov = sub.mean(axis=(2, 3))[..., None]
    img = (img * (1 - cov) + np.array([175, 95, 35]) * 0.6 * cov).astype(np.uint8)
    x, y = edge_centre(img, cx + 0.7, cy - 0.5, r)
    assert np.hypot(x - cx, y - cy) < 0.077  # measured 0.051 px
    assert edge_centre(np.full((60, 60, 3), 128, np.uint8), 30, 30, r) is None
    r = 5.0  # pressed by three beads like it (the gaps closed): their outlines lie outside its circle; with the
    # beads' known radius they are left out of the fit, a free circle is drawn off by them.
    cov = _disc(cx, cy, r)
    for a in (-30, 30, 90):
        cov = np.maximum(cov, _disc(cx + 1.7 * r * np.cos(np.radians(a)), cy + 1.7 * r * np.sin(np.radians(a)), r))
    img = (160 * (1 - cov[..., None]) + 25 * cov[..., None]).astype(np.uint8).repeat(3, axis=2)
    known = edge_circle(img, cx + 0.8, cy - 0.6, r, iterations=5, outward=True, known_radius=True)
    free = edge_circle(img, cx + 0.8, cy - 0.6, r, iterations=5, outward=True)
    assert known[2] == r and known[3] == 4
    assert np.hypot(known[0] - cx, known[1] - cy) < 0.3 < np.hypot(free[0] - cx, free[1] - cy)


def test_one_fit_of_the_silhouette_circle_from_a_start_off_its_centre_is_the_silhouettes():
    # The luma carry fits the circle once (refine.CARRY_EDGE_ROUNDS), from the colour centre less its offset
    # at the last intra frame: from up to 1.4 px off, in any direction, on noisy sand, that one fit is the
    # dark disc's circle within 0.06 px.
    from sandtrack_tui.tracking.refine import CARRY_EDGE_ROUNDS

    rng = np.random.default_rng(1)
    cx, cy, r = 30.3, 28.6, 4.5
    cov = _disc(cx, cy, r)[..., None]
    img = np.array([110, 150, 185]) * (1 - cov) + np.array([175, 95, 35]) * 0.6 * cov + rng.normal(0, 3, (60, 60, 3))
    img = np.clip(img, 0, 255).astype(np.uint8)
    for off in (0.3, 0.7, 1.0, 1.4):
        for a in np.radians(np.arange(0, 360, 45)):
            x, y = edge_centre(img, cx + off * np.cos(a), cy + off * np.sin(a), r, iterations=CARRY_EDGE_ROUNDS,
                               outward=True)
            assert np.hypot(x - cx, y - cy) < 0.06


def _disc(cx: float, cy: float, r: float, n: int = 60, ss: int = 8) -> np.ndarray:
    """Coverage (0..1) of an anti-aliased disc on an n x n grid."""
    yy, xx = np.mgrid[0:n, 0:n]
    sub = ((xx[..., None, None] + (np.arange(ss)[None, None, :, None] + 0.5) / ss - 0.5 - cx) ** 2
           + (yy[..., None, None] + (np.arange(ss)[None, None, None, :] + 0.5) / ss - 0.5 - cy) ** 2) < r * r
    return sub.mean(axis=(2, 3))


def _white_sphere_on_sand(sand, cx, cy, r, ss=8):
    """A matte white sphere lit from the upper left (its lit side brighter than the beige sand, its
    shaded side about as bright), anti-aliased, on `sand` (float BGR)."""
    out = sand.copy()
    x0, y0 = int(cx - r - 2), int(cy - r - 2)
    n = int(2 * r + 5)
    off = (np.arange(ss) + 0.5) / ss - 0.5
    yy, xx = np.mgrid[y0:y0 + n, x0:x0 + n].astype(float)
    nx = (xx[..., None, None] + off[None, None, None, :] - cx) / r
    ny = (yy[..., None, None] + off[None, None, :, None] - cy) / r
    inside = nx**2 + ny**2 < 1
    nz = np.sqrt(np.clip(1 - nx**2 - ny**2, 0, 1))
    light = np.array([-0.5, -0.6, 0.62]) / np.linalg.norm([-0.5, -0.6, 0.62])
    shade = 0.55 + 0.5 * np.clip(nx * light[0] + ny * light[1] + nz * light[2], 0, 1)
    cov = inside.mean(axis=(2, 3))[..., None]
    lum = np.where(inside, shade, 0).sum(axis=(2, 3)) / np.maximum(inside.sum(axis=(2, 3)), 1)
    marker = lum[..., None] * np.array([0.80, 0.82, 0.82]) * 255
    out[y0:y0 + n, x0:x0 + n] = out[y0:y0 + n, x0:x0 + n] * (1 - cov) + marker * cov
    return np.clip(out, 0, 255).astype(np.uint8)


def test_luma_pattern_follows_a_white_marker_that_has_no_dark_silhouette():
    """A white marker moved over sand that stays put: its disc's brightness pattern, registered from
    where it was, gives the move within 0.15 px; the dark-silhouette edge, which such a marker
    does not have, does not (the luma carry used it); a disc covered (by the tool) is not found."""
    sand = synthetic.sand_texture(80, 80, np.random.default_rng(5)).astype(float)
    r = 4.4
    new, old = [], []
    moves = [(38.3, 40.6, 1.3, -0.6), (41.7, 37.2, -0.8, 1.1), (40.0, 40.0, 2.0, 0.5), (39.4, 41.1, 0.4, 0.3)]
    for ax, ay, dx, dy in moves:
        a, b = _white_sphere_on_sand(sand, ax, ay, r), _white_sphere_on_sand(sand, ax + dx, ay + dy, r)
        pattern = LumaPattern(a, ax, ay, r)
        fx, fy = pattern.find(b, ax, ay)  # (searched from where it was: the stale colour's place)
        new.append(np.hypot(fx - ax - dx, fy - ay - dy))
        ea, eb = edge_centre(a, ax, ay, r, outward=True), edge_centre(b, ax, ay, r, outward=True)
        old.append(np.hypot(eb[0] - ea[0] - dx, eb[1] - ea[1] - dy) if ea and eb else np.inf)
        covered = b.copy()
        covered[25:55, 25:55] = (96, 100, 104)
        assert pattern.find(covered, ax, ay) is None
    assert max(new) < 0.13 and np.mean(new) < 0.25 * np.mean(old)  # measured 0.086 px


def test_luma_pattern_finds_a_fast_white_marker_smeared_by_the_exposure():
    """A white marker moving 6-9 px per frame, smeared over a whole frame's exposure: given its velocity,
    its pattern (cut while it was still) is found within 0.5 px of its mid-exposure centre and fits to
    NCC >= 0.98; without it, the still pattern alone misses the fastest one (fit under 0.9)."""
    sand = synthetic.sand_texture(80, 80, np.random.default_rng(5)).astype(float)
    r = 4.4
    unseen = 0
    for ax, ay, vx, vy in [(36.3, 40.6, 6.0, -1.5), (41.7, 37.2, -4.5, 4.0), (34.0, 38.0, 9.0, 1.0)]:
        cx, cy = ax + vx, ay + vy
        smear = [_white_sphere_on_sand(sand, cx + s * vx, cy + s * vy, r).astype(float)
                 for s in np.linspace(-0.5, 0.5, 13)]
        b = np.clip(np.mean(smear, axis=0), 0, 255).astype(np.uint8)
        pattern = LumaPattern(_white_sphere_on_sand(sand, ax, ay, r), ax, ay, r)
        unseen += pattern.find(b, cx - 1, cy + 0.5) is None
        found = pattern.find(b, cx - 1, cy + 0.5, velocity=(vx, vy))
        assert found is not None and np.hypot(found[0] - cx, found[1] - cy) < 0.5 and pattern.fit >= 0.98
    assert unseen >= 1


def test_a_white_markers_colour_left_behind_or_partly_hidden_is_not_taken_for_it():
    """Between intra frames, a white marker whose pattern fits too poorly to place it keeps its colour
    match, unless it moves fast and the colour lies behind where the pattern registers, along the
    motion, by more than STALE_BEHIND_PX (stale chroma left behind), or the colour covers less than a
    whole disc and lies more than PARTIAL_ASTRAY_PX from where the pattern registers with a fit of
    PLACE_MIN_FIT or more (the uncovered part of a marker being hidden): then it is not measured."""
    from types import SimpleNamespace

    from sandtrack_tui.tracking.matcher import STREAK_MIN_SPEED, Match
    from sandtrack_tui.tracking.refine import PARTIAL_ASTRAY_PX, PLACE_MIN_FIT, STALE_BEHIND_PX, LumaCarry
    from sandtrack_tui.tracking.tracker import TrackParams

    def takes(colour_xy, velocity, coverage=0.9, fit=0.8):
        c = LumaCarry(None, TrackParams(), SimpleNamespace(vxy=velocity))
        c.pattern = SimpleNamespace(find=lambda *a, **k: None, place=(50.0, 40.0), fit=fit)  # (fit under MIN_NCC)
        c.offset = (0.5, -0.25)
        m = Match(*colour_xy, 0.73, 5.0, coverage)
        return c._carry_pattern(None, m, intra=False), (m.x, m.y) == colour_xy

    fast = (6.0, 8.0)  # 10 px per frame, along (0.6, 0.8)
    behind = 1.5 * STALE_BEHIND_PX
    at = (50.5, 39.75)  # the pattern's place + the offset
    assert takes((at[0] - 0.6 * behind, at[1] - 0.8 * behind), fast) == (False, True)
    assert takes((at[0] + 0.6 * behind, at[1] + 0.8 * behind), fast) == (True, True)  # ahead: not stale
    assert takes((at[0] + 0.8 * behind, at[1] - 0.6 * behind), fast) == (True, True)  # aside
    slow = tuple(0.9 * STREAK_MIN_SPEED * u for u in (0.6, 0.8))
    assert takes((at[0] - 0.6 * behind, at[1] - 0.8 * behind), slow) == (True, True)
    part, away, near = 0.6, 1.5 * PARTIAL_ASTRAY_PX, 0.7 * PARTIAL_ASTRAY_PX
    assert takes((at[0] + away, at[1]), slow, coverage=part) == (False, True)  # partly hidden, astray
    assert takes((at[0], at[1] - near), slow, coverage=part) == (True, True)  # partly hidden, in place
    assert takes((at[0] + away, at[1]), slow) == (True, True)  # a whole disc
    assert takes((at[0] + away, at[1]), slow, coverage=part, fit=0.8 * PLACE_MIN_FIT) == (True, True)  # no place


def test_a_white_marker_whose_colour_match_fails_at_an_intra_frame_is_found_by_its_pattern():
    """At an intra frame (fresh colour) a white marker whose colour match failed (smeared, say) is
    still found by its brightness pattern, as between intra frames, and the chain is cut again there."""
    from types import SimpleNamespace

    from sandtrack_tui.tracking.refine import LumaCarry
    from sandtrack_tui.tracking.tracker import TrackParams

    sand = synthetic.sand_texture(80, 80, np.random.default_rng(5)).astype(float)
    r, (ax, ay), (dx, dy) = 4.4, (38.3, 40.6), (1.6, -0.9)
    c = LumaCarry(SimpleNamespace(luma_follows=False, radius=r), TrackParams(),
                  SimpleNamespace(xy=(ax, ay), vxy=(0.0, 0.0), d2=lambda x, y: 1.0))
    c.intra = np.array([True, True])
    c.pattern, c.offset = LumaPattern(_white_sphere_on_sand(sand, ax, ay, r), ax, ay, r), (0.3, -0.2)
    m = c.pattern_match(_white_sphere_on_sand(sand, ax + dx, ay + dy, r), 1)
    assert m is not None and np.hypot(m.x - 0.3 - ax - dx, m.y + 0.2 - ay - dy) < 0.15
    assert (c.pattern.x, c.pattern.y) == m.luma


def test_a_lost_white_marker_is_found_again_by_the_pattern_kept_from_before_it_was_hidden():
    """A white marker lost (unseen longer than lost_after) is searched by the brightness pattern its chain
    had when the miss broke it: back in sight within its radius of its prediction, it is found there
    within 0.15 px and followed on from it; half covered, or farther than its radius, it is not."""
    from types import SimpleNamespace

    from sandtrack_tui.tracking.refine import LumaCarry
    from sandtrack_tui.tracking.tracker import LOST, MarkerTrack, TrackParams

    sand = synthetic.sand_texture(80, 80, np.random.default_rng(5)).astype(float)
    r, (ax, ay), (dx, dy), offset = 4.4, (38.3, 40.6), (1.2, -0.8), (0.3, -0.2)

    def lost_track():
        t = MarkerTrack.__new__(MarkerTrack)
        t.model, t.params = SimpleNamespace(luma_follows=False, radius=r), TrackParams()
        t.kf = SimpleNamespace(xy=(ax + offset[0], ay + offset[1]), vxy=(0.0, 0.0), d2=lambda x, y: 50.0)
        t.carry = LumaCarry(t.model, t.params, t.kf)
        t.intra = np.array([False])
        t.carry.pattern = LumaPattern(_white_sphere_on_sand(sand, ax, ay, r), ax, ay, r)
        t.carry.offset, t.carry.anchor_luma, t.status, t.held = offset, (ax, ay), LOST, False
        t.carry._follow_pattern_chain(None, None, False, long_miss=True)  # (the chain broken by the miss)
        assert t.carry.pattern is None
        t.misses = 40
        return t

    back = _white_sphere_on_sand(sand, ax + dx, ay + dy, r)
    t = lost_track()
    m = t.pattern_return(back, 7)
    assert m is not None and np.hypot(m.x - offset[0] - ax - dx, m.y - offset[1] - ay - dy) < 0.15
    assert t.carry.pattern is not None and t.carry.kept is None  # (followed on by its pattern)
    half = back.copy()
    half[int(ay + dy):, :] = np.round(sand[int(ay + dy):, :]).astype(np.uint8)
    assert lost_track().pattern_return(half, 7) is None
    far = _white_sphere_on_sand(sand, ax + 2.5 * r, ay, r)
    assert lost_track().pattern_return(far, 7) is None


def test_a_white_marker_found_again_far_away_with_weak_colour_is_placed_by_its_kept_pattern():
    """A lost white marker carried while hidden far beyond its radius of its prediction, whose colour match at
    the blob re-acquisition gave it covers less than min_colour and fits its template less than min_score
    (its chroma contrast weakened), but stands out (PSR): its brightness pattern, kept from before the miss,
    places it within 0.15 px of its centre and its chain goes on from there; half covered, or with a colour
    peak that does not stand out, it is not taken."""
    from types import SimpleNamespace

    from sandtrack_tui.tracking.matcher import Match
    from sandtrack_tui.tracking.refine import LumaCarry
    from sandtrack_tui.tracking.tracker import LOST, MarkerTrack, TrackParams

    sand = synthetic.sand_texture(80, 80, np.random.default_rng(5)).astype(float)
    r, (ax, ay), offset = 4.4, (30.3, 40.6), (0.3, -0.2)
    bx, by = ax + 5 * r, ay - 1.3  # (carried far from where it was lost: pattern_return does not see it)

    def lost_track():
        t = MarkerTrack.__new__(MarkerTrack)
        t.model = SimpleNamespace(luma_follows=False, radius=r, has_blob=True)
        t.params = TrackParams()
        t.kf = SimpleNamespace(xy=(ax + offset[0], ay + offset[1]), vxy=(0.0, 0.0), d2=lambda x, y: 50.0)
        t.carry = LumaCarry(t.model, t.params, t.kf)
        t.intra = np.array([False])
        t.carry.pattern = LumaPattern(_white_sphere_on_sand(sand, ax, ay, r), ax, ay, r)
        t.carry.offset, t.carry.anchor_luma, t.status, t.held = offset, (ax, ay), LOST, False
        t.carry._follow_pattern_chain(None, None, False, long_miss=True)  # (the chain broken by the miss)
        t.misses = 40
        return t

    p = TrackParams()
    weak = Match(bx + offset[0] + 1.2, by + offset[1] - 0.6, 0.9 * p.min_score, 2 * p.min_psr, 0.8 * p.min_colour)
    back = _white_sphere_on_sand(sand, bx, by, r)
    t = lost_track()
    assert t.pattern_return(back, 7) is None
    m = t.carry.whole_by_pattern(back, weak, 1.0)
    assert m is not None and np.hypot(m.x - offset[0] - bx, m.y - offset[1] - by) < 0.15
    t.carry._follow_pattern_chain(back, m, reattach=True)
    assert t.carry.pattern is not None and t.carry.kept is None  # (followed on by its pattern)
    half = back.copy()
    half[int(by):, :] = np.round(sand[int(by):, :]).astype(np.uint8)
    assert lost_track().carry.whole_by_pattern(half, weak, 1.0) is None
    flat = Match(weak.x, weak.y, weak.score, 0.5 * p.min_psr, weak.colour_frac)
    assert lost_track().carry.whole_by_pattern(back, flat, 1.0) is None


def test_a_creeping_white_marker_is_carried_by_its_brightness_pattern_not_its_stale_colour(tmp_path):
    """A white marker creeping over beige sand (its colour model has a contrast of ~5 sand spreads, its
    brightness no dark edge), in H.264: between intra frames its colour stays behind; followed by its
    brightness pattern it stays within a pixel of the truth (the dark-edge carry: 1.5 px mean, 3.4 max)."""
    n, rng = 40, np.random.default_rng(4)
    sand = synthetic.sand_texture(96, 128, rng).astype(float)
    sand += 1.5 * (sand - sand.mean(axis=(0, 1)))  # coarse grains: the sand's spread of ~20 luma levels
    xy = np.stack([40 + 0.3 * np.arange(n), 48 + 0.1 * np.arange(n)], 1)
    frames = [np.clip(_white_sphere_on_sand(sand, *xy[f], 4.4) + rng.normal(0, 2, sand.shape), 0, 255)
              .astype(np.uint8) for f in range(n)]
    video = tmp_path / "side.mp4"
    _encode(frames, video, keyint=20)
    with Project.create(tmp_path / "w.sandtrack", {"side": video}) as proj:
        accept_seeds(proj, pd.DataFrame([(1, "side", 0, *xy[0], 16.0, 16.0)],
                                        columns=["marker", "camera", "frame", "x_px", "y_px", "w", "h"]))
        summary = track_project(proj)
        p = proj.points()
    assert summary["per_marker"]["1"]["side"]["appearance"]["model"] == "colour"
    p = p[p.status == "tracked"]
    err = np.hypot(p.x_px - xy[p.frame, 0], p.y_px - xy[p.frame, 1])
    assert len(p) >= n - 2 and err.mean() < 0.7 and err.max() < 1.5


def test_markers_at_rest_or_creeping_follow_their_measurement_and_moving_ones_are_measured(tmp_path):
    t = np.arange(N, dtype=float)
    paths = [synthetic.MarkerPath(1, np.stack([120.3 + 0 * t, 100.6 + 0 * t], 1)),  # still
             synthetic.MarkerPath(2, np.stack([60 + 0.5 * t, 250 + 0.2 * t], 1)),  # drifting
             synthetic.MarkerPath(3, np.stack([330 + 0.05 * t, 180 - 0.03 * t], 1))]  # creeping
    clip = synthetic.render(paths, N, seed=5)
    video = tmp_path / "side.mp4"
    _encode(clip.frames, video)
    full, _ = _run(video, clip, tmp_path, rest_check=False)
    fast, summary = _run(video, clip, tmp_path, rest_check=True)
    at_rest = {int(m): d["side"]["at_rest"] for m, d in summary["per_marker"].items()}
    assert at_rest[1] > N // 2 and at_rest[2] == 0
    assert at_rest[3] > N // 2  # creeping 0.06 px/frame: followed by its brightness shift
    both = full.merge(fast, on=["frame", "marker"], suffixes=("_full", "_fast"))
    assert (both.status_full == both.status_fast).all()
    shift = np.hypot(both.x_px_full - both.x_px_fast, both.y_px_full - both.y_px_fast)
    assert shift.max() < 0.1
    err = np.hypot(fast.x_px - fast.x_px_t, fast.y_px - fast.y_px_t)
    assert err[fast.status == "tracked"].max() < 1.0


def test_tracking_backward_through_video_matches_the_truth(tmp_path):
    """Re-tracking backward from the last frame: the reader decodes each group of pictures forward
    and hands it out in reverse (decoding.py); the track must be as good as the forward one."""
    clip = synthetic.render(synthetic.standard_paths(N), N, seed=4)
    video = tmp_path / "side.mp4"
    _encode(clip.frames, video)
    with Project.create(tmp_path / "back.sandtrack", {"side": video}) as proj:
        accept_seeds(proj, clip.seeds.rename(columns={"x": "x_px", "y": "y_px"}).assign(camera="side"))
        track_project(proj)
        forward = proj.points()
        s = track_project(proj, start=N - 1, direction="backward")
        backward = proj.points()
    assert s["first_frame"] == N - 1 and s["last_frame"] == 0 and s["frames"] == N
    for p in (forward, backward):
        p = p.merge(clip.truth, on=["frame", "marker"], suffixes=("", "_t"))
        p = p[(p.status == "tracked") & p.visible]
        err = np.hypot(p.x_px - p.x_px_t, p.y_px - p.y_px_t)
        # measured: 444 of 450 visible frames, 0.28 / 0.31 px mean
        assert len(p) > 0.98 * clip.truth.visible.sum() and err.max() < 3.0 and err.mean() < 0.46
