"""gldt_ros.bench.graph's "rate the core sustains": the replay rate its latency goal is judged at."""

from __future__ import annotations

import pytest

pytest.importorskip("rclpy", reason="gldt_ros comes with the ROS workspace that `make test` builds")

from gldt_ros.bench.graph import stamp_rate, sustained_rate  # noqa: E402


def test_the_bag_rate_comes_from_the_camera_stamps() -> None:
    assert stamp_rate([10.0 + i / 30 for i in range(150)]) == pytest.approx(30.0)
    assert stamp_rate([0.0, 0.1, 0.2, 0.3]) == pytest.approx(10.0)


@pytest.mark.parametrize("stamps", [[], [5.0], [1.0, 1.0]])
def test_too_few_stamps_to_tell_fall_back_to_30_fps(stamps: list[float]) -> None:
    assert stamp_rate(stamps) == 30.0


def test_a_core_faster_than_the_camera_is_judged_at_the_cameras_rate() -> None:
    assert sustained_rate(0.020, 30.0) == 1.0


def test_a_slower_core_is_judged_at_its_own_share_of_the_cameras_rate() -> None:
    # 60 ms per frame keeps up with 16.7 fps: 0.556 of a 30 fps bag.
    assert sustained_rate(0.060, 30.0) == pytest.approx(1 / 1.8)


def test_overhead_is_the_median_of_back_to_back_pairs() -> None:
    from gldt_ros.bench.graph import paired_overhead

    # A slow minute (second pair) slows both halves alike: its ratio is as good as the others'.
    median, each = paired_overhead([0.030, 0.060, 0.031], [0.036, 0.069, 0.0341])
    assert each == pytest.approx([0.20, 0.15, 0.10])
    assert median == pytest.approx(0.15)
    assert paired_overhead([0.05, 0.05], [0.06, 0.07])[0] == pytest.approx(0.3)
    with pytest.raises(ValueError, match="as many offline as lockstep"):
        paired_overhead([0.05], [])
