"""The tracker's frame prefetch: the right frames in the asked order, and backward reading that
decodes each group of pictures in forward passes instead of once per frame."""

from __future__ import annotations

import time

import numpy as np
import pytest

from conftest import frame_number, write_clip
from sandtrack_tui.tracking.decoding import ThreadPrefetch
from sandtrack_tui.video import FrameSource

GOP = 12


class CountingSource(FrameSource):
    """A FrameSource that counts the frames its decoder produced."""

    decoded = 0

    def _frames_from_decoder(self):
        for frame in super()._frames_from_decoder():
            self.decoded += 1
            yield frame


def _read(source, indices, budget_mb):
    source.frame(indices[0])  # the decoder past the start, as after showing that frame
    source.decoded = 0
    feed = ThreadPrefetch(source, indices, budget_mb=budget_mb)
    try:
        return [feed.get() for _ in indices]
    finally:
        feed.close()


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_clip(tmp_path_factory.mktemp("prefetch") / "clip.mp4", n_frames=60, gop=GOP)


@pytest.mark.parametrize("indices", [list(range(59, -1, -1)), list(range(50, 3, -3)), list(range(60))],
                         ids=["backward", "backward-step-3", "forward"])
def test_prefetch_hands_out_the_asked_frames_in_order(clip, indices):
    with FrameSource(clip, cache_mb=1) as src:
        frame_mb = src.width * src.height * 3 / 2**20
        got = _read(src, indices, budget_mb=5 * frame_mb)  # slices of 5 frames: several passes per group
    assert [j for j, _ in got] == indices
    assert [frame_number(img) for _, img in got] == indices


def test_backward_reading_decodes_each_group_once_when_it_fits(clip):
    with CountingSource(clip, cache_mb=1) as src:
        assert list(src.keyframes.nonzero()[0]) == list(range(0, 60, GOP))
        _read(src, list(range(59, -1, -1)), budget_mb=64)
        one_pass = src.decoded
    with CountingSource(clip, cache_mb=1) as src:
        frame_mb = src.width * src.height * 3 / 2**20
        _read(src, list(range(59, -1, -1)), budget_mb=4 * frame_mb)
        sliced = src.decoded
    # Frame by frame with a small cache, reading backward decodes ~6.5 frames per frame here.
    assert one_pass == 60  # every group of 12 in one forward pass
    assert sliced == 5 * (12 + 8 + 4)  # slices of 4 from the top of each group, each pass from its key frame


class SlowSource:
    """Frames that take a while to decode; optionally a decoder failure at one index."""

    width, height = 64, 48

    def __init__(self, delay_s=0.01, fail_at=None):
        self.delay_s, self.fail_at, self.made = delay_s, fail_at, 0

    def frame(self, j):
        time.sleep(self.delay_s)
        if j == self.fail_at:
            raise RuntimeError(f"damaged frame {j}")
        self.made += 1
        return np.full((self.height, self.width, 3), j, dtype=np.uint8)


def test_wait_for_returns_once_a_batch_is_decoded():
    src = SlowSource()
    feed = ThreadPrefetch(src, list(range(40)), depth=8)
    try:
        feed.wait_for(5)
        assert src.made >= 5  # the batch is there: five gets will not wait for the decoder
        assert [feed.get()[0] for _ in range(5)] == list(range(5))
        feed.wait_for(100)  # more than the queue holds: waits for a full queue only
        assert src.made - 5 >= feed.depth
    finally:
        feed.close()


def test_wait_for_past_the_end_or_a_decoder_failure_returns():
    feed = ThreadPrefetch(SlowSource(), [0, 1, 2], depth=8)
    try:
        feed.wait_for(4)  # only three frames will ever come
        assert [feed.get()[0] for _ in range(3)] == [0, 1, 2]
        with pytest.raises(RuntimeError, match="stopped before"):
            feed.get()
    finally:
        feed.close()
    feed = ThreadPrefetch(SlowSource(fail_at=2), list(range(10)), depth=8)
    try:
        feed.wait_for(4)
        assert [feed.get()[0] for _ in range(2)] == [0, 1]
        with pytest.raises(RuntimeError, match="damaged frame 2"):
            feed.get()
    finally:
        feed.close()


def test_close_releases_a_decoder_waiting_for_room():
    src = SlowSource(delay_s=0.0)
    feed = ThreadPrefetch(src, list(range(100)), depth=4)
    feed.wait_for(4)
    feed.close()
    assert not feed._t.is_alive()
    assert src.made <= 5  # it stopped at the full queue instead of decoding on
