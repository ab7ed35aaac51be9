"""mode_scheduler in lockstep: a LOCAL frame whose detections never come does not stall the graph."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any, cast

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_msgs.msg import SchedulerState, Track, TrackPredictions  # noqa: E402

from gldt_ros.nodes import mode_scheduler  # noqa: E402


def predictions(frame: int, last_tracked: int | None = None, index: int | None = None) -> TrackPredictions:
    """One confirmed track in mid-image, for frame ``frame`` of a 30 Hz 1920x1080 stream, from a
    tracker that tracked every frame before it unless ``last_tracked`` says otherwise (-1: none);
    ``index`` is the frame buffer's count when it differs from ``frame`` (a restarted buffer)."""
    last_tracked = frame - 1 if last_tracked is None else last_tracked
    message = TrackPredictions(frame_index=frame if index is None else index, width=1920, height=1080)
    message.header.stamp.sec, message.header.stamp.nanosec = divmod((frame + 1) * 33_333_333, 1_000_000_000)
    if last_tracked >= 0:  # else the zero stamp: nothing tracked
        message.last_tracked_stamp.sec, message.last_tracked_stamp.nanosec = divmod(
            (last_tracked + 1) * 33_333_333, 1_000_000_000
        )
    message.tracks = [Track(id=1, state=Track.STATE_CONFIRMED, center_x=960.0, center_y=540.0, width=20.0, height=12.0)]
    return message


class Published:
    """Stands in for the decision publisher: keeps what the node decided."""

    def __init__(self) -> None:
        self.decisions: list[SchedulerState] = []

    def publish(self, message: SchedulerState) -> None:
        self.decisions.append(message)


@pytest.fixture
def lockstep_scheduler() -> Iterator[Callable[[float], tuple[mode_scheduler.ModeSchedulerNode, Published]]]:
    """Makes lockstep schedulers (N_g = 1) with a given ``report_timeout`` whose decisions are
    kept instead of published; rclpy and the nodes are torn down after the test."""
    rclpy.init()
    nodes: list[mode_scheduler.ModeSchedulerNode] = []

    def make(report_timeout: float = 600.0) -> tuple[mode_scheduler.ModeSchedulerNode, Published]:
        node = mode_scheduler.create_node(
            cli_args=[
                "--ros-args",
                "-p",
                "lockstep:=true",
                "-p",
                "global_frames:=1",
                "-p",
                f"report_timeout:={report_timeout}",
            ]
        )
        nodes.append(node)
        published = Published()
        node.state_publisher = cast(Any, published)  # keeps the decisions instead of publishing them
        return node, published

    try:
        yield make
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.shutdown()


def test_after_a_report_timeout_only_the_newest_queued_frame_is_planned(lockstep_scheduler) -> None:
    node, published = lockstep_scheduler(report_timeout=0.2)
    node.on_predictions(predictions(0))  # GLOBAL (N_g = 1)
    node.on_predictions(predictions(1))  # LOCAL around the track: now waits for its detections
    assert [d.mode for d in published.decisions] == [SchedulerState.MODE_GLOBAL, SchedulerState.MODE_LOCAL]
    for frame in range(2, 6):  # the player moved on; the local detector never answers
        node.on_predictions(predictions(frame))
    assert len(published.decisions) == 2, "lockstep must wait for frame 1's detections"
    time.sleep(0.3)
    node._check_report_timeout()
    assert [int(d.frame_index) for d in published.decisions] == [0, 1, 5], (
        "frames 2-4 are stale (no longer buffered upstream): only the newest is planned"
    )


def test_a_frame_the_tracker_moved_past_untracked_is_not_waited_for(lockstep_scheduler) -> None:
    """Issue 9: a local detector killed mid-frame must not stall the restarted graph for
    ``report_timeout``: the tracker's next predictions say the frame was given up."""
    node, published = lockstep_scheduler()
    node.on_predictions(predictions(0))  # GLOBAL
    node.on_predictions(predictions(1))  # LOCAL: waits for its detections
    node.on_predictions(predictions(2, last_tracked=1))  # frame 1 was tracked: its report is on its way
    assert len(published.decisions) == 2, "the tracker has frame 1's detections, so the scheduler gets them too"
    node.on_predictions(predictions(3, last_tracked=0))  # the tracker never tracked frame 1: given up
    assert [int(d.frame_index) for d in published.decisions] == [0, 1, 2, 3]


def test_a_restarted_frame_buffer_counting_from_zero_does_not_stall_the_wait(lockstep_scheduler) -> None:
    """The buffer's frame index starts at 0 again after its restart; the stamps go on."""
    node, published = lockstep_scheduler()
    node.on_predictions(predictions(40))  # GLOBAL
    node.on_predictions(predictions(41))  # LOCAL: waits for its detections
    node.on_predictions(predictions(42, last_tracked=40, index=0))  # frame 41 never tracked
    assert [int(d.frame_index) for d in published.decisions] == [40, 41, 0]
