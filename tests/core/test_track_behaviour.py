"""What the trackers are for: identities through occlusion, crossings, frame rates and drops."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track import ByteTrack, JPTrack, JPTrackConfig, TrackState


def run(
    tracker,
    fps: float,
    seconds: float,
    gap: tuple[float, float] | None = None,
    velocity=(60.0, 20.0),
    start=(200.0, 300.0),
    size=(24.0, 16.0),
    seed: int = 0,
    drop_every: int = 0,
) -> list[tuple[float, list[int]]]:
    """One target in constant-velocity flight (px/s) observed at ``fps`` with 1 px jitter; no
    detections during ``gap`` (seconds). Returns (t, reported ids) per frame."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(int(round(seconds * fps))):
        t = k / fps
        if drop_every and k % drop_every == drop_every - 1:
            continue  # the frame never arrives
        centre = np.asarray(start) + np.asarray(velocity) * t + rng.normal(0, 1.0, 2)
        if gap and gap[0] <= t < gap[1]:
            dets = np.zeros((0, 5))
        else:
            dets = np.array([[*(centre - np.asarray(size) / 2), *(centre + np.asarray(size) / 2), 0.9]])
        result = tracker.update(dets, t)
        out.append((t, result[:, 4].astype(int).tolist()))
    return out


def ids_after(history, t0: float) -> set[int]:
    return {i for t, ids in history if t >= t0 for i in ids}


def test_pmr_keeps_the_identity_through_a_two_second_occlusion() -> None:
    gap = (2.0, 4.0)
    full = run(JPTrack(), 30.0, 6.0, gap)
    jcma_only = run(JPTrack(JPTrackConfig(use_pmr=False)), 30.0, 6.0, gap)
    byte = run(ByteTrack(), 30.0, 6.0, gap)
    assert ids_after(full, 0.0) == {1}
    # Without PMR a lost track is forgotten after 1 s (ByteTrack's buffer): a new id appears.
    assert ids_after(jcma_only, 4.0) == {2}
    assert ids_after(byte, 4.0) == {2}


def test_recovered_state_then_confirmed() -> None:
    tracker = JPTrack()
    states = []
    rng = np.random.default_rng(1)
    for k in range(150):
        t = k / 30.0
        c = np.array([100.0 + 45.0 * t, 200.0]) + rng.normal(0, 0.5, 2)
        dets = np.zeros((0, 5)) if 1.0 <= t < 3.0 else np.array([[c[0] - 10, c[1] - 8, c[0] + 10, c[1] + 8, 0.9]])
        tracker.update(dets, t)
        states.append(tracker.tracks[0].state)
    first_back = int(3.0 * 30)
    assert states[first_back - 1] is TrackState.LOST
    assert states[first_back] is TrackState.RECOVERED
    assert states[first_back + 1] is TrackState.CONFIRMED
    assert len(tracker.tracks) == 1 and tracker.tracks[0].track_id == 1


@pytest.mark.parametrize("fps", [15.0, 30.0, 60.0])
def test_frame_rate_does_not_change_the_outcome(fps: float) -> None:
    tracker = JPTrack()
    history = run(tracker, fps, 5.0, gap=(1.5, 3.0))
    assert ids_after(history, 0.0) == {1}
    np.testing.assert_allclose(tracker.tracks[0].velocity_px_s, [60.0, 20.0], atol=4.0)


def test_dropped_frames_are_just_longer_time_steps() -> None:
    tracker = JPTrack()
    history = run(tracker, 30.0, 4.0, drop_every=3, velocity=(300.0, 0.0), size=(12.0, 12.0))
    assert ids_after(history, 0.0) == {1}
    np.testing.assert_allclose(tracker.tracks[0].velocity_px_s, [300.0, 0.0], atol=15.0)


def test_crossing_small_fast_targets_keep_their_identities() -> None:
    """Two 10 px drones cross at 240 px/s (8 px per frame, no IoU between frames)."""
    tracker = JPTrack()
    rng = np.random.default_rng(2)
    labels = {}
    for k in range(90):
        t = k / 30.0
        a = np.array([100.0 + 240.0 * t, 300.0 + 60.0 * t])
        b = np.array([100.0 + 240.0 * t, 480.0 - 60.0 * t])
        dets = []
        for c in (a, b):
            c = c + rng.normal(0, 0.7, 2)
            dets.append([c[0] - 5, c[1] - 5, c[0] + 5, c[1] + 5, 0.9])
        out = tracker.update(np.asarray(dets), t)
        for row in out:
            cy = (row[1] + row[3]) / 2
            truth = "a" if abs(cy - a[1]) < abs(cy - b[1]) else "b"
            if abs(a[1] - b[1]) > 20:  # skip the frames where they overlap
                labels.setdefault(truth, set()).add(int(row[4]))
    assert labels["a"] == {1} and labels["b"] == {2}


def test_low_score_detections_continue_tracks_but_never_start_them() -> None:
    tracker = JPTrack()
    for k in range(10):
        tracker.update(np.array([[100.0 + k, 100.0, 120.0 + k, 115.0, 0.9]]), k / 30.0)
    out = tracker.update(np.array([[110.0, 100.0, 130.0, 115.0, 0.3], [500, 500, 520, 515, 0.3]]), 10 / 30.0)
    assert out[:, 4].tolist() == [1.0]
    for k in range(11, 20):
        tracker.update(np.array([[500.0, 500.0, 520.0, 515.0, 0.3]]), k / 30.0)
    assert [tr.track_id for tr in tracker.tracks] == [1]
