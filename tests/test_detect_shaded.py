"""Every-particle detection of solid markers in shade: blue discs on textured sand under light that
falls off across the view, some smaller (farther), some partly hidden by a sand grain."""

import cv2
import numpy as np

from sandtrack_tui.tracking.detect import detect, learn_particle, local_background, project

W, H, N, DIAM = 480, 320, 120, 12.0


def _scene():
    rng = np.random.default_rng(3)
    sand = rng.normal(0, 1, (H, W, 3)).astype(np.float32)
    sand = cv2.GaussianBlur(sand, (0, 0), 1.5) * 40 + np.array([110, 160, 190], np.float32)  # BGR: tan
    xy, placed = [], 0
    while placed < N:
        p = rng.uniform([20, 20], [W - 20, H - 20])
        if xy and np.hypot(*(np.array(xy) - p).T).min() < 1.6 * DIAM:
            continue
        xy.append(p)
        placed += 1
    xy = np.array(xy)
    img = sand.copy()
    blue = np.array([170, 60, 30], np.float32)
    yy, xx = np.mgrid[0:H, 0:W]
    for k, (x, y) in enumerate(xy):
        r = DIAM / 2 * (0.8 + 0.4 * (y / H))  # nearer the bottom: larger
        cover = np.clip(r + 0.5 - np.hypot(xx - x, yy - y), 0, 1)[..., None]
        img = img * (1 - cover) + blue * cover
        if k % 4 == 0:  # a grain hides part of the marker's rim
            a = rng.uniform(0, 2 * np.pi)
            gx, gy = x + 0.9 * r * np.cos(a), y + 0.9 * r * np.sin(a)
            grain = np.clip(0.35 * DIAM + 0.5 - np.hypot(xx - gx, yy - gy), 0, 1)[..., None]
            img = img * (1 - grain) + np.array([120, 170, 200], np.float32) * grain
    light = (1.0 - 0.65 * xx / W)[..., None]  # shade: the right side gets a third of the light
    img = np.clip(img * light + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8)
    return img, xy


def test_shaded_partly_hidden_markers_found_and_nothing_else():
    img, xy = _scene()
    seed = xy[np.argmin(xy[:, 0] + np.abs(xy[:, 1] - H / 2))]  # a lit, whole marker at the left
    model = learn_particle(img, seed[0] + 1.0, seed[1] - 1.0, DIAM)
    det = detect(img, model)[["x_px", "y_px"]].to_numpy()
    d = np.hypot(*(det[None] - xy[:, None]).transpose(2, 0, 1))
    found = d.min(axis=1) <= 1.5
    assert found.mean() >= 0.95
    assert (d.min(axis=0) > 3.0).sum() <= 2  # detections on no marker (sand, grains)


def test_thousands_of_candidates_in_one_frame():
    # A 1080p frame of sand holds thousands of candidate peaks; their rays are sampled in slices
    # (cv2.remap takes maps of fewer than 32767 rows).
    img, xy = _scene()
    model = learn_particle(img, xy[0, 0], xy[0, 1], DIAM)
    n = 1500
    x = np.tile(xy[:, 0], n // len(xy) + 1)[:n]
    y = np.tile(xy[:, 1], n // len(xy) + 1)[:n]
    bg = local_background(project(img, model.weights), model, x, y)
    assert bg.shape == (n,) and np.isfinite(bg).all()
    assert np.array_equal(bg[:len(xy)], bg[len(xy):2 * len(xy)])


def test_an_edge_between_sand_and_a_darker_wall_is_no_particle():
    # The sand box's wall meets the sand along a straight edge: on one side of it the projection is lower
    # all along, as round a marker; a particle stands out on most sides, the edge on one side only.
    img, xy = _scene()
    seed = xy[np.argmin(xy[:, 0] + np.abs(xy[:, 1] - H / 2))]
    model = learn_particle(img, seed[0] + 1.0, seed[1] - 1.0, DIAM)
    above = np.arange(H)[:, None, None] < 100 + 0.05 * np.arange(W)[None, :, None]  # a slightly tilted edge
    on_sand = xy[:, 1] > 100 + 0.05 * xy[:, 0] + DIAM
    off = 0
    for shade in ([0.45, 0.38, 0.36], [1.0, 0.6, 0.5], [0.5, 0.5, 0.5]):  # walls of three colours
        wall = np.where(above, np.clip(img * np.array(shade), 0, 255).astype(np.uint8), img)
        det = detect(wall, model)[["x_px", "y_px"]].to_numpy()
        d = np.hypot(*(det[None] - xy[:, None]).transpose(2, 0, 1))
        assert (d[on_sand].min(axis=1) <= 1.5).mean() >= 0.95
        off += int((d.min(axis=0) > 3.0).sum())
    assert off <= 1
