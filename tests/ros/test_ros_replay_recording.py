"""The lockstep player closes its recording only after the last frame's outputs on every recorded
topic arrived (the last frame's tracks can overtake its detections: other writers, other topics)."""

from __future__ import annotations

import threading

import pytest

pytest.importorskip("rclpy", reason="gldt_ros is installed with the ROS wheels that `make test` installs")

import rclpy  # noqa: E402
from builtin_interfaces.msg import Time  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402
from std_msgs.msg import Header  # noqa: E402

from gldt_ros.interface import topics  # noqa: E402
from gldt_ros.launcher.bag_io import message_class  # noqa: E402
from gldt_ros.launcher.pipeline import parse_args  # noqa: E402
from gldt_ros.launcher.replay import RECORDED_TOPICS, GraphDriver  # noqa: E402

STAMP_NS = 3_000_000_005


def _raw(msgtype: str, sec: int = 3, nanosec: int = 5) -> bytes:
    return serialize_message(
        message_class(msgtype)(header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id="camera"))
    )


@pytest.fixture
def driver(tmp_path):
    rclpy.init()
    node = GraphDriver(parse_args(["--record", str(tmp_path / "graph.mcap")]))
    try:
        yield node
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown()


def test_the_recording_waits_for_the_last_frames_detections(driver, tmp_path) -> None:
    from gldt_core.io.recording import iter_recorded

    deliver = {topic: driver._make_record_callback(topic, msgtype) for topic, msgtype in RECORDED_TOPICS.items()}
    stop = threading.Event()
    deliver[topics.SCHEDULER_STATE](_raw(RECORDED_TOPICS[topics.SCHEDULER_STATE]))
    deliver[topics.TRACKS](_raw(RECORDED_TOPICS[topics.TRACKS]))
    deliver[topics.DETECTIONS](_raw(RECORDED_TOPICS[topics.DETECTIONS], sec=2))  # an older frame's
    assert not driver.wait_until_recorded(STAMP_NS, stop, timeout_s=0.2), "the last frame's detections have not arrived"

    delivered = threading.Event()

    def late_detections() -> None:
        deliver[topics.DETECTIONS](_raw(RECORDED_TOPICS[topics.DETECTIONS]))
        delivered.set()

    threading.Timer(0.2, late_detections).start()
    assert driver.wait_until_recorded(STAMP_NS, stop, timeout_s=10.0)
    assert delivered.is_set(), "returned before the late detections were recorded"
    driver.close()
    stamps = [message.header.stamp.sec for _, message, _ in iter_recorded(tmp_path / "graph.mcap", topics.DETECTIONS)]
    assert stamps == [2, 3], "both detection messages are in the recording"


def test_a_stop_request_ends_the_wait(driver) -> None:
    stop = threading.Event()
    stop.set()
    assert not driver.wait_until_recorded(STAMP_NS, stop, timeout_s=10.0)
