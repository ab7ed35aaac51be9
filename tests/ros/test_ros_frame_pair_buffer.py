"""frame_pair_buffer on a GD stretch: it letterboxes a frame while its decision is pending, and it
leaves the previous image out of a pair once the global detector has answered that frame (the
planned skip off, as in lockstep); with the planned skip on, a GLOBAL frame decided while a pair is
in flight is announced as skipped, after that pair's answer and in frame order with LOCAL crops."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.context import Context  # noqa: E402

WIDTH, HEIGHT = 640, 512


def recording_buffer(skip_when_busy: bool) -> Iterator[Any]:
    """A frame_pair_buffer whose pair, crop and skip-notice publishers record what they would send
    (``sent`` holds all three in order)."""
    from rclpy.parameter import Parameter

    from gldt_ros.nodes.frame_pair_buffer import FramePairBuffer

    context = Context()
    rclpy.init(context=context)
    try:
        overrides = [Parameter("skip_global_when_busy", value=skip_when_busy)]
        node: Any = FramePairBuffer(context=context, parameter_overrides=overrides)  # given the lists below
        node.sent_pairs, node.sent_crops, node.sent_skips, node.sent = [], [], [], []
        for publisher, kept in (
            (node.pairs, node.sent_pairs),
            (node.crops, node.sent_crops),
            (node.skips, node.sent_skips),
        ):
            publisher.publish = lambda message, kept=kept: (kept.append(message), node.sent.append(message))
        yield node
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


@pytest.fixture
def buffer() -> Iterator[Any]:
    yield from recording_buffer(skip_when_busy=False)


@pytest.fixture
def skipping_buffer() -> Iterator[Any]:
    yield from recording_buffer(skip_when_busy=True)


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
    assert prepared_ahead(buffer) == {0}, "a stream starts in GLOBAL: its first frame is letterboxed ahead"
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


def test_a_global_frame_decided_while_a_pair_is_in_flight_is_skipped_by_plan(skipping_buffer: Any) -> None:
    from gldt_msgs.msg import DetectionArray, FramePair, RoiCrops, SchedulerState

    buffer = skipping_buffer
    images = [camera_image(i) for i in range(6)]
    modes = [SchedulerState.MODE_GLOBAL] * 3 + [SchedulerState.MODE_LOCAL, SchedulerState.MODE_GLOBAL]
    for index, mode in enumerate(modes):
        buffer.on_image(images[index])
        decide(buffer, index, images[index], mode)
    # Frame 0's pair is in flight: frames 1, 2 and 4 are skipped by plan, frame 3's crops go out.
    kinds = [(type(m).__name__, int(m.frame_index)) for m in buffer.sent]
    assert kinds == [
        (FramePair.__name__, 0),
        (DetectionArray.__name__, 1),
        (DetectionArray.__name__, 2),
        (RoiCrops.__name__, 3),
        (DetectionArray.__name__, 4),
    ], kinds
    assert all(m.mode == DetectionArray.MODE_SKIPPED and not m.detections for m in buffer.sent_skips)
    assert buffer.events["frames_skipped"] == 3
    answer(buffer, 0, camera_image(0, stream=7))  # another stream's frame 0 frees nothing
    assert buffer.global_detector_busy()
    answer(buffer, 0, images[0])
    assert not buffer.global_detector_busy()
    # The next GLOBAL frame's pair goes out, paired with frame 4, which the detector never saw.
    buffer.on_image(images[5])
    decide(buffer, 5, images[5], SchedulerState.MODE_GLOBAL)
    pair = buffer.sent[-1]
    assert isinstance(pair, FramePair) and pair.frame_index == 5 and pair.previous_frame_index == 4
    assert pair.previous.height > 0


def test_an_unanswered_pair_stops_counting_as_busy_after_the_answer_timeout(skipping_buffer: Any) -> None:
    from gldt_msgs.msg import FramePair, SchedulerState

    buffer = skipping_buffer
    buffer.answer_timeout_s = 0.05
    images = [camera_image(i) for i in range(2)]
    buffer.on_image(images[0])
    decide(buffer, 0, images[0], SchedulerState.MODE_GLOBAL)  # never answered: a detector that died
    time.sleep(0.1)  # past the timeout
    buffer.on_image(images[1])
    decide(buffer, 1, images[1], SchedulerState.MODE_GLOBAL)
    assert [type(m) for m in buffer.sent] == [FramePair, FramePair]


def test_an_undecodable_image_is_announced_at_once_and_counted(skipping_buffer: Any) -> None:
    from gldt_msgs.msg import DetectionArray

    buffer = skipping_buffer
    broken = camera_image(0)
    broken.data = bytes(broken.data[:100])
    with pytest.raises(ValueError):
        buffer.on_image(broken)
    (notice,) = buffer.sent
    assert notice.mode == DetectionArray.MODE_UNREADABLE and notice.frame_index == 0
    assert buffer.events["frames_unreadable"] == 1
    buffer.on_image(camera_image(1))
    assert 1 in buffer._frames, "the next frame keeps its own index"
