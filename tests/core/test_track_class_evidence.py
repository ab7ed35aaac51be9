"""Track-level class evidence: a track is what most of its detections said, not what one frame said."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track.class_evidence import UNKNOWN_CLASS_ID, ClassEvidence, drone_track_rows, drone_tracks

DRONE, BIRD = np.array([[0.9, 0.08, 0.02]]), np.array([[0.2, 0.75, 0.05]])


def track(track_id: int, x: float = 100.0) -> np.ndarray:
    return np.array([[x, 100, x + 20, 115, track_id, 0.8]])


def detection(x: float = 100.0) -> np.ndarray:
    return np.array([[x + 1, 100, x + 21, 115, 0.8]])


def test_one_drone_frame_does_not_make_a_bird_track_a_drone() -> None:
    evidence = ClassEvidence()
    labels = evidence.update(track(1), detection(), DRONE)
    assert labels[0].tolist() == [1, pytest.approx(0.9)]
    for _ in range(4):
        labels = evidence.update(track(1), detection(), BIRD)
    assert labels[0, 0] == 2 and labels[0, 1] == pytest.approx((0.08 + 4 * 0.75) / 5)


def test_tracks_without_a_matching_detection_keep_their_evidence_or_stay_unknown() -> None:
    evidence = ClassEvidence()
    evidence.update(track(1), detection(), BIRD)
    labels = evidence.update(np.vstack([track(1), track(2, 400)]), detection(600), DRONE)
    assert labels[0, 0] == 2  # its detection is elsewhere: nothing added
    assert labels[1].tolist() == [UNKNOWN_CLASS_ID, 0.0]


def test_each_detection_feeds_one_track_the_one_it_overlaps_most() -> None:
    evidence = ClassEvidence()
    tracks = np.vstack([track(1, 100), track(2, 104)])
    labels = evidence.update(tracks, detection(103), DRONE)
    assert sorted(labels[:, 0].tolist()) == [UNKNOWN_CLASS_ID, 1]
    assert labels[1, 0] == 1  # track 2 (x 104) overlaps the detection (x 104) most


def test_memory_is_bounded_by_forgetting_tracks_no_longer_reported() -> None:
    evidence = ClassEvidence(forget_after_frames=5)
    for i in range(50):
        evidence.update(track(i, 10.0 * i), detection(10.0 * i), DRONE)
    assert len(evidence) <= 6
    with pytest.raises(ValueError, match="probability rows"):
        evidence.update(track(1), detection(), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="forget_after_frames"):
        ClassEvidence(0)


def test_a_tracks_probabilities_are_the_mean_of_its_detections_and_drop_with_it() -> None:
    evidence = ClassEvidence(forget_after_frames=2)
    assert evidence.probabilities(1) is None
    evidence.update(track(1), detection(), DRONE)
    evidence.update(track(1), detection(), BIRD)
    mean = evidence.probabilities(1)
    assert mean is not None
    np.testing.assert_allclose(mean, (DRONE[0] + BIRD[0]) / 2)
    assert evidence.label(1) == (1, pytest.approx(0.55))
    for _ in range(3):
        evidence.update(track(2, 400), detection(400), DRONE)
    assert evidence.probabilities(1) is None  # forgotten: no longer reported


def test_drone_tracks_lists_the_tracks_published_as_drones_most_rows_first() -> None:
    evidence = ClassEvidence()
    evidence.update(track(7), detection(), DRONE)
    rows = np.array(
        [
            # frame, id, x, y, w, h, score, class, -1, -1
            [1, 3, 0, 0, 5, 5, 0.6, -1, -1, -1],  # unknown: published as a drone
            [1, 7, 100, 100, 20, 15, 0.6, 1, -1, -1],
            [2, 7, 100, 100, 20, 15, 0.6, 1, -1, -1],
            [2, 9, 50, 50, 20, 15, 0.6, 2, -1, -1],  # a bird: not listed
        ]
    )
    listed = drone_tracks(rows, evidence.probabilities)
    assert [(track_id, count) for track_id, count, _ in listed] == [(7, 2), (3, 1)]
    np.testing.assert_allclose(listed[0][2], DRONE[0])
    assert listed[1][2] is None
    assert drone_track_rows(rows) == 3
    assert drone_tracks(np.zeros((0, 10)), evidence.probabilities) == []
