"""gldt_ros.bench.live: what it reports of a run's tracks against the bag's ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from gldt_ros.bench.live import LiveRun, Tracking, report, tracking_scores


def rows(frames: int, track_id: int, cls: int = 1, shift: float = 0.0) -> np.ndarray:
    """MOT rows of one box moving right, ``frame, id, x, y, w, h, conf, class, -1, -1``."""
    return np.array(
        [(f, track_id, 10.0 + 5 * f + shift, 20.0, 12.0, 8.0, 1, cls, -1, -1) for f in range(1, frames + 1)]
    )


def test_tracks_are_scored_against_the_drones_of_the_ground_truth() -> None:
    drone, bird = rows(20, 1), rows(20, 2, cls=2, shift=300.0)
    truth = np.vstack([drone, bird])
    assert tracking_scores(truth, drone) == Tracking(100.0, 100.0)
    half = tracking_scores(truth, drone[:10])  # a run that answered the last 10 frames by prediction
    assert half is not None and half.mota == pytest.approx(50.0) and half.idf1 == pytest.approx(100 * 10 / 15)
    assert tracking_scores(None, drone) is None, "a bag without ground truth is not scored"
    assert tracking_scores(bird, drone) is None, "nor one without a drone in it"


def test_the_report_gives_each_bags_worst_tracking_beside_the_offline_run() -> None:
    def run(mota: float) -> LiveRun:
        return LiveRun("bag", 100, 33.3, 100, 10, 4, 10.0, 80.0, 90.0, 0, Tracking(mota, 90.0))

    text = report([run(95.0), run(91.5)], {"bag": Tracking(98.7, 99.3)})
    assert "10 (4)" in text, "frames by prediction, of them at the deadline"
    assert "- bag: 91.5 / 90.0 live, 98.7 / 99.3 offline" in text
