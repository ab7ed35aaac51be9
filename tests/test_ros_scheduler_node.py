"""mode_scheduler in lockstep: a LOCAL frame whose detections never come does not stall the graph."""

from __future__ import annotations

import time

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from gldt_msgs.msg import SchedulerState, Track, TrackPredictions  # noqa: E402

from gldt_ros.nodes import mode_scheduler  # noqa: E402


def predictions(frame: int) -> TrackPredictions:
    """One confirmed track in mid-image, for frame ``frame`` of a 30 Hz 1920x1080 stream."""
    message = TrackPredictions(frame_index=frame, width=1920, height=1080)
    message.header.stamp.sec, message.header.stamp.nanosec = divmod((frame + 1) * 33_333_333, 1_000_000_000)
    message.tracks = [Track(id=1, state=Track.STATE_CONFIRMED, center_x=960.0, center_y=540.0, width=20.0, height=12.0)]
    return message


class Published:
    """Stands in for the decision publisher: keeps what the node decided."""

    def __init__(self) -> None:
        self.decisions: list[SchedulerState] = []

    def publish(self, message: SchedulerState) -> None:
        self.decisions.append(message)


def test_after_a_report_timeout_only_the_newest_queued_frame_is_planned() -> None:
    rclpy.init()
    try:
        node = mode_scheduler.create_node(
            cli_args=["--ros-args", "-p", "lockstep:=true", "-p", "global_frames:=1", "-p", "report_timeout:=0.2"]
        )
        published = Published()
        node.state_publisher = published
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
        node.destroy_node()
    finally:
        rclpy.shutdown()
