"""global_detector: pairs that arrive while it is busy are skipped for the newest one (parameter
``pair_queue_depth``, default 1), so a detector slower than the camera does not fall behind."""

from __future__ import annotations

import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="rclpy comes with the ROS wheels that `make test` installs")

from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

from gldt_ros.interface.qos import RELIABLE  # noqa: E402

PAIRS = 5


def pairs(count: int) -> list:
    """``count`` frame pairs of a sky with one dark blob, letterboxed as frame_pair_buffer does."""
    from gldt_msgs.msg import FramePair
    from std_msgs.msg import Header

    from gldt_core.detect import GlobalDetector
    from gldt_ros.interface.convert import bgr_to_image

    geometry = GlobalDetector(num_threads=1, optimize_graph=False)
    frame = np.full((512, 640, 3), 200, dtype=np.uint8)
    frame[250:262, 300:316] = 40
    prepared, letterbox = geometry.prepare(frame)
    messages = []
    for index in range(count):
        header = Header(frame_id="camera")
        header.stamp.sec, header.stamp.nanosec = 1, index * 33_333_333
        image = bgr_to_image(prepared, header)
        messages.append(
            FramePair(
                header=header,
                frame_index=index,
                previous_frame_index=max(index - 1, 0),
                full_width=640,
                full_height=512,
                scale=float(letterbox.scale),
                pad_x=int(letterbox.pad_x),
                pad_y=int(letterbox.pad_y),
                previous=image,
                current=image,
            )
        )
    return messages


def answered_frames(queue_depth: int | None) -> list[int]:
    """Publish ``PAIRS`` pairs while the detector is not spinning (as if busy with an earlier one),
    then let it run; return the frame indices it answered."""
    from gldt_msgs.msg import DetectionArray, FramePair

    from gldt_ros.nodes.global_detector import GlobalDetectorNode

    context = Context()
    rclpy.init(context=context)
    try:
        arguments = ["--ros-args", "-p", f"pair_queue_depth:={queue_depth}"] if queue_depth else None
        detector = GlobalDetectorNode(cli_args=arguments, context=context)
        probe = rclpy.create_node("pair_probe", context=context)
        answered: list[int] = []
        probe.create_subscription(
            DetectionArray, "gldt/detections", lambda m: answered.append(int(m.frame_index)), RELIABLE
        )
        publisher = probe.create_publisher(FramePair, "gldt/frame_pairs", RELIABLE)
        deadline = time.monotonic() + 10
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        for message in pairs(PAIRS):
            publisher.publish(message)
        time.sleep(1.0)  # let DDS deliver every pair into the detector's reader before it runs
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(detector)
        executor.add_node(probe)
        quiet_until = time.monotonic() + 3.0
        deadline = time.monotonic() + 30
        while time.monotonic() < min(quiet_until, deadline):
            count = len(answered)
            executor.spin_once(timeout_sec=0.1)
            if len(answered) != count:
                quiet_until = time.monotonic() + 3.0  # wait until nothing more comes for 3 s
        executor.shutdown()
        detector.destroy_node()
        probe.destroy_node()
        return answered
    finally:
        rclpy.shutdown(context=context)


def test_a_busy_global_detector_answers_the_newest_pair_not_the_backlog() -> None:
    assert answered_frames(None) == [PAIRS - 1]


def test_with_a_deeper_queue_it_works_through_every_pair_in_order() -> None:
    """The same run with ``pair_queue_depth`` = ``PAIRS``: every pair answered, which shows the
    test above can tell the two behaviours apart."""
    assert answered_frames(PAIRS) == list(range(PAIRS))
