"""gldt_ros.bench_hops: the per-stage medians it prints come from the right pairs of arrivals."""

from __future__ import annotations

import pytest

from gldt_ros.bench_hops import stage_medians


def test_stage_medians_use_only_frames_that_reached_every_topic() -> None:
    arrivals = {
        1: {"a": 0.0, "b": 0.010, "c": 0.040},
        2: {"a": 1.0, "b": 1.030, "c": 1.050},
        3: {"a": 2.0, "b": 2.020, "c": 2.060},
        4: {"a": 3.0, "b": 3.900},  # never answered: must not pull the a -> b median up
    }
    stages = stage_medians(arrivals, ("a", "b", "c"))
    assert [(first, second) for first, second, _ in stages] == [("a", "b"), ("b", "c")]
    assert stages[0][2] == pytest.approx(0.020) and stages[1][2] == pytest.approx(0.030)
    assert stage_medians({4: arrivals[4]}, ("a", "b", "c")) == []
