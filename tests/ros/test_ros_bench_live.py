"""gldt_ros.bench.live: what it reports of a run's tracks against the bag's ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gldt_ros.bench.live import LiveRun, Tracking, report, tracking_scores


def rows(frames: int, track_id: int, cls: int = 1, shift: float = 0.0) -> np.ndarray:
    """MOT rows of one box moving right, ``frame, id, x, y, w, h, conf, class, -1, -1``."""
    return np.array(
        [(f, track_id, 10.0 + 5 * f + shift, 20.0, 12.0, 8.0, 1, cls, -1, -1) for f in range(1, frames + 1)]
    )


def test_tracks_are_scored_against_the_drones_of_the_ground_truth_with_birds_as_distractors() -> None:
    drone, bird = rows(20, 1), rows(20, 2, cls=2, shift=300.0)
    truth = np.vstack([drone, bird])
    assert tracking_scores(truth, drone) == Tracking(100.0, 100.0)
    half = tracking_scores(truth, drone[:10])  # a run that answered the last 10 frames by prediction
    assert half is not None and half.mota == pytest.approx(50.0) and half.idf1 == pytest.approx(100 * 10 / 15)
    bird_tracked = np.vstack([drone, rows(20, 7, shift=300.0)])  # the tracker follows the bird too
    assert tracking_scores(truth, bird_tracked) == Tracking(100.0, 100.0), "a bird is a distractor, as in gldt run"
    assert tracking_scores(None, drone) is None, "a bag without ground truth is not scored"
    assert tracking_scores(bird, drone) is None, "nor one without a drone in it"


def test_the_report_gives_each_bags_worst_tracking_beside_the_offline_run() -> None:
    def run(mota: float) -> LiveRun:
        return LiveRun("bag", 100, 33.3, 100, 10, 4, 0, 10.0, 80.0, 90.0, 0, Tracking(mota, 90.0))

    text = report([run(95.0), run(91.5)], {"bag": Tracking(98.7, 99.3)})
    assert "10 (4)" in text, "frames by prediction, of them at the deadline"
    assert "- bag: 91.5 / 90.0 live, 98.7 / 99.3 offline" in text


@pytest.mark.parametrize("rate", [1.0, 2.0, 0.5])
@pytest.mark.parametrize("first_answered", [0, 2])
def test_latency_counts_from_when_the_player_sent_the_frame_at_any_rate(
    monkeypatch, rate: float, first_answered: int
) -> None:
    """The player stamps frame k with the replay's start plus the bag's time since its first
    frame, and sends it after that time divided by the rate: answers 10 ms after sending are 10 ms
    late, whatever the rate, and whether or not the first frames were answered (counted from the
    stamp alone they would be early at rate 2). A frame answered twice is counted, once."""
    from types import SimpleNamespace

    from gldt_msgs.msg import TrackArray
    from rclpy.serialization import serialize_message

    from gldt_ros.bench import live

    start, period = 1_700_000_000 * 10**9, 33_333_333
    frames = live.BagFrames(20, period / 1e6, [k * period + (k % 3) * 1000 for k in range(20)])
    messages = []
    for k in range(first_answered, 20):
        array = TrackArray(frame_index=k, source=TrackArray.SOURCE_LATE if k == 3 else TrackArray.SOURCE_GLOBAL)
        array.header.stamp.sec, array.header.stamp.nanosec = divmod(start + frames.since_first_ns[k], 10**9)
        sent = start + frames.since_first_ns[k] / rate
        message = SimpleNamespace(topic="/gldt/tracks", data=serialize_message(array), log_time_ns=sent + 10**7)
        messages += [message, message] if k == 5 else [message]
    monkeypatch.setattr(live, "read_mcap", lambda _path: iter(messages))
    judged = live.judge_recording(Path("unused.mcap"), frames, rate)
    assert (judged.answered, judged.predicted, judged.late) == (20 - first_answered, 1, 1)
    assert judged.answered_twice == 1
    np.testing.assert_allclose(judged.latencies_ms, 10.0, atol=1e-3)
