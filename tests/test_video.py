import random

import cv2
import numpy as np
import pytest

from conftest import frame_number, numbered_frame, write_clip
from sandtrack_tui.errors import SandtrackError
from sandtrack_tui.video import FramePair, FrameSource, fingerprint


def test_random_seek_equals_sequential_decode_with_bframes(clip):
    sequential = [f.copy() for _, f in FrameSource(clip).iter_frames()]
    assert [frame_number(f) for f in sequential] == list(range(60))
    src = FrameSource(clip, cache_mb=0.001)  # cache holds one frame: every access decodes
    order = list(range(60))
    random.Random(1).shuffle(order)
    for i in order + [59, 0, 30, 31, 29]:
        assert np.array_equal(src.frame(i), sequential[i]), f"frame {i} differs"


def test_exact_count_and_presentation_times(clip):
    src = FrameSource(clip)
    assert len(src) == 60
    assert src.fps == pytest.approx(50.0)
    assert np.allclose(np.diff(src.times_s), 0.02)
    assert src.index_at(0.503) == 25
    assert src.index_at(-5) == 0 and src.index_at(99) == 59


def test_cache_is_bounded(clip):
    frame_bytes = 320 * 240 * 3
    src = FrameSource(clip, cache_mb=5 * frame_bytes / 2**20)
    for i in range(60):
        src.frame(i)
    assert src._cache.bytes <= 5 * frame_bytes


def test_image_folder(tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(5):
        cv2.imwrite(str(folder / f"f{i:03d}.png"), numbered_frame(i))
    src = FrameSource(folder, fps=25)
    assert len(src) == 5 and src.times_s[2] == pytest.approx(0.08)
    assert [frame_number(src[i]) for i in (4, 0, 2)] == [4, 0, 2]


def test_frame_pair_sub_frame_offset(tmp_path):
    side = FrameSource(write_clip(tmp_path / "s.mp4", n_frames=40))
    front = FrameSource(write_clip(tmp_path / "f.mp4", n_frames=40))
    pair = FramePair(side, front, offset_s=0.137)  # front started 6.85 frames later
    p = pair.index(20)  # side t = 0.40 -> front t = 0.263 -> frame 13 + 0.15
    assert p.front == 13 and p.remainder_frames == pytest.approx(0.15)
    first, last = pair.side_range()
    assert first == 7 and last == 39
    s_img, f_img, _ = pair[20]
    assert frame_number(s_img) == 20 and frame_number(f_img) == 13


def test_mismatched_videos_are_reported(tmp_path):
    a = FrameSource(write_clip(tmp_path / "a.mp4", n_frames=5))
    b = FrameSource(write_clip(tmp_path / "b.mp4", n_frames=5, fps=25, width=160, height=120))
    warnings = FramePair(a, b).mismatch_warnings()
    assert any("resolutions differ" in w for w in warnings)
    assert any("frame rates differ" in w for w in warnings)


@pytest.mark.parametrize("kind", ["missing", "not_video", "empty", "garbage_mp4", "empty_folder"])
def test_bad_video_inputs_raise_clear_errors(tmp_path, kind):
    p = tmp_path / "x.mp4"
    if kind == "not_video":
        p.write_text("hello, I am a text file\n" * 100)
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "garbage_mp4":
        p.write_bytes(np.random.default_rng(0).integers(0, 256, 50_000, dtype=np.uint8).tobytes())
    elif kind == "empty_folder":
        p = tmp_path / "folder"
        p.mkdir()
    with pytest.raises(SandtrackError) as err:
        FrameSource(p)
    assert "\n" not in str(err.value)


def test_truncated_video_keeps_frames_before_the_damage(tmp_path):
    whole = write_clip(tmp_path / "whole.mp4", faststart=True)  # index first, as cameras write it
    data = whole.read_bytes()
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    src = FrameSource(cut)
    assert src.truncated and 10 < len(src) < 60
    assert [frame_number(f) for _, f in src.iter_frames()] == list(range(len(src)))


def test_truncated_index_gives_clear_error(tmp_path, clip):
    data = clip.read_bytes()  # index (moov) at the end: cutting it leaves nothing to read
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(SandtrackError):
        FrameSource(cut)


def test_fingerprint_changes_with_content(tmp_path, clip):
    fp = fingerprint(clip)
    other = write_clip(tmp_path / "other.mp4", n_frames=61)
    assert fingerprint(other) != fp and fingerprint(clip) == fp


def test_image_folder_frame_rate_is_kept_by_the_project(tmp_path):
    """An image folder's frame rate given to `sandtrack new --fps` is the project's: its frame times, its
    sources, and a relink that does not give it again."""
    import json
    import subprocess
    import sys

    from sandtrack_tui.store import Project
    from sandtrack_tui.xyz import Timeline

    folder = tmp_path / "imgs"
    folder.mkdir()
    for i in range(4):
        cv2.imwrite(str(folder / f"f{i:03d}.png"), numbered_frame(i))
    proj_path = tmp_path / "flume.sandtrack"
    out = subprocess.run([sys.executable, "-m", "sandtrack_tui", "new", str(proj_path), "--side", str(folder),
                          "--fps", "130", "--json"], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["videos"]["side"]["fps"] == 130
    proj = Project.open(proj_path)
    assert proj.videos()["side"].fps == 130
    assert Timeline.from_project(proj).time("side", np.array([13]))[0] == pytest.approx(0.1)
    assert proj.open_sources()["side"].times_s[3] == pytest.approx(3 / 130)
    proj.link_video("side", folder)  # a relink keeps the rate
    assert proj.videos()["side"].fps == 130
    proj.close()
    bad = subprocess.run([sys.executable, "-m", "sandtrack_tui", "new", str(tmp_path / "b.sandtrack"), "--side",
                          str(folder), "--fps", "0"], capture_output=True, text=True)
    assert bad.returncode == 1 and "--fps" in bad.stderr and "Traceback" not in bad.stderr
