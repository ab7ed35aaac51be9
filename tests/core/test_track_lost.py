"""Lost tracks: the 1 s window and PMR on short tracks."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track import ByteTrack, JPTrack, JPTrackConfig
from gldt_core.track.base import REATTACHED_FIRST_STAGE, REATTACHED_RECOVER, REATTACHED_RELINK
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


def shown_after_return(config: JPTrackConfig, offset: float) -> list[int]:
    """Ids shown for a target seen 20 frames, hidden 1.5 s (45 frames at 30 Hz), then back
    ``offset`` px off its straight path."""
    tr = JPTrack(config)
    shown = []
    for frame in range(20 + 45 + 5):
        x, y = 100 + 5.0 * frame, 200 + (offset if frame >= 65 else 0.0)
        seen = not 20 <= frame < 65
        out = tr.update(np.array([[x, y, x + 10, y + 10, 0.9]]) if seen else None, frame / 30)
        if frame >= 65:
            shown += out[:, 4].astype(int).tolist()
    return shown


def test_a_tentative_track_seen_where_a_lost_track_would_be_continues_its_id() -> None:
    """120 px off after 1.5 s: beyond stage 3's tau_t, within the recovery radius (about 400 px
    here) at both sightings. The returning target keeps its id from its second sighting on, and
    keeps it (the fresh filter follows it); its first sighting is not shown either way (a
    tentative track)."""
    assert shown_after_return(JPTrackConfig(pmr_relink=False), 120.0) == [2, 2, 2, 2]  # off: a new id
    assert shown_after_return(JPTrackConfig(), 120.0) == [1, 1, 1, 1]


def test_relink_leaves_a_target_beyond_every_recovery_radius_a_new_id() -> None:
    assert shown_after_return(JPTrackConfig(), 600.0) == [2, 2, 2, 2]


def test_relink_prefers_the_track_lost_two_frames_ago_to_an_old_wide_hypothesis() -> None:
    """Target 1 vanished 2 s ago, 400 px away (a wide PMR mixture); target 2 is missed for two
    frames and comes back 40 px ahead, beyond JCMA's gate. Both gates hold, and the likelihood of
    the two sightings (not P_final, relative to each mixture's own mode) gives it to target 2."""
    tr = JPTrack()
    shown = []
    for frame in range(90):
        rows = []
        if frame < 20:
            rows.append([100 + 5.0 * frame, 200, 110 + 5.0 * frame, 210, 0.9])
        if frame >= 40 and not 78 < frame <= 80:
            x = 700 + 5.0 * (frame - 40) + (40.0 if frame > 80 else 0.0)
            rows.append([x, 300, x + 10, 310, 0.9])
        out = tr.update(np.array(rows) if rows else None, frame / 30)
        if frame > 80:
            shown += out[:, 4].astype(int).tolist()
    assert shown and set(shown) == {2}, shown


def test_relink_never_hands_a_lost_track_to_a_target_seen_while_it_was_still_seen() -> None:
    """A newcomer first seen 8 px from the target, in the frame of the target's last detection,
    is another object, however well the target's model explains both of its sightings: at 5 Hz
    it is confirmed under its own id the frame the target is missed."""
    tr = JPTrack()
    for frame in range(12):
        tr.update(np.array([[100.0 + 5 * frame, 200, 110 + 5 * frame, 210, 0.9]]), frame / 5)
    tr.update(np.array([[160.0, 200, 170, 210, 0.9], [160.0, 208, 170, 218, 0.9]]), 12 / 5)
    out = tr.update(np.array([[165.0, 225, 175, 235, 0.9]]), 13 / 5)
    assert out[:, 4].astype(int).tolist() == [2]


def ids_after_return_at_size(config: JPTrackConfig, side: float) -> list[int]:
    """Ids shown for a 10 px target seen 20 frames, hidden 1.5 s, then back on its path at
    ``side`` px (its centre where it would be)."""
    tr = JPTrack(config)
    shown = []
    for frame in range(20 + 45 + 5):
        cx, half = 105 + 5.0 * frame, (side if frame >= 65 else 10.0) / 2
        seen = not 20 <= frame < 65
        out = tr.update(np.array([[cx - half, 205 - half, cx + half, 205 + half, 0.9]]) if seen else None, frame / 30)
        if frame >= 65:
            shown += out[:, 4].astype(int).tolist()
    return shown


def test_pmr_takes_back_only_a_detection_of_the_lost_tracks_size() -> None:
    """Stage 3 alone (relink off): the target back at 15 px (x1.5) keeps its id from its first
    frame; at 30 px (x3) it is another object to PMR and starts a new id, unless the gate is off."""
    stage3 = JPTrackConfig(pmr_relink=False)
    assert ids_after_return_at_size(stage3, 10.0) == [1] * 5
    assert ids_after_return_at_size(stage3, 15.0) == [1] * 5
    assert ids_after_return_at_size(stage3, 30.0) == [2] * 4
    assert ids_after_return_at_size(JPTrackConfig(pmr_relink=False, pmr_size_ratio=float("inf")), 30.0) == [1] * 5


@pytest.mark.parametrize("ratio", [0.99, float("nan"), -1.0])
def test_a_size_ratio_below_one_is_refused(ratio: float) -> None:
    with pytest.raises(ValueError, match="pmr_size_ratio must be >= 1"):
        JPTrackConfig(pmr_size_ratio=ratio)


@pytest.mark.parametrize("growth", [1.0, -0.2])
def test_a_lost_box_coasts_at_its_last_size(growth: float) -> None:
    """A target whose box grew (or shrank) every frame is lost: its box keeps the size it had,
    where the size rate alone would have swollen or collapsed it over two seconds."""
    tr = JPTrack()
    for frame in range(30):
        side = 20.0 + growth * frame
        tr.update(np.array([[100.0, 100.0, 100.0 + side, 100.0 + side, 0.9]]), frame / 30)
    (track,) = tr.tracks
    size_at_loss = None
    for frame in range(30, 90):
        tr.update(None, frame / 30)
        if size_at_loss is None:
            size_at_loss = track.box_xyxy[2] - track.box_xyxy[0]
    assert track.kf.state[6:8].tolist() == [0.0, 0.0]
    assert track.box_xyxy[2] - track.box_xyxy[0] == pytest.approx(size_at_loss)
    assert abs(size_at_loss - (20.0 + growth * 30)) < 3.0


def relinked_id(config: JPTrackConfig, return_y: float, return_side: float) -> list[int]:
    """Ids shown for a target back 1.5 s after two were lost together, 100 px ahead of both
    paths (beyond stage 3's gate, within both recovery radii): a 10 px one on y = 205 (id 1) and
    a 30 px one on y = 275 (id 2)."""
    tr = JPTrack(config)
    shown = []
    for frame in range(70):
        x = 100 + 5.0 * frame
        if frame < 20:
            dets = np.array([[x, 200, x + 10, 210, 0.9], [x, 260, x + 30, 290, 0.9]])
        elif frame < 65:
            dets = None
        else:
            cx, half = x + 105, return_side / 2
            dets = np.array([[cx - half, return_y - half, cx + half, return_y + half, 0.9]])
        out = tr.update(dets, frame / 30)
        if frame >= 65:
            shown += out[:, 4].astype(int).tolist()
    return shown


@pytest.mark.parametrize("return_y", [215.0, 225.0])
def test_relink_tells_two_lost_tracks_apart_by_the_size_of_what_came_back(return_y: float) -> None:
    """Nearer the small target's path, a 30 px return is the large one's; ranked by position
    alone it went to the small one."""
    assert relinked_id(JPTrackConfig(relink_size_std=float("inf")), return_y, 30.0) == [1] * 4
    assert relinked_id(JPTrackConfig(), return_y, 30.0) == [2] * 4
    assert relinked_id(JPTrackConfig(), return_y, 10.0) == [1] * 4


@pytest.mark.parametrize("std", [0.0, float("nan"), -0.3])
def test_a_relink_size_std_that_is_not_positive_is_refused(std: float) -> None:
    with pytest.raises(ValueError, match="relink_size_std must be > 0"):
        JPTrackConfig(relink_size_std=std)


def reattachments_after_gap(gap: int, offset: float) -> list[tuple[int, int, str]]:
    """``(frame, id, how)`` of every lost-track return for a target seen 20 frames, hidden
    ``gap`` frames, then back ``offset`` px off its straight path."""
    tr = JPTrack()
    tr.reattachments = []
    for frame in range(20 + gap + 5):
        x, y = 100 + 5.0 * frame, 200 + (offset if frame >= 20 + gap else 0.0)
        seen = not 20 <= frame < 20 + gap
        tr.update(np.array([[x, y, x + 10, y + 10, 0.9]]) if seen else None, frame / 30)
    return [(round(t * 30), track_id, how) for t, track_id, how in tr.reattachments]


def test_each_way_back_of_a_lost_track_is_recorded_when_asked() -> None:
    assert reattachments_after_gap(10, 0.0) == [(30, 1, REATTACHED_FIRST_STAGE)]  # within the 1 s window
    assert reattachments_after_gap(45, 0.0) == [(65, 1, REATTACHED_RECOVER)]  # PMR, beyond it
    assert reattachments_after_gap(45, 120.0) == [(66, 1, REATTACHED_RELINK)]  # at its second sighting
    silent = JPTrack()
    silent.update(np.array([[0.0, 0.0, 10.0, 10.0, 0.9]]), 0.0)
    assert silent.reattachments is None  # recorded only when asked


def test_pmr_leaves_a_just_lost_tracks_outlier_to_it_rather_than_to_an_old_lost_track() -> None:
    """Target 1 is seen 20 frames and then lost; target 2, tracked throughout, is boxed once 24 px
    off its path, where target 1 would now be. That detection is in reach of target 2's track,
    lost this frame: PMR leaves it, and no frame shows target 1's id on target 2. With the
    deferral off, the old identity surfaces for that frame (two identity switches)."""

    def shown_ids(config: JPTrackConfig) -> list[list[int]]:
        tr = JPTrack(config)
        shown = []
        for frame in range(64):
            rows = [[100 + 3.0 * frame - 5, 195, 100 + 3.0 * frame + 5, 205, 0.9]] if frame < 20 else []
            y = 200 if frame == 52 else 224
            rows.append([251, y - 5, 261, y + 5, 0.9])
            shown.append(tr.update(np.array(rows), frame / 30)[:, 4].astype(int).tolist())
        return shown

    deferred = shown_ids(JPTrackConfig())
    assert deferred[52] == [] and all(ids == [2] for ids in deferred[21:52] + deferred[53:])
    taken = shown_ids(JPTrackConfig(pmr_defer_to_just_lost=False))
    assert taken[52] == [1] and taken[53:] == deferred[53:]


def test_stage_one_leaves_a_tracked_target_its_own_low_scored_detection() -> None:
    """Target 1 (20 px, moving right) is tracked throughout; target 2, 34 px to its right, is seen
    10 frames, then missed for 1.2 s (past the first stage's window: only PMR may bring it back),
    and comes back with a high score on the frame where target 1 is boxed with a low score, on its
    path. The first stage must not hand target 2's detection to target 1's track (an identity
    switch on both targets): with the deferral, target 1's track takes its own low-scored box in
    stage 2 and target 2's detection goes to target 2's lost track."""

    def boxes_by_id(config: JPTrackConfig) -> dict[int, list[float]]:
        tr = JPTrack(config)
        out: dict[int, list[float]] = {}
        for frame in range(50):
            x = 100 + 1.0 * frame
            rows = [[x - 10, 190, x + 10, 210, 0.2 if frame == 46 else 0.9]]
            if frame < 10 or frame >= 46:
                rows.append([x + 24, 190, x + 44, 210, 0.9])
            shown = tr.update(np.array(rows), frame / 30)
            out = {int(row[4]): row[:4].tolist() for row in shown} if frame == 46 else out
        return out

    deferred = boxes_by_id(JPTrackConfig())
    assert deferred[1] == pytest.approx([136, 190, 156, 210], abs=3), "target 1's track on target 1"
    assert deferred[2] == pytest.approx([170, 190, 190, 210], abs=3), "target 2's id back on target 2"
    taken = boxes_by_id(JPTrackConfig(defer_to_own_low=False))
    assert taken[1][0] > 150, "without it, target 1's track jumps toward target 2 (its box is filtered)"
