"""Lost tracks: the 1 s window, a coasting box that keeps its size, PMR on short tracks."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track import ByteTrack, JPTrack
from gldt_core.track.jptrack import PMR_SETTLING_HITS, settled_history
from gldt_core.track.state import TrackState


@pytest.mark.parametrize("last_frame", range(1, 60))
def test_a_thirty_frame_gap_is_bridged_whatever_the_frame_number(last_frame: int) -> None:
    """The 1 s window must not depend on where (f + 30) / 30 - f / 30 rounds."""
    tr = ByteTrack()
    for frame in range(last_frame + 31):
        seen = frame <= last_frame or frame == last_frame + 30
        out = tr.update(np.array([[100, 100, 120, 120, 0.9]]) if seen else None, frame / 30)
    assert out[:, 4].tolist() == [1.0]


def test_a_lost_track_coasts_at_the_size_it_had_when_lost() -> None:
    tr = ByteTrack()
    for frame in range(8):  # a small target whose box shrinks 1 px a frame: 14 px down to 7 px
        size = 14 - frame
        tr.update(np.array([[100.0 + 3 * frame, 100, 100 + 3 * frame + size, 100 + size, 0.9]]), frame / 30)
    widths = []
    for frame in range(8, 38):
        tr.update(None, frame / 30)
        (track,) = [t for t in tr.tracks if t.state is TrackState.LOST]
        x1, _, x2, _ = track.box_xyxy
        widths.append(x2 - x1)
    # Lost on the first missed frame (predicted one frame on), then no more shrinking: without
    # the freeze it would coast down by about 1 px a frame to the filter's floor.
    assert widths[-1] == pytest.approx(widths[0], abs=1e-9) and widths[0] > 5.0
    assert track.box_xyxy[0] > 100 + 3 * 7  # the position still moves with the velocity


@pytest.mark.parametrize("hits", [6, 8, 10])
def test_pmr_brings_back_a_short_track_after_more_than_a_second(hits: int) -> None:
    tr = JPTrack()
    shown = []
    for frame in range(hits + 45 + 5):
        x = 100 + 5.0 * frame
        seen = not hits <= frame < hits + 45  # hidden 1.5 s: beyond JCMA's 1 s window, PMR's job
        out = tr.update(np.array([[x, 200, x + 6, 206, 0.9]]) if seen else None, frame / 30)
        if frame >= hits + 45:
            shown += out[:, 4].astype(int).tolist()
    assert shown and set(shown) == {1}, shown


def test_settled_history_drops_the_first_three_updates_only_while_they_are_in_the_deque() -> None:
    def track_after(updates: int):
        tr = JPTrack()  # history_len 30
        for frame in range(updates):
            tr.update(np.array([[100.0 + frame, 100, 110 + frame, 110, 0.9]]), frame / 30)
        (track,) = tr.tracks
        return track

    assert PMR_SETTLING_HITS == 3
    young = track_after(10)
    assert np.array_equal(settled_history(young), young.history_array()[3:])
    rolled = track_after(31)  # the deque already forgot the birth sample: two unsettled are left
    assert np.array_equal(settled_history(rolled), rolled.history_array()[2:])
    old = track_after(40)
    assert np.array_equal(settled_history(old), old.history_array())
    newborn = track_after(2)
    assert len(settled_history(newborn)) == 1  # never empty: the newest sample stays
