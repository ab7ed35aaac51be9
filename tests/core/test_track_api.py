"""The tracker contract other modules code against, and its refusal of bad input."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_core.track import ByteTrack, JPTrack, JPTrackConfig, Track, TrackState

TRACKERS = [ByteTrack, JPTrack, lambda: JPTrack(JPTrackConfig(use_pmr=False))]
IDS = ["bytetrack", "jptrack", "jcma-only"]


def boxes_at(k: int, n: int = 3) -> np.ndarray:
    """n well separated targets moving right at 2 px/frame, score 0.9."""
    rows = []
    for i in range(n):
        x, y = 100.0 + 200.0 * i + 2.0 * k, 100.0 + 150.0 * i
        rows.append([x, y, x + 30.0, y + 20.0, 0.9])
    return np.asarray(rows)


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_update_returns_boxes_ids_and_scores(make) -> None:
    tracker = make()
    out = None
    for k in range(5):
        out = tracker.update(boxes_at(k), k / 30.0)
        assert out.ndim == 2 and out.shape[1] == 6
    assert out is not None and len(out) == 3
    assert sorted(out[:, 4].astype(int).tolist()) == [1, 2, 3]
    np.testing.assert_allclose(out[:, 5], 0.9)
    # Reported boxes sit on the detections (filtered, so within a pixel).
    order = np.argsort(out[:, 0])
    np.testing.assert_allclose(out[order, :4], boxes_at(4)[:, :4], atol=1.0)


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_tracks_expose_state_velocity_and_covariance(make) -> None:
    tracker = make()
    for k in range(30):
        tracker.update(boxes_at(k), k / 30.0)
    tracks = tracker.tracks
    assert len(tracks) == 3 and all(isinstance(tr, Track) for tr in tracks)
    for tr in tracks:
        assert tr.state is TrackState.CONFIRMED
        assert isinstance(tr.track_id, int)
        assert tr.box_xyxy.shape == (4,)
        assert tr.covariance.shape == (8, 8)
        np.testing.assert_allclose(tr.velocity_px_s, [60.0, 0.0], atol=3.0)  # 2 px/frame at 30 Hz
        assert tr.age_s == pytest.approx(29 / 30.0)
        assert tr.hits == 30 and tr.frames_since_update == 0
        assert tr.last_update_t == pytest.approx(29 / 30.0)
        assert 0.0 <= tr.score <= 1.0


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_empty_frames_keep_tracks_and_mark_them_lost(make) -> None:
    tracker = make()
    for k in range(10):
        tracker.update(boxes_at(k), k / 30.0)
    out = tracker.update(np.zeros((0, 5)), 10 / 30.0)
    assert out.shape == (0, 6)
    out = tracker.update(None, 11 / 30.0)
    assert out.shape == (0, 6)
    assert all(tr.state is TrackState.LOST for tr in tracker.tracks)
    assert all(tr.frames_since_update == 2 for tr in tracker.tracks)
    out = tracker.update(boxes_at(12), 12 / 30.0)
    assert sorted(out[:, 4].astype(int).tolist()) == [1, 2, 3]


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_predict_does_not_change_state_and_extrapolates(make) -> None:
    tracker = make()
    for k in range(20):
        tracker.update(boxes_at(k), k / 30.0)
    before = [(tr.kf.mean.copy(), tr.kf.covariance.copy(), tr.state) for tr in tracker.tracks]
    predicted = tracker.predict(25 / 30.0)
    after = [(tr.kf.mean, tr.kf.covariance, tr.state) for tr in tracker.tracks]
    for (m0, c0, s0), (m1, c1, s1) in zip(before, after):
        np.testing.assert_array_equal(m0, m1)
        np.testing.assert_array_equal(c0, c1)
        assert s0 is s1
    assert predicted.shape == (3, 5)
    order = np.argsort(predicted[:, 4])
    np.testing.assert_allclose(predicted[order, :4], boxes_at(25)[:, :4], atol=1.5)
    # The next update still works from the unchanged state.
    out = tracker.update(boxes_at(20), 20 / 30.0)
    assert len(out) == 3


def test_ids_are_per_instance_and_reset_restarts_them() -> None:
    a, b = JPTrack(), JPTrack()
    a.update(boxes_at(0, 2), 0.0)
    out_b = b.update(boxes_at(0, 1), 0.0)
    assert out_b[:, 4].tolist() == [1.0]
    out_a = a.update(boxes_at(1, 3), 1 / 30.0)
    assert 1.0 in out_a[:, 4] and 2.0 in out_a[:, 4]
    a.reset()
    assert a.tracks == []
    out = a.update(boxes_at(0, 1), 0.0)  # time may restart after a reset
    assert out[:, 4].tolist() == [1.0]


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
@pytest.mark.parametrize(
    "row, field",
    [
        ([np.nan, 0, 10, 10, 0.9], "x1"),
        ([0, 0, 10, np.inf, 0.9], "y2"),
        ([10, 0, 5, 10, 0.9], "x2"),
        ([0, 10, 10, 4, 0.9], "y2"),
        ([0, 0, 10, 10, 1.5], "score"),
        ([0, 0, 10, 10, -0.1], "score"),
    ],
)
def test_bad_detections_name_frame_and_field(make, row, field) -> None:
    tracker = make()
    tracker.update(boxes_at(0), 0.0, frame=1)
    dets = np.vstack([boxes_at(1), row])
    with pytest.raises(ValueError, match=rf"frame 2: detection 3 field {field}"):
        tracker.update(dets, 1 / 30.0, frame=2)


@pytest.mark.parametrize("make", TRACKERS, ids=IDS)
def test_time_must_increase(make) -> None:
    tracker = make()
    tracker.update(boxes_at(0), 1.0, frame=5)
    with pytest.raises(ValueError, match="frame 5: field t: time repeated"):
        tracker.update(boxes_at(1), 1.0, frame=5)
    with pytest.raises(ValueError, match="frame 4: field t: time went backwards"):
        tracker.update(boxes_at(1), 0.5, frame=4)
    with pytest.raises(ValueError, match="NaN or infinite"):
        tracker.update(boxes_at(1), float("nan"))
    # A rejected frame changes nothing: the next valid frame continues the same tracks.
    out = tracker.update(boxes_at(1), 1.0 + 1 / 30.0)
    assert len(tracker.tracks) == 3 and out.shape[1] == 6


def test_wrong_shape_is_refused() -> None:
    with pytest.raises(ValueError, match=r"\(N, 5\)"):
        JPTrack().update(np.zeros((2, 4)), 0.0)


def test_assignment_solver_is_scipys_without_importing_scipy_optimize() -> None:
    """The trackers' solver (loaded from SciPy's extension file, for start-up time) gives exactly
    SciPy's assignment, and importing it does not pull in scipy.optimize."""
    import subprocess
    import sys

    from scipy.optimize import linear_sum_assignment as reference

    from gldt_core.track.assignment import SOURCE, linear_sum_assignment

    assert SOURCE == "extension"
    rng = np.random.default_rng(0)
    for _ in range(100):
        cost = rng.random((int(rng.integers(1, 9)), int(rng.integers(1, 9))))
        cost[rng.random(cost.shape) < 0.3] = 1e6  # forbidden pairs, as the trackers pass them
        for ours, theirs in zip(linear_sum_assignment(cost), reference(cost)):
            np.testing.assert_array_equal(ours, theirs)
    probe = "import sys, gldt_core.track; print('scipy.optimize' in sys.modules)"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "False"
