"""Lost tracks: the 1 s window and PMR on short tracks."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track import ByteTrack, JPTrack
from gldt_core.track.jptrack import PMR_SETTLING_HITS, settled_history


@pytest.mark.parametrize("last_frame", range(1, 60))
def test_a_thirty_frame_gap_is_bridged_whatever_the_frame_number(last_frame: int) -> None:
    """The 1 s window must not depend on where (f + 30) / 30 - f / 30 rounds."""
    tr = ByteTrack()
    for frame in range(last_frame + 31):
        seen = frame <= last_frame or frame == last_frame + 30
        out = tr.update(np.array([[100, 100, 120, 120, 0.9]]) if seen else None, frame / 30)
    assert out[:, 4].tolist() == [1.0]


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
