"""jptrack_tracker answers frames in camera order: the global detector, the local detector and the
buffer's skip notices are three writers, and a notice for frame t+1 can reach the tracker before
the global detector's detections for frame t. Frames are answered in the order they were ticked,
and one whose detections never come is given up after ``input_order_timeout``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.context import Context  # noqa: E402


@pytest.fixture
def tracker() -> Iterator[Any]:
    from rclpy.parameter import Parameter

    from gldt_ros.nodes.jptrack_tracker import TrackerNode

    context = Context()
    rclpy.init(context=context)
    try:
        node: Any = TrackerNode(context=context, parameter_overrides=[Parameter("input_order_timeout", value=0.2)])
        node.published = []
        node.track_publisher.publish = node.published.append
        node.prediction_publisher.publish = lambda _message: None
        yield node
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def header(index: int) -> Any:
    from std_msgs.msg import Header

    stamped = Header(frame_id="camera")
    stamped.stamp.sec, stamped.stamp.nanosec = 1, index * 33_333_333
    return stamped


def tick(node: Any, index: int) -> None:
    from gldt_msgs.msg import FrameTick

    node.on_tick(FrameTick(header=header(index), frame_index=index, width=640, height=512))


def detections(index: int, mode: int) -> Any:
    from gldt_msgs.msg import Detection, DetectionArray

    found = [Detection(center_x=100.0 + index, center_y=200.0, width=20.0, height=12.0, score=0.9, class_id=1)]
    return DetectionArray(header=header(index), frame_index=index, mode=mode, detections=found if mode != 2 else [])


def test_a_notice_that_overtakes_the_frame_before_it_waits_for_it(tracker: Any) -> None:
    from gldt_msgs.msg import DetectionArray, TrackArray

    for index in range(3):
        tick(tracker, index)
    tracker.on_detections_arrived(detections(0, DetectionArray.MODE_GLOBAL))
    tracker.on_detections_arrived(detections(2, DetectionArray.MODE_SKIPPED))  # overtakes frame 1
    assert [int(a.frame_index) for a in tracker.published] == [0], "frame 2 must wait for frame 1"
    tracker.on_detections_arrived(detections(1, DetectionArray.MODE_GLOBAL))
    assert [int(a.frame_index) for a in tracker.published] == [0, 1, 2]
    assert [int(a.source) for a in tracker.published] == [
        TrackArray.SOURCE_GLOBAL,
        TrackArray.SOURCE_GLOBAL,
        TrackArray.SOURCE_PREDICTED,
    ]
    assert tracker.frames_dropped == 0, "frame 1's detections were not taken for late ones"


def test_a_frame_whose_detections_never_come_is_given_up(tracker: Any) -> None:
    from gldt_msgs.msg import DetectionArray

    for index in range(2):
        tick(tracker, index)
    tracker.on_detections_arrived(detections(1, DetectionArray.MODE_LOCAL))
    assert tracker.published == []
    time.sleep(0.3)  # past input_order_timeout
    tracker._answer_in_order()
    assert [int(a.frame_index) for a in tracker.published] == [1]
