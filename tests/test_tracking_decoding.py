"""The tracker's frame prefetch: the right frames in the asked order, and backward reading that
decodes each group of pictures in forward passes instead of once per frame."""

from __future__ import annotations

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
