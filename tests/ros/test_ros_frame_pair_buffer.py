"""frame_pair_buffer on a GD stretch: it letterboxes a frame while its decision is pending, and it
leaves the previous image out of a pair once the global detector has answered that frame."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.context import Context  # noqa: E402

WIDTH, HEIGHT = 640, 512


@pytest.fixture
def buffer() -> Iterator[Any]:
    """A frame_pair_buffer whose pair and crop publishers record what they would send."""
    from gldt_ros.nodes.frame_pair_buffer import FramePairBuffer

    context = Context()
    rclpy.init(context=context)
    try:
        node: Any = FramePairBuffer(context=context)  # given the two lists below
        node.sent_pairs, node.sent_crops = [], []
        node.pairs.publish = node.sent_pairs.append
        node.crops.publish = node.sent_crops.append
        yield node
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def camera_image(index: int, stream: int = 0) -> Any:
    """A raw bgr8 frame, different for each index, stamped 30 Hz from ``stream`` seconds."""
    from std_msgs.msg import Header

    from gldt_ros.interface.convert import bgr_to_image

    frame = np.full((HEIGHT, WIDTH, 3), 180, np.uint8)
    frame[100 + index : 110 + index, 200:212] = 30
    header = Header(frame_id="camera")
    header.stamp.sec, header.stamp.nanosec = stream, index * 33_333_333
    return bgr_to_image(frame, header)


def decide(node: Any, index: int, image: Any, mode: int) -> None:
    from gldt_msgs.msg import Roi, SchedulerState
    from sensor_msgs.msg import RegionOfInterest

    rois = [Roi(region=RegionOfInterest(x_offset=100, y_offset=100, width=300, height=300))] if mode else []
    node.on_decision(SchedulerState(header=image.header, frame_index=index, mode=mode, rois=rois))


def answer(node: Any, index: int, image: Any, mode: int = 0) -> None:
    """What the global (mode 0) or local (1) detector publishes for frame ``index``."""
    from gldt_msgs.msg import DetectionArray

    node.on_detections(DetectionArray(header=image.header, frame_index=index, mode=mode))


def letterboxed(node: Any, image: Any) -> np.ndarray:
    from gldt_ros.interface.convert import image_to_bgr

    return node.global_input.prepare(image_to_bgr(image))[0]


def test_a_pair_after_an_answered_frame_leaves_its_previous_image_out(buffer: Any) -> None:
    from gldt_ros.interface.convert import image_to_bgr

    images = [camera_image(i) for i in range(4)]
    for index in range(3):
        buffer.on_image(images[index])
        decide(buffer, index, images[index], 0)
        if index < 1:
            answer(buffer, index, images[index])  # the detector answered frame 0, not frame 1
    first, second, third = buffer.sent_pairs
    assert first.previous.height > 0  # a stream's first pair: the frame with itself
    assert second.previous.height == 0 and second.previous_frame_index == 0
    assert third.previous.height > 0 and third.previous_frame_index == 1, "frame 1 was never answered"
    np.testing.assert_array_equal(image_to_bgr(third.previous), letterboxed(buffer, images[1]))
    np.testing.assert_array_equal(image_to_bgr(third.current), letterboxed(buffer, images[2]))


def test_only_the_global_detector_answering_this_very_frame_counts(buffer: Any) -> None:
    images = [camera_image(i) for i in range(2)]
    buffer.on_image(images[0])
    decide(buffer, 0, images[0], 0)
    answer(buffer, 0, camera_image(0, stream=7))  # frame 0 of another stream (a restarted buffer's)
    answer(buffer, 0, images[0], mode=1)  # the local detector's answer says nothing of the pair
    buffer.on_image(images[1])
    decide(buffer, 1, images[1], 0)
    assert buffer.sent_pairs[-1].previous.height > 0


def prepared_ahead(buffer: Any) -> set[int]:
    """Indices of the buffered frames letterboxed while their decision was pending."""
    return {index for index, frame in buffer._frames.items() if frame.prepared is not None}


def test_a_frame_is_letterboxed_ahead_only_in_a_gd_stretch_and_the_pair_is_the_same(buffer: Any) -> None:
    from gldt_msgs.msg import SchedulerState

    from gldt_ros.interface.convert import image_to_bgr

    images = [camera_image(i) for i in range(4)]
    buffer.on_image(images[0])
    assert not prepared_ahead(buffer), "no decision yet: nothing to guess from"
    decide(buffer, 0, images[0], SchedulerState.MODE_GLOBAL)
    buffer.on_image(images[1])
    assert prepared_ahead(buffer) == {1}
    decide(buffer, 1, images[1], SchedulerState.MODE_GLOBAL)
    assert not prepared_ahead(buffer)
    np.testing.assert_array_equal(image_to_bgr(buffer.sent_pairs[-1].current), letterboxed(buffer, images[1]))
    buffer.on_image(images[2])
    decide(buffer, 2, images[2], SchedulerState.MODE_LOCAL)  # the guess was wrong: dropped, crops sent
    assert not prepared_ahead(buffer) and len(buffer.sent_crops) == 1
    buffer.on_image(images[3])
    assert not prepared_ahead(buffer), "after a LOCAL decision nothing is letterboxed ahead"


def test_frames_letterboxed_ahead_leave_with_their_frames(buffer: Any) -> None:
    """A scheduler that stops answering must not make the buffer hoard letterboxed frames."""
    from gldt_ros.nodes.frame_pair_buffer import PENDING_FRAMES

    first = camera_image(0)
    buffer.on_image(first)
    decide(buffer, 0, first, 0)
    for index in range(1, 3 * PENDING_FRAMES):
        buffer.on_image(camera_image(index))
    assert len(buffer._frames) == PENDING_FRAMES
    # Every frame after the GLOBAL decision was letterboxed ahead; only the buffered ones are held.
    assert prepared_ahead(buffer) == set(buffer._frames)
