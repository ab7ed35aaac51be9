"""gldt_ros.bench.hops: the per-stage medians it prints come from the right pairs of arrivals."""

from __future__ import annotations

import pytest

from gldt_ros.bench.hops import stage_medians


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


def test_slowest_frames_rank_complete_frames_by_total_and_split_them_by_stage() -> None:
    from gldt_ros.bench.hops import slowest_frames

    arrivals = {
        1: {"a": 0.0, "b": 0.010, "c": 0.040},  # 40 ms
        2: {"a": 1.0, "b": 1.030, "c": 1.150},  # 150 ms: the stall, in b -> c
        3: {"a": 2.0, "b": 2.020, "c": 2.060},  # 60 ms
        4: {"a": 3.0, "b": 9.000},  # never answered: not a frame the replay waited on
    }
    ranked = slowest_frames(arrivals, ("a", "b", "c"), 2)
    assert [stamp for stamp, _, _ in ranked] == [2, 3]
    stamp, total, stages = ranked[0]
    assert total == pytest.approx(0.150) and stages == pytest.approx([0.030, 0.120])
    assert slowest_frames(arrivals, ("a", "b", "c"), 0) == []
